//! An ONNX model drives the SIL car over ROS 2 for a lap, as `paddock bridge drive
//! --driver model.onnx` does, and its lap matches the plain rollout of the same model
//! from the same start within the bridge's transport tolerance.
//!
//! The model reads the scan, so the drive node acts on every scan: the SIL publishes a
//! scan every physics step (100 Hz), as a rollout feeds its driver, and runs at `RATE`
//! times real time.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread;
use std::time::Duration;

use paddock_bridge::drive::{DriveCore, DriveOptions, DriverSpec, run_drive};
use paddock_bridge::ros::RosConfig;
use paddock_bridge::safety::SafetyConfig;
use paddock_bridge::sil::SilOptions;
use paddock_policy::onnx::write;
use paddock_rollout::{AgentSpec, Scenario, StartSpec, run_episode};
use paddock_sim::circuit::Circuits;
use paddock_sim::collision::CollisionMode;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Starts, World, WorldConfig};

mod common;
use common::SilThread;

const MAP: &str = "lakeside";
const RATE: f64 = 2.0;

#[test]
fn an_onnx_model_laps_the_sil_car_like_a_rollout() {
    let lidar = LidarConfig::default();
    let bytes = write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.5).bytes();
    let dir = std::env::temp_dir().join(format!("paddock-onnx-loop-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("centering.onnx");
    std::fs::write(&path, &bytes).unwrap();
    let spec = DriverSpec::resolve(path.to_str().unwrap(), &[]).unwrap();

    // the plain rollout from the SIL's start (its grid at s = 0, LIDAR noise from seed 0)
    let circuit = Circuits::new().get(MAP).unwrap();
    let world = World::new(circuit.clone(), WorldConfig::default()).unwrap();
    let start = world.start_poses_for(0, &Starts::Grid { s: 0.0 }).unwrap();
    let scenario = Scenario {
        map: MAP.into(),
        agents: vec![AgentSpec::with_defaults(&spec.name).unwrap()],
        starts: StartSpec::Poses(start),
        laps: 1,
        time_limit: 120.0,
        collision_mode: CollisionMode::Terminate,
        ..Scenario::single(&spec.name).unwrap()
    };
    let expected = run_episode(&paddock_sim::circuit::Circuits::new(), &scenario, 0, None)
        .unwrap()
        .agents[0]
        .lap_times
        .clone();
    assert_eq!(expected.len(), 1, "the rollout itself must lap");

    let ros = RosConfig {
        domain_id: 67,
        ..RosConfig::default()
    };
    let sil = SilThread::start(
        SilOptions {
            map: MAP.into(),
            rate: RATE,
            scan_hz: 100.0,
            laps: Some(1),
            seconds: Some(120.0),
            wait_for_drive: true,
            ..SilOptions::default()
        },
        &ros,
    );
    let stop = Arc::new(AtomicBool::new(false));
    let drive = {
        let (ros, stop, spec) = (ros.clone(), stop.clone(), spec.clone());
        thread::spawn(move || {
            let circuit = Circuits::new().get(MAP).unwrap();
            let options = DriveOptions {
                safety: SafetyConfig {
                    max_speed: 20.0,
                    sensor_timeout: 0.5,
                    ..SafetyConfig::default()
                },
                ..DriveOptions::default()
            };
            spec.check_lidar(&options.lidar).unwrap();
            let driver = spec.build(&circuit, &VehicleParams::default()).unwrap();
            let core = DriveCore::new(driver, options.lidar.clone(), options.safety).unwrap();
            run_drive(core, &ros, &options, &stop)
        })
    };
    let mut waited = 0.0;
    while !sil.is_finished() && waited < 150.0 {
        thread::sleep(Duration::from_millis(100));
        waited += 0.1;
    }
    let sil = sil.stop();
    stop.store(true, Ordering::Relaxed);
    let drive = drive.join().unwrap().unwrap();
    eprintln!("rollout lap {expected:?}; SIL {sil:?}; drive {drive:?}");
    assert_eq!(drive.trigger, "scan", "a LIDAR model acts on every scan");
    assert_eq!(drive.fault, None);
    assert_eq!(sil.lap_times[0].len(), 1, "SIL laps: {sil:?}");
    assert_eq!(sil.collision_steps[0], 0);
    let (got, want) = (sil.lap_times[0][0], expected[0]);
    let rel = (got - want).abs() / want;
    assert!(
        rel < 0.01,
        "SIL lap {got:.3} s vs rollout {want:.3} s ({:.2} %)",
        rel * 1e2
    );
}
