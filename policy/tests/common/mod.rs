//! Episode runners shared by the driver tests and the `laps` example.
#![allow(dead_code)]

use std::sync::Arc;

use paddock_policy::{Driver, build_driver, driver_info, params_from_overrides};
use paddock_sim::circuit::{Circuit, Circuits};
use paddock_sim::geometry::Pose;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{
    Action, AgentConfig, AgentStatus, ObstacleConfig, Starts, World, WorldConfig,
};

pub const MAPS: [&str; 3] = ["lakeside", "quarry", "harbour"];

pub fn circuit(name: &str) -> Arc<Circuit> {
    Circuits::new().get(name).expect("shipped map")
}

/// A driver by registry name with `overrides` on its defaults.
pub fn driver(name: &str, circuit: &Arc<Circuit>, overrides: &[(&str, f64)]) -> Box<dyn Driver> {
    let info = driver_info(name).expect("registered");
    let o: Vec<(String, f64)> = overrides.iter().map(|(k, v)| (k.to_string(), *v)).collect();
    let p = params_from_overrides(name, &info.params, &o).expect("valid overrides");
    build_driver(name, &p, circuit, &VehicleParams::default()).expect("builds")
}

#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// Completed lap times of each car, seconds.
    pub lap_times: Vec<Vec<f64>>,
    pub status: Vec<AgentStatus>,
    pub time: f64,
}

impl Outcome {
    pub fn finished(&self, i: usize) -> bool {
        self.status[i] == AgentStatus::Finished
    }
}

/// Run `drivers` until every car is out of the race or `max_time` seconds pass.
pub fn run(
    circuit: &Arc<Circuit>,
    mut drivers: Vec<Box<dyn Driver>>,
    seed: u64,
    starts: &Starts,
    laps: u32,
    obstacles: usize,
    max_time: f64,
) -> Outcome {
    let n = drivers.len();
    let config = WorldConfig {
        agents: drivers
            .iter()
            .map(|d| AgentConfig {
                params: VehicleParams::default(),
                scan: d.sensors().lidar,
            })
            .collect(),
        laps: Some(laps),
        obstacles: ObstacleConfig {
            count: obstacles,
            ..ObstacleConfig::default()
        },
        ..WorldConfig::default()
    };
    let mut world = World::new(circuit.clone(), config).expect("config");
    world.reset(seed, starts).expect("reset");
    for d in drivers.iter_mut() {
        d.reset();
    }
    let steps = (max_time / world.config().dt) as usize;
    let mut actions = vec![Action::default(); n];
    for _ in 0..steps {
        let obs = world.observation().expect("reset");
        for (i, d) in drivers.iter_mut().enumerate() {
            actions[i] = d.act(obs, i);
        }
        world.step(&actions).expect("step");
        if world.done() {
            break;
        }
    }
    let state = world.state().expect("reset");
    Outcome {
        lap_times: (0..n)
            .map(|i| state.agents[i].laps.lap_times.clone())
            .collect(),
        status: state.agents.iter().map(|a| a.status).collect(),
        time: state.time,
    }
}

/// One car alone from a seeded random start.
pub fn solo(map: &str, name: &str, overrides: &[(&str, f64)], seed: u64, laps: u32) -> Outcome {
    let c = circuit(map);
    let d = driver(name, &c, overrides);
    let max_time = 40.0 + laps as f64 * c.track.length() / 2.0;
    run(&c, vec![d], seed, &Starts::Random, laps, 0, max_time)
}

/// Car 0 (`name`) starts on the centerline at a seeded place; a pure-pursuit car at
/// `opp_scale` of its speed profile starts `gap` metres ahead of it.
pub fn head_to_head(
    map: &str,
    name: &str,
    seed: u64,
    gap: f64,
    opp_scale: f64,
    laps: u32,
) -> Outcome {
    let c = circuit(map);
    let me = driver(name, &c, &[]);
    let opp = driver("pure-pursuit", &c, &[("speed_scale", opp_scale)]);
    let mut rng = paddock_sim::rng::Rng::new(seed);
    let s = rng.uniform_range(0.0, c.track.length());
    let pose = |s: f64| {
        let (p, _, _) = c.track.at(s);
        Pose::new(p.x, p.y, p.theta)
    };
    let starts = Starts::Poses(vec![pose(s), pose(s + gap)]);
    let max_time = 40.0 + laps as f64 * c.track.length() / 2.0;
    run(&c, vec![me, opp], seed, &starts, laps, 0, max_time)
}
