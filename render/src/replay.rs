//! Scenes of a recorded episode: its trajectory (poses and speeds every few steps) with
//! what the trajectory leaves out rebuilt from the scenario and seed: the obstacles (the
//! same seeded placement as the episode's), each car's lap count (from its lap times)
//! and status (from its end time), and car 0's scan (cast noise-free from its recorded
//! pose against the walls, the obstacles and the other cars).

use std::sync::Arc;

use paddock_rollout::{EpisodeResult, Scenario, Termination, episode_world};
use paddock_sim::circuit::{Circuit, Circuits};
use paddock_sim::geometry::{Obb, Pose};
use paddock_sim::lidar::Lidar;

use crate::{CarStatus, CarView, RenderError, ScanView, Scene, lidar_origin};

/// The scenes of one recorded episode, one per trajectory sample.
pub struct Replay<'a> {
    scenario: &'a Scenario,
    episode: &'a EpisodeResult,
    circuit: Arc<Circuit>,
    obstacles: Vec<Obb>,
    lidar: Lidar,
    /// Per car: the times at which it completed each lap.
    lap_ends: Vec<Vec<f64>>,
    caption: String,
}

impl<'a> Replay<'a> {
    /// The replay of `episode`, an episode of `scenario` run with a trajectory recorded.
    pub fn new(
        circuits: &Circuits,
        scenario: &'a Scenario,
        episode: &'a EpisodeResult,
    ) -> Result<Self, RenderError> {
        let Some(tr) = &episode.trajectory else {
            return Err(RenderError::Invalid {
                field: "trajectory".into(),
                value: "none".into(),
                reason: "the episode was run without recording its trajectory".into(),
            });
        };
        let n = scenario.agents.len();
        if tr.agents.len() != n || episode.agents.len() != n {
            return Err(RenderError::Invalid {
                field: "trajectory.agents".into(),
                value: tr.agents.len().to_string(),
                reason: format!("the scenario has {n} cars"),
            });
        }
        let circuit = circuits
            .get(&scenario.map)
            .map_err(paddock_rollout::RolloutError::from)?;
        let world = episode_world(scenario, circuit.clone(), episode.seed, &[])?;
        let obstacles = world.obstacles()?.to_vec();
        let lap_ends = episode
            .agents
            .iter()
            .map(|a| {
                a.lap_times
                    .iter()
                    .scan(0.0, |t, lap| {
                        *t += lap;
                        Some(*t)
                    })
                    .collect()
            })
            .collect();
        let drivers: Vec<&str> = scenario.agents.iter().map(|a| a.driver.as_str()).collect();
        let caption = format!("{} · {}", circuit.name, drivers.join(" vs "));
        Ok(Self {
            scenario,
            episode,
            circuit,
            obstacles,
            lidar: Lidar::new(scenario.lidar.clone()),
            lap_ends,
            caption,
        })
    }

    /// The circuit the episode ran on.
    pub fn circuit(&self) -> &Arc<Circuit> {
        &self.circuit
    }

    /// Number of scenes (trajectory samples).
    pub fn len(&self) -> usize {
        self.episode.trajectory.as_ref().map_or(0, |t| t.t.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Scene `k` (`k < len()`).
    pub fn scene(&self, k: usize) -> Scene {
        let tr = self.episode.trajectory.as_ref().expect("checked in new");
        let t = tr.t[k];
        let cars: Vec<CarView> = tr
            .agents
            .iter()
            .enumerate()
            .map(|(i, a)| {
                let result = &self.episode.agents[i];
                let ended = result.end_time.is_some_and(|e| t >= e - 1e-9);
                let status = match (ended, result.termination) {
                    (true, Termination::Crashed) => CarStatus::Crashed,
                    (true, Termination::Finished) => CarStatus::Finished,
                    _ => CarStatus::Racing,
                };
                let vehicle = &self.scenario.agents[i].vehicle;
                CarView {
                    pose: Pose::new(a.x[k], a.y[k], a.theta[k]),
                    length: vehicle.length,
                    width: vehicle.width,
                    speed: a.speed[k],
                    laps: self.lap_ends[i].iter().filter(|&&e| e <= t + 1e-9).count() as u32,
                    status,
                }
            })
            .collect();
        let scan = cars.first().map(|car0| {
            let mut seen: Vec<Obb> = cars
                .iter()
                .skip(1)
                .filter(|c| c.status != CarStatus::Finished)
                .map(|c| Obb::car(c.pose, c.length, c.width))
                .collect();
            seen.extend_from_slice(&self.obstacles);
            let mut ranges = vec![0.0; self.lidar.num_beams()];
            self.lidar
                .scan(&self.circuit.map, car0.pose, &seen, &mut ranges);
            let cfg = self.lidar.config();
            ScanView {
                origin: lidar_origin(car0.pose, cfg.mount_offset),
                fov: cfg.fov,
                max_range: cfg.max_range,
                ranges,
            }
        });
        Scene {
            time: t,
            laps: Some(self.scenario.laps),
            cars,
            obstacles: self.obstacles.clone(),
            scan,
            caption: self.caption.clone(),
        }
    }
}
