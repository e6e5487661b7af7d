//! Running one episode.

use std::sync::Arc;

use paddock_policy::{build_driver, check_lidar};
use paddock_sim::circuit::{Circuit, Circuits};
use paddock_sim::world::{
    Action, AgentConfig, AgentStatus, Starts, StepEvents, World, WorldConfig,
};
use serde::{Deserialize, Serialize};

use crate::{RolloutError, Scenario, StartSpec};

/// Why a car's episode ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Termination {
    /// Completed the scenario's laps.
    Finished,
    /// Collided (collision mode `terminate`).
    Crashed,
    /// Still racing at the time limit.
    TimeLimit,
}

/// One car's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AgentResult {
    pub driver: String,
    pub termination: Termination,
    /// Every completed lap's time, seconds.
    pub lap_times: Vec<f64>,
    /// Whether the car collided at any time.
    pub collided: bool,
    /// Arc length driven along the centerline, metres.
    pub progress: f64,
    /// Episode time at which it finished or crashed (None at the time limit).
    pub end_time: Option<f64>,
    /// Progress in metres, minus the scenario's crash penalty if it crashed.
    pub episode_return: f64,
}

/// One car's recorded trajectory.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct AgentTrace {
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub theta: Vec<f64>,
    pub speed: Vec<f64>,
    pub steer: Vec<f64>,
}

/// Samples every `decimation` steps (and the final state).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Trajectory {
    pub decimation: u32,
    pub t: Vec<f64>,
    pub agents: Vec<AgentTrace>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeResult {
    pub seed: u64,
    pub map: String,
    pub steps: u64,
    /// Simulated seconds.
    pub time: f64,
    pub agents: Vec<AgentResult>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trajectory: Option<Trajectory>,
}

/// The world of episode `seed` of `scenario` at its start (cars and obstacles placed),
/// as [`run_episode`] steps it; `scans[i]`: whether car `i` has a LIDAR. Replays of a
/// recorded episode (videos) rebuild its obstacles from this.
pub fn episode_world(
    scenario: &Scenario,
    circuit: Arc<Circuit>,
    seed: u64,
    scans: &[bool],
) -> Result<World, RolloutError> {
    let config = WorldConfig {
        dt: 0.01,
        lidar: scenario.lidar.clone(),
        collision_mode: scenario.collision_mode,
        agents: scenario
            .agents
            .iter()
            .enumerate()
            .map(|(i, a)| AgentConfig {
                params: a.vehicle.clone(),
                scan: scans.get(i).copied().unwrap_or(false),
            })
            .collect(),
        obstacles: scenario.obstacles.clone(),
        laps: Some(scenario.laps),
    };
    let mut world = World::new(circuit, config)?;
    let starts = match &scenario.starts {
        StartSpec::Random => Starts::Random,
        StartSpec::Poses(p) => Starts::Poses(p.clone()),
        StartSpec::RandomReversed => {
            // the same random grid as `Random`, with the cars in reverse slot order
            let mut poses = world.start_poses_for(seed, &Starts::Random)?;
            poses.reverse();
            Starts::Poses(poses)
        }
    };
    world.reset(seed, &starts)?;
    Ok(world)
}

/// Run one episode of `scenario` with `seed`; record the trajectory every `record`
/// steps if given. The scenario's map is looked up in `circuits`, which loads it once
/// for every episode run with the same registry.
pub fn run_episode(
    circuits: &Circuits,
    scenario: &Scenario,
    seed: u64,
    record: Option<u32>,
) -> Result<EpisodeResult, RolloutError> {
    scenario.validate()?;
    let circuit = circuits.get(&scenario.map)?;
    let mut drivers = Vec::with_capacity(scenario.agents.len());
    for (i, a) in scenario.agents.iter().enumerate() {
        let d = check_lidar(&a.driver, &scenario.lidar)
            .and_then(|()| build_driver(&a.driver, &a.params, &circuit, &a.vehicle))
            .map_err(|source| RolloutError::Driver { agent: i, source })?;
        drivers.push(d);
    }
    let scans: Vec<bool> = drivers.iter().map(|d| d.sensors().lidar).collect();
    let mut world = episode_world(scenario, circuit.clone(), seed, &scans)?;
    let n = scenario.agents.len();
    for d in &mut drivers {
        d.reset();
    }
    let dt = world.config().dt;
    let max_steps = (scenario.time_limit / dt).ceil() as u64;
    let mut trajectory = record.map(|decimation| Trajectory {
        decimation: decimation.max(1),
        t: Vec::new(),
        agents: vec![AgentTrace::default(); n],
    });
    let mut actions = vec![Action::default(); n];
    // One buffer for every step's events (`World::step` would allocate them each step).
    let mut events = StepEvents::default();
    let mut ever_collided: Vec<bool> = world.observation()?.collisions.clone();
    let mut steps = 0u64;
    // when a car's driver faulted (Driver::fault): it is stopped and its episode ends as
    // a crash at that time
    let mut faulted: Vec<Option<f64>> = vec![None; n];
    loop {
        let state = world.state()?;
        if let Some(tr) = &mut trajectory
            && (steps.is_multiple_of(tr.decimation as u64) || world.done() || steps == max_steps)
        {
            let obs = &state.observation;
            tr.t.push(state.time);
            for (i, a) in tr.agents.iter_mut().enumerate() {
                a.x.push(obs.poses_x[i]);
                a.y.push(obs.poses_y[i]);
                a.theta.push(obs.poses_theta[i]);
                a.speed.push(obs.linear_vels_x[i]);
                a.steer.push(obs.steering_angles[i]);
            }
        }
        let racing = |i: usize, faulted: &[Option<f64>]| {
            state.agents[i].status == AgentStatus::Racing && faulted[i].is_none()
        };
        if world.done() || steps >= max_steps || !(0..n).any(|i| racing(i, &faulted)) {
            break;
        }
        let obs = &state.observation;
        for (i, d) in drivers.iter_mut().enumerate() {
            actions[i] = if racing(i, &faulted) {
                let a = d.act(obs, i);
                if d.fault().is_some() {
                    faulted[i] = Some(state.time);
                }
                a
            } else {
                Action::default()
            };
        }
        world.step_into(&actions, &mut events)?;
        for (c, e) in ever_collided.iter_mut().zip(&events.collided) {
            *c |= *e;
        }
        steps += 1;
    }
    let state = world.state()?;
    let agents = state
        .agents
        .iter()
        .zip(&scenario.agents)
        .zip(&ever_collided)
        .zip(&faulted)
        .map(|(((a, spec), &collided), &fault_time)| {
            let termination = match a.status {
                _ if fault_time.is_some() => Termination::Crashed,
                AgentStatus::Finished => Termination::Finished,
                AgentStatus::Crashed => Termination::Crashed,
                AgentStatus::Racing => Termination::TimeLimit,
            };
            let penalty = if termination == Termination::Crashed {
                scenario.crash_penalty
            } else {
                0.0
            };
            AgentResult {
                driver: spec.driver.clone(),
                termination,
                lap_times: a.laps.lap_times.clone(),
                collided: collided || termination == Termination::Crashed,
                progress: a.laps.progress,
                end_time: fault_time.or(a.finish_time),
                episode_return: a.laps.progress - penalty,
            }
        })
        .collect();
    Ok(EpisodeResult {
        seed,
        map: circuit.name.clone(),
        steps,
        time: state.time,
        agents,
        trajectory,
    })
}
