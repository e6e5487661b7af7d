//! Self-play: two learner cars of one vector-env copy, driven by the same ONNX model, race
//! benchmark B3's head-to-head (the same starts, grid swapped in the second race of a
//! pair), and the races are the benchmark's, bit for bit: lap times, progress, ends.
//!
//! The learners' actions travel as `f32` (the wire's type), the benchmark's drivers act in
//! `f64`. A model's raw output is `f32`, so the two agree exactly unless the action is
//! clamped to a vehicle limit that `f32` cannot hold; the test's vehicle has its steering
//! limits at `f32` values so that clamped actions agree too.

use std::sync::Arc;

use paddock_policy::onnx::{self, write};
use paddock_policy::{Driver, build_driver};
use paddock_rollout::benchmark::{BenchmarkSpec, Task};
use paddock_rollout::env::{EnvConfig, VecEnv};
use paddock_rollout::{AgentSpec, Executor, LocalExecutor};
use paddock_sim::circuit::{Circuit, DEFAULT_MAP};
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{AgentStatus, Starts};

const LAPS: u32 = 1;
const TIME_LIMIT: f64 = 60.0;

fn vehicle() -> VehicleParams {
    let v = VehicleParams::default();
    VehicleParams {
        s_min: f64::from(v.s_min as f32),
        s_max: f64::from(v.s_max as f32),
        ..v
    }
}

/// One race of two learners in a fresh 1-copy session started from `seed` (the grid
/// `swapped` as B3's second race of a pair does): each car's lap times, progress and
/// whether it finished, and the race's steps.
fn self_play_race(model: &str, seed: u64, swapped: bool) -> (Vec<(Vec<f64>, f64, bool)>, u64) {
    let mut config = EnvConfig::single(DEFAULT_MAP, 1, 0);
    config.learners = 2;
    config.vehicle = vehicle();
    config.laps = LAPS;
    config.time_limit = TIME_LIMIT;
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), config).unwrap();
    let mut poses = env
        .world(0)
        .unwrap()
        .start_poses_for(seed, &Starts::Random)
        .unwrap();
    if swapped {
        poses.reverse();
    }
    env.reset(&[0], &[seed], Some(&poses)).unwrap();
    let circuit: Arc<Circuit> = env.circuit().clone();
    let mut drivers: Vec<Box<dyn Driver>> = (0..2)
        .map(|_| build_driver(model, &[], &circuit, &vehicle()).unwrap())
        .collect();
    for d in &mut drivers {
        d.reset();
    }
    let mut actions = [0f32; 4];
    while !env.frame().ended(0) {
        let obs = env.world(0).unwrap().observation().unwrap();
        for (k, d) in drivers.iter_mut().enumerate() {
            let a = d.act(obs, k);
            assert!(d.fault().is_none());
            // exactly representable: the raw f32 output, or a limit that is an f32
            assert_eq!(f64::from(a.steer as f32), a.steer);
            assert_eq!(f64::from(a.speed as f32), a.speed);
            actions[2 * k] = a.steer as f32;
            actions[2 * k + 1] = a.speed as f32;
        }
        env.step(&actions, &[]).unwrap();
    }
    let state = env.world(0).unwrap().state().unwrap();
    let cars = state
        .agents
        .iter()
        .map(|a| {
            (
                a.laps.lap_times.clone(),
                a.laps.progress,
                a.status == AgentStatus::Finished,
            )
        })
        .collect();
    (cars, state.steps)
}

#[test]
fn two_learner_cars_race_b3_head_to_head_as_the_benchmark_does() {
    let lidar = LidarConfig::default();
    let model = write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.5).bytes();
    let name = onnx::register(&model, "centering.onnx").unwrap();
    let mut car = AgentSpec::with_defaults(name).unwrap();
    car.vehicle = vehicle();
    let spec = BenchmarkSpec {
        task: Task::B3,
        map: DEFAULT_MAP.into(),
        driver: car.clone(),
        opponent: Some(car),
        episodes: 2,
        seed: 11,
        laps: LAPS,
        obstacles: 0,
        time_limit: TIME_LIMIT,
    };
    let tasks = spec.tasks().unwrap();
    let results = LocalExecutor::new(1, paddock_sim::circuit::Circuits::new())
        .unwrap()
        .run_batch(&tasks, &|_| {});
    let mut finished = 0;
    for (k, (task, result)) in tasks.iter().zip(results).enumerate() {
        let episode = result.unwrap();
        let (cars, steps) = self_play_race(name, task.seed, k % 2 == 1);
        assert_eq!(steps, episode.steps, "race {k}: steps");
        for (i, (got, want)) in cars.iter().zip(&episode.agents).enumerate() {
            assert_eq!(got.0, want.lap_times, "race {k} car {i}: lap times");
            assert_eq!(
                got.1.to_bits(),
                want.progress.to_bits(),
                "race {k} car {i}: progress"
            );
            assert_eq!(
                got.2,
                want.termination == paddock_rollout::Termination::Finished,
                "race {k} car {i}: finished"
            );
            finished += usize::from(got.2);
        }
    }
    // a race, not two parked cars: the reference model laps the default map
    assert!(finished >= 2, "{finished} of 4 cars finished");
}
