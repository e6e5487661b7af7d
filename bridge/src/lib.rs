//! # paddock-bridge: Paddock drivers on a ROS 2 car, a software-in-the-loop car, recordings
//!
//! The team's car runs ROS 2 (f1tenth_system: LIDAR on `/scan`, VESC odometry on `/odom`,
//! drive commands on `/drive`). This crate speaks that stack with no ROS installation,
//! through its own node layer over RustDDS (pure-Rust DDS, [`ros`]), so one static
//! `paddock` binary can, on Humble as on Jazzy (the distribution is chosen at run time):
//!
//! - [`drive`]: run any Paddock driver (built-in or a `paddock tune` result) as a ROS 2
//!   node, behind a safety layer ([`safety`]: stale-sensor stop, clamps, time-to-collision
//!   emergency stop, clean stop on exit) with scan-to-command latency measured;
//! - [`sil`]: stand in for the car with the simulator (same topics and message types as
//!   the car, like f1tenth_gym_ros), paced by the wall clock or a multiple of it;
//! - [`record`]: record the car's topics to MCAP (ROS 2 bag format, `cdr` + `ros2msg`
//!   schemas) and export a recording to the reality-gap CSV layout.
//!
//! ## Design
//! The decisions are sans-IO: [`safety::Safety`] and [`drive::DriveCore`] take messages and
//! times as arguments and return commands, so stale-sensor, clamp and emergency-stop
//! behaviour is unit-tested with a virtual clock; the ROS loops around them only move
//! messages. Messages ([`msg`], from `paddock-recordings`, shared with the reality-gap
//! tool) are serde structs in ROS 2 IDL field order, encoded by one CDR codec
//! (`paddock_recordings::cdr`) byte-compatible with rclcpp/rclpy nodes, on DDS and in
//! MCAP files alike.

pub mod drive;
pub mod driver_spec;
pub mod freshness;
pub mod mount;
pub mod record;
pub mod ros;
pub mod safety;
pub mod scan;
pub mod sil;

/// The car's ROS 2 messages (they live in `paddock-recordings`, with their CDR codec).
pub use paddock_recordings::msg;

use std::fmt::Display;

/// Errors of the bridge; each names the field, topic, file or value involved.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error("invalid {field} = {value}: {reason}")]
    Config {
        field: String,
        value: String,
        reason: String,
    },
    #[error("ROS 2: {what}: {message}")]
    Ros { what: String, message: String },
    /// (The cause is in the message, not chained, so it prints once.)
    #[error("{path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error("{path}: {message}")]
    Format { path: String, message: String },
    /// The driver failed while the car was driving (a panic inside `act`); zero speed
    /// was sent before this error was returned.
    #[error("driver {driver} failed: {message}")]
    Driver { driver: String, message: String },
    #[error(transparent)]
    Policy(#[from] paddock_policy::PolicyError),
    #[error(transparent)]
    World(#[from] paddock_sim::world::WorldError),
    #[error(transparent)]
    Map(#[from] paddock_sim::track::TrackError),
}

impl BridgeError {
    /// An I/O error on the file `path`.
    pub fn io(path: &std::path::Path, error: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            error,
        }
    }

    /// A file `path` whose contents are not what they should be.
    pub fn format(path: &std::path::Path, message: String) -> Self {
        Self::Format {
            path: path.display().to_string(),
            message,
        }
    }

    /// A configuration error naming `field`, its `value` and why it is wrong.
    pub fn config(field: &str, value: impl Display, reason: &str) -> Self {
        Self::Config {
            field: field.to_string(),
            value: value.to_string(),
            reason: reason.to_string(),
        }
    }
}
