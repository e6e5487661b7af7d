//! The ROS 2 flags every bridge command shares (domain, distribution, topics, frames,
//! QoS), read into the bridge's [`RosConfig`].

use anyhow::{Context, Result};
use clap::Args;
use paddock_bridge::ros::{Frames, QosConfig, RosConfig, RosDistro, parse_domain_id};

use crate::args;

/// ROS 2 settings shared by the node commands.
#[derive(Args, Clone)]
pub(super) struct RosArgs {
    /// DDS domain (default: $ROS_DOMAIN_ID, else 0).
    #[arg(long)]
    domain_id: Option<String>,
    /// The car's ROS 2 distribution: humble, iron, jazzy, kilted or rolling (default:
    /// $ROS_DISTRO, else jazzy). It sets the layout of the ROS graph record that `ros2
    /// node list` reads: 24-byte gids on Humble, 16 from Iron on.
    #[arg(long)]
    ros_distro: Option<String>,
    /// The car's LIDAR topic (sensor_msgs/LaserScan).
    #[arg(long, default_value = "/scan")]
    scan_topic: String,
    /// The car's odometry topic (nav_msgs/Odometry).
    #[arg(long, default_value = "/odom")]
    odom_topic: String,
    /// The car's drive command topic (ackermann_msgs/AckermannDriveStamped).
    #[arg(long, default_value = "/drive")]
    drive_topic: String,
    /// Where the SIL car takes a new start pose (geometry_msgs/PoseWithCovarianceStamped).
    #[arg(long, default_value = "/initialpose")]
    initialpose_topic: String,
    /// The opponent's LIDAR topic.
    #[arg(long, default_value = "/opp_scan")]
    opp_scan_topic: String,
    /// The opponent's odometry topic.
    #[arg(long, default_value = "/opp_odom")]
    opp_odom_topic: String,
    /// The opponent's drive command topic.
    #[arg(long, default_value = "/opp_drive")]
    opp_drive_topic: String,
    /// The SIL car's transforms (tf2's topic).
    #[arg(long, default_value = "/tf")]
    tf_topic: String,
    /// The SIL car's static transforms (transient local, tf2's topic).
    #[arg(long, default_value = "/tf_static")]
    tf_static_topic: String,
    /// Odometry header frame id, the parent of the SIL car's /tf transforms (default:
    /// `odom` on the car, `map` for the SIL car, as f1tenth_gym_ros).
    #[arg(long)]
    odom_frame: Option<String>,
    /// The car's body frame: odometry child frame, drive commands (default: `base_link`
    /// on the car, `ego_racecar/base_link` for the SIL car).
    #[arg(long)]
    base_frame: Option<String>,
    /// The LIDAR's frame (default: `laser` on the car, `ego_racecar/laser` for the SIL car).
    #[arg(long)]
    laser_frame: Option<String>,
    /// The opponent's body frame (default `opp_base_link`; SIL `opp_racecar/base_link`).
    #[arg(long)]
    opp_base_frame: Option<String>,
    /// The opponent's LIDAR frame (default `opp_laser`; SIL `opp_racecar/laser`).
    #[arg(long)]
    opp_laser_frame: Option<String>,
    /// Publish best effort instead of reliable.
    #[arg(long)]
    publish_best_effort: bool,
    /// Subscribe reliable instead of best effort (then only reliable publishers match).
    #[arg(long)]
    subscribe_reliable: bool,
    /// QoS history depth (keep last N) of publishers and subscriptions.
    #[arg(long, default_value_t = 5, value_parser = args::whole::<usize>(1, 1_000))]
    qos_depth: usize,
}

impl RosArgs {
    /// The settings, with frame ids from `frames` unless given.
    pub(super) fn config(&self, frames: Frames) -> Result<RosConfig> {
        let domain_id = match (&self.domain_id, std::env::var("ROS_DOMAIN_ID")) {
            (Some(d), _) => parse_domain_id(d).context("--domain-id")?,
            (None, Ok(d)) => {
                parse_domain_id(&d).context("the environment variable ROS_DOMAIN_ID")?
            }
            (None, Err(_)) => 0,
        };
        let mut c = RosConfig {
            domain_id,
            distro: ros_distro(self.ros_distro.as_deref(), std::env::var("ROS_DISTRO").ok())?,
            ..RosConfig::default()
        };
        c.topics.scan = self.scan_topic.clone();
        c.topics.odom = self.odom_topic.clone();
        c.topics.drive = self.drive_topic.clone();
        c.topics.initialpose = self.initialpose_topic.clone();
        c.topics.opp_scan = self.opp_scan_topic.clone();
        c.topics.opp_odom = self.opp_odom_topic.clone();
        c.topics.opp_drive = self.opp_drive_topic.clone();
        c.topics.tf = self.tf_topic.clone();
        c.topics.tf_static = self.tf_static_topic.clone();
        let pick = |given: &Option<String>, default: String| given.clone().unwrap_or(default);
        c.frames = Frames {
            odom: pick(&self.odom_frame, frames.odom),
            base: pick(&self.base_frame, frames.base),
            laser: pick(&self.laser_frame, frames.laser),
            opp_base: pick(&self.opp_base_frame, frames.opp_base),
            opp_laser: pick(&self.opp_laser_frame, frames.opp_laser),
        };
        c.publish_qos = QosConfig {
            reliable: !self.publish_best_effort,
            depth: self.qos_depth,
        };
        c.subscribe_qos = QosConfig {
            reliable: self.subscribe_reliable,
            depth: self.qos_depth,
        };
        c.validate()?;
        Ok(c)
    }
}

/// The distribution from `--ros-distro`, else from `ROS_DISTRO` (`from_env`), else
/// Jazzy's layout with a warning (the binary runs without a sourced ROS, where
/// `ROS_DISTRO` is unset).
fn ros_distro(flag: Option<&str>, from_env: Option<String>) -> Result<RosDistro> {
    if let Some(f) = flag {
        return f.parse().context("--ros-distro");
    }
    match from_env.filter(|v| !v.trim().is_empty()) {
        Some(v) => v
            .parse()
            .context("the environment variable ROS_DISTRO (set --ros-distro to override it)"),
        None => {
            let d = RosDistro::default();
            tracing::warn!(
                "neither --ros-distro nor ROS_DISTRO is set: the ROS graph record is written \
                 in {d}'s layout (Iron and later); pass --ros-distro humble on a Humble car"
            );
            Ok(d)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_distribution_comes_from_the_flag_then_ros_distro_then_jazzy() {
        let env = |v: &str| Some(v.to_string());
        assert_eq!(
            ros_distro(Some("humble"), env("jazzy")).unwrap(),
            RosDistro::Humble
        );
        assert_eq!(ros_distro(None, env("humble")).unwrap(), RosDistro::Humble);
        assert_eq!(ros_distro(None, env("iron")).unwrap(), RosDistro::Iron);
        assert_eq!(ros_distro(None, None).unwrap(), RosDistro::Jazzy);
        assert_eq!(ros_distro(None, env(" ")).unwrap(), RosDistro::Jazzy);
        let e = format!("{:#}", ros_distro(None, env("foxy")).unwrap_err());
        assert!(e.contains("ROS_DISTRO") && e.contains("\"foxy\""), "{e}");
        let e = format!(
            "{:#}",
            ros_distro(Some("hubmle"), env("humble")).unwrap_err()
        );
        assert!(
            e.contains("--ros-distro") && e.contains("humble, iron"),
            "{e}"
        );
    }
}
