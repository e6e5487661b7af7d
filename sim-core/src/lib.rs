//! # paddock-sim: the Paddock simulator
//!
//! A deterministic, multi-agent simulator for 1/10-scale autonomous race cars (F1TENTH).
//! It steps the kinematic and dynamic single-track vehicle models exactly as the
//! f1tenth_gym reference does, casts a 2D LIDAR against ROS map_server maps, detects
//! car-car and car-wall collisions, and counts laps by arc length along the centerline.
//!
//! ## Design
//! - **Pure and deterministic.** All state is in plain values passed to `step`; there is no
//!   global state. Maps are values too: a program creates a [`circuit::Circuits`]
//!   registry (the folders of its user's maps plus the maps shipped inside the library),
//!   which loads each circuit once, and passes it to whatever needs maps. f64 state, a
//!   fixed timestep, one seeded PRNG per world ([`rng::Rng`]), and transcendental
//!   functions from the `libm` crate, so the same seed and actions give the same bits on
//!   every host.
//! - **No I/O** beyond loading the maps, tracks and vehicle parameter files it is asked
//!   to load (shipped maps load from the bytes compiled in); no environment variables.
//! - **Fast.** The LIDAR and the dynamics are built for millions of steps per second.
//!
//! Start with [`prelude`].

pub mod circuit;
pub mod collision;
pub mod dynamics;
pub mod geometry;
pub mod lidar;
pub mod map;
pub mod params;
pub mod rng;
pub mod shipped;
pub mod track;
pub mod trackgen;
pub mod world;

/// The types most users need.
pub mod prelude {
    pub use crate::geometry::{Obb, Pose};
    pub use crate::rng::Rng;
}
