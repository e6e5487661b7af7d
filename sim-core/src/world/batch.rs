//! Many worlds of one configuration stepped in one call: the worlds of a vector env.
//!
//! [`Worlds`] owns N worlds cloned from one, so they share the circuit and the LIDAR's
//! tables (one copy in the cache for all of them) and each keeps its own reused step
//! buffers. [`Worlds::step`] steps every active world with its cars' actions from one
//! slice and writes each world's observation into caller-provided buffers right after
//! that world's step, while it is still in the cache, in the layout an env session sends
//! (little-endian packed arrays, world-major, then car-major; PROTOCOL.md): the scans
//! land in the reply's frame once, and nothing is allocated per step.
//!
//! Stepping world `i` here gives the very bits [`World::step`] gives it alone: the
//! worlds share nothing that changes.

use std::sync::Arc;

use super::{Action, Observation, Starts, StepEvents, World, WorldConfig, WorldError};
use crate::circuit::Circuit;
use crate::lidar::{Lidar, ScanPath, ScanPathError};

/// Values per car in [`PackedObservations::states`]: x, y, theta, body-frame vx and vy,
/// yaw rate, steering angle.
pub const PACKED_STATE: usize = 7;

/// Where a batch step writes every world's observation. Each buffer holds all worlds
/// (world-major, then car-major) in little-endian bytes, or is empty to skip that field.
#[derive(Debug, Default)]
pub struct PackedObservations<'a> {
    /// The scans of cars `0..scan_cars` of every world as `f32` metres (a range that
    /// noise took below zero is written as 0): `worlds x scan_cars x beams x 4` bytes.
    pub scans: &'a mut [u8],
    pub scan_cars: usize,
    /// `worlds x cars x PACKED_STATE` `f64`: `[x, y, theta, vx, vy, yaw_rate, steer]`.
    pub states: &'a mut [u8],
    /// `worlds x cars` bytes: 1 when the car collided in the last step.
    pub collisions: &'a mut [u8],
    /// `worlds x cars` `u32`: completed laps.
    pub lap_counts: &'a mut [u8],
    /// `worlds x cars` `f64`: race time, frozen when the car stops racing.
    pub lap_times: &'a mut [u8],
    /// `worlds` `f64`: simulated seconds since the reset.
    pub time: &'a mut [u8],
}

impl<'a> PackedObservations<'a> {
    /// Buffers for `scan_cars` scans per world (the other fields skipped).
    pub fn scans(scans: &'a mut [u8], scan_cars: usize) -> Self {
        Self {
            scans,
            scan_cars,
            ..Self::default()
        }
    }

    /// Checks every buffer's length for `worlds` worlds of `cars` cars and `beams` beams.
    fn check(&self, worlds: usize, cars: usize, beams: usize) -> Result<(), WorldError> {
        let sizes = [
            (
                "scans",
                self.scans.len(),
                worlds * self.scan_cars * beams * 4,
            ),
            (
                "states",
                self.states.len(),
                worlds * cars * PACKED_STATE * 8,
            ),
            ("collisions", self.collisions.len(), worlds * cars),
            ("lap_counts", self.lap_counts.len(), worlds * cars * 4),
            ("lap_times", self.lap_times.len(), worlds * cars * 8),
            ("time", self.time.len(), worlds * 8),
        ];
        if self.scan_cars > cars {
            return Err(config_error(
                "scan_cars",
                self.scan_cars,
                format!("a world has {cars} cars"),
            ));
        }
        for (field, got, want) in sizes {
            if got != 0 && got != want {
                return Err(config_error(
                    field,
                    format!("{got} bytes"),
                    format!("expected {want} bytes for {worlds} worlds of {cars} cars, or none"),
                ));
            }
        }
        Ok(())
    }

    /// Writes world `i`'s observation (`cars` cars) into its place in every buffer.
    fn write(&mut self, i: usize, cars: usize, obs: &Observation, time: f64) {
        let beams = obs.num_beams;
        if !self.scans.is_empty() {
            let k = self.scan_cars;
            let dst = &mut self.scans[i * k * beams * 4..][..k * beams * 4];
            for (d, &r) in dst.chunks_exact_mut(4).zip(&obs.scans[..k * beams]) {
                d.copy_from_slice(&(r.max(0.0) as f32).to_le_bytes());
            }
        }
        if !self.states.is_empty() {
            let dst = &mut self.states[i * cars * PACKED_STATE * 8..][..cars * PACKED_STATE * 8];
            for (a, row) in dst.chunks_exact_mut(PACKED_STATE * 8).enumerate() {
                let values = [
                    obs.poses_x[a],
                    obs.poses_y[a],
                    obs.poses_theta[a],
                    obs.linear_vels_x[a],
                    obs.linear_vels_y[a],
                    obs.ang_vels_z[a],
                    obs.steering_angles[a],
                ];
                for (d, v) in row.chunks_exact_mut(8).zip(values) {
                    d.copy_from_slice(&v.to_le_bytes());
                }
            }
        }
        if !self.collisions.is_empty() {
            for (d, &c) in self.collisions[i * cars..][..cars]
                .iter_mut()
                .zip(&obs.collisions)
            {
                *d = u8::from(c);
            }
        }
        if !self.lap_counts.is_empty() {
            let dst = &mut self.lap_counts[i * cars * 4..][..cars * 4];
            for (d, &c) in dst.chunks_exact_mut(4).zip(&obs.lap_counts) {
                d.copy_from_slice(&c.to_le_bytes());
            }
        }
        if !self.lap_times.is_empty() {
            let dst = &mut self.lap_times[i * cars * 8..][..cars * 8];
            for (d, &t) in dst.chunks_exact_mut(8).zip(&obs.lap_times) {
                d.copy_from_slice(&t.to_le_bytes());
            }
        }
        if !self.time.is_empty() {
            self.time[i * 8..][..8].copy_from_slice(&time.to_le_bytes());
        }
    }

    /// The buffers of worlds `0..at` and of worlds `at..` (to step parts of a batch on
    /// several threads).
    pub fn split_at(self, at: usize, cars: usize, beams: usize) -> (Self, Self) {
        fn cut(b: &mut [u8], bytes: usize) -> (&mut [u8], &mut [u8]) {
            if b.is_empty() {
                (&mut [], &mut [])
            } else {
                b.split_at_mut(bytes)
            }
        }
        let k = self.scan_cars;
        let (s0, s1) = cut(self.scans, at * k * beams * 4);
        let (st0, st1) = cut(self.states, at * cars * PACKED_STATE * 8);
        let (c0, c1) = cut(self.collisions, at * cars);
        let (l0, l1) = cut(self.lap_counts, at * cars * 4);
        let (t0, t1) = cut(self.lap_times, at * cars * 8);
        let (w0, w1) = cut(self.time, at * 8);
        (
            Self {
                scans: s0,
                scan_cars: k,
                states: st0,
                collisions: c0,
                lap_counts: l0,
                lap_times: t0,
                time: w0,
            },
            Self {
                scans: s1,
                scan_cars: k,
                states: st1,
                collisions: c1,
                lap_counts: l1,
                lap_times: t1,
                time: w1,
            },
        )
    }
}

fn config_error(field: &str, value: impl ToString, reason: impl Into<String>) -> WorldError {
    WorldError::Config {
        field: field.to_string(),
        value: value.to_string(),
        reason: reason.into(),
    }
}

/// N worlds of one configuration on one circuit (see the module docs).
#[derive(Debug, Clone)]
pub struct Worlds {
    worlds: Vec<World>,
    /// What the last step did in each world.
    events: Vec<StepEvents>,
}

/// A run of consecutive worlds of a [`Worlds`], stepped as a batch of its own (one
/// part per thread).
#[derive(Debug)]
pub struct WorldsMut<'a> {
    worlds: &'a mut [World],
    events: &'a mut [StepEvents],
}

impl Worlds {
    /// `n` worlds of `config` on `circuit` (not yet reset).
    pub fn new(circuit: Arc<Circuit>, config: WorldConfig, n: usize) -> Result<Self, WorldError> {
        Ok(Self::of(&World::new(circuit, config)?, n))
    }

    /// `n` clones of `world` (sharing its circuit and LIDAR tables; each with its own
    /// state).
    pub fn of(world: &World, n: usize) -> Self {
        Self {
            worlds: vec![world.clone(); n],
            events: vec![StepEvents::default(); n],
        }
    }

    pub fn len(&self) -> usize {
        self.worlds.len()
    }

    pub fn is_empty(&self) -> bool {
        self.worlds.is_empty()
    }

    /// Cars per world.
    pub fn num_agents(&self) -> usize {
        self.worlds.first().map_or(0, World::num_agents)
    }

    pub fn world(&self, i: usize) -> &World {
        &self.worlds[i]
    }

    /// World `i`, to reset or restore it.
    pub fn world_mut(&mut self, i: usize) -> &mut World {
        &mut self.worlds[i]
    }

    pub fn iter(&self) -> std::slice::Iter<'_, World> {
        self.worlds.iter()
    }

    /// What the last step did in world `i` (unchanged when it was not stepped).
    pub fn events(&self, i: usize) -> &StepEvents {
        &self.events[i]
    }

    /// Takes every world's LIDAR scans on `path` (see [`World::set_scan_path`]): worlds
    /// that shared one LIDAR's tables share its replacement's (a copy per world would
    /// multiply the tables a batch step reads). An error, changing nothing, if this CPU
    /// cannot run the path.
    pub fn set_scan_path(&mut self, path: ScanPath) -> Result<(), ScanPathError> {
        let mut replaced: Vec<(Arc<Lidar>, Arc<Lidar>)> = Vec::new();
        for w in &mut self.worlds {
            if let Some((_, new)) = replaced.iter().find(|(old, _)| Arc::ptr_eq(old, &w.lidar)) {
                w.lidar = new.clone();
                continue;
            }
            let old = w.lidar.clone();
            w.set_scan_path(path)?;
            replaced.push((old, w.lidar.clone()));
        }
        Ok(())
    }

    /// Start an episode in world `i` (see [`World::reset`]).
    pub fn reset(&mut self, i: usize, seed: u64, starts: &Starts) -> Result<(), WorldError> {
        self.worlds[i].reset(seed, starts).map(|_| ())
    }

    /// The whole batch as one run.
    pub fn batch_mut(&mut self) -> WorldsMut<'_> {
        WorldsMut {
            worlds: &mut self.worlds,
            events: &mut self.events,
        }
    }

    /// See [`WorldsMut::step`].
    pub fn step(
        &mut self,
        actions: &[Action],
        active: &[bool],
        out: Option<&mut PackedObservations<'_>>,
    ) -> Result<(), WorldError> {
        self.batch_mut().step(actions, active, out)
    }

    /// See [`WorldsMut::pack`].
    pub fn pack(&self, out: &mut PackedObservations<'_>) -> Result<(), WorldError> {
        pack(&self.worlds, out)
    }
}

/// Writes the current observation of every world of `worlds` into `out`.
fn pack(worlds: &[World], out: &mut PackedObservations<'_>) -> Result<(), WorldError> {
    let Some(first) = worlds.first() else {
        return Ok(());
    };
    let cars = first.num_agents();
    out.check(worlds.len(), cars, first.config.lidar.num_beams)?;
    for (i, w) in worlds.iter().enumerate() {
        let s = w.state()?;
        out.write(i, cars, &s.observation, s.time);
    }
    Ok(())
}

impl<'a> WorldsMut<'a> {
    pub fn len(&self) -> usize {
        self.worlds.len()
    }

    pub fn is_empty(&self) -> bool {
        self.worlds.is_empty()
    }

    /// Worlds `0..at` and `at..` of this run.
    pub fn split_at(self, at: usize) -> (WorldsMut<'a>, WorldsMut<'a>) {
        let (w0, w1) = self.worlds.split_at_mut(at);
        let (e0, e1) = self.events.split_at_mut(at);
        (
            WorldsMut {
                worlds: w0,
                events: e0,
            },
            WorldsMut {
                worlds: w1,
                events: e1,
            },
        )
    }

    pub fn world(&self, i: usize) -> &World {
        &self.worlds[i]
    }

    pub fn world_mut(&mut self, i: usize) -> &mut World {
        &mut self.worlds[i]
    }

    /// What the last step did in world `i` of this run.
    pub fn events(&self, i: usize) -> &StepEvents {
        &self.events[i]
    }

    /// Step every world `i` of this run for which `active[i]` holds (every world when
    /// `active` is empty) with the actions `actions[i * cars..(i + 1) * cars]` (one per
    /// car; those of inactive worlds are not read), then write every world's
    /// observation, stepped or not, into `out` when given. Everything is checked
    /// before any world changes: a bad action or buffer leaves every world as it was.
    pub fn step(
        &mut self,
        actions: &[Action],
        active: &[bool],
        mut out: Option<&mut PackedObservations<'_>>,
    ) -> Result<(), WorldError> {
        let n = self.len();
        let Some(first) = self.worlds.first() else {
            return Ok(());
        };
        let cars = first.num_agents();
        let beams = first.config.lidar.num_beams;
        if actions.len() != n * cars {
            return Err(WorldError::ActionCount {
                expected: n * cars,
                got: actions.len(),
            });
        }
        if !active.is_empty() && active.len() != n {
            return Err(config_error(
                "active",
                format!("{} flags", active.len()),
                format!("expected none or one per world ({n})"),
            ));
        }
        if let Some(out) = out.as_deref() {
            out.check(n, cars, beams)?;
        }
        for (i, w) in self.worlds.iter().enumerate() {
            if active.get(i).copied().unwrap_or(true) {
                w.check_actions(&actions[i * cars..(i + 1) * cars])?;
            } else {
                w.state()?;
            }
        }
        for (i, (w, events)) in self
            .worlds
            .iter_mut()
            .zip(self.events.iter_mut())
            .enumerate()
        {
            if active.get(i).copied().unwrap_or(true) {
                w.step_into(&actions[i * cars..(i + 1) * cars], events)?;
            }
            if let Some(out) = out.as_deref_mut() {
                let s = w.state()?;
                out.write(i, cars, &s.observation, s.time);
            }
        }
        Ok(())
    }

    /// Write every world's current observation into `out` (after resets).
    pub fn pack(&self, out: &mut PackedObservations<'_>) -> Result<(), WorldError> {
        pack(self.worlds, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::circuit::Circuits;

    #[test]
    fn a_scan_path_set_on_the_batch_keeps_its_worlds_sharing_one_lidar() {
        let circuit = Circuits::new().get("lakeside").expect("a shipped map");
        let mut worlds = Worlds::new(circuit, WorldConfig::default(), 4).expect("worlds");
        worlds
            .set_scan_path(ScanPath::Portable)
            .expect("every CPU runs the portable path");
        for w in worlds.iter() {
            assert_eq!(w.scan_path(), ScanPath::Portable);
            assert!(Arc::ptr_eq(&w.lidar, &worlds.world(0).lidar));
        }
    }
}
