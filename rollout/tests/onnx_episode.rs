//! ONNX models in a rollout: run by their registered name like any driver, the scan
//! checked against the scenario's LIDAR, a NaN action ending the car's episode as a crash,
//! and the same result on every run.

use paddock_policy::onnx::{self, write};
use paddock_rollout::{RolloutError, Scenario, Termination, run_episode};
use paddock_sim::lidar::LidarConfig;

fn scenario(driver: &str) -> Scenario {
    let mut s = Scenario::single(driver).expect("registered");
    s.time_limit = 20.0;
    s
}

#[test]
fn a_linear_model_drives_a_deterministic_episode() {
    let lidar = LidarConfig::default();
    let model = write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.0).bytes();
    let name = onnx::register(&model, "centering.onnx").unwrap();
    let s = scenario(name);
    assert_eq!(s.agents[0].driver, name);
    let a = run_episode(&paddock_sim::circuit::Circuits::new(), &s, 7, Some(50)).unwrap();
    let b = run_episode(&paddock_sim::circuit::Circuits::new(), &s, 7, Some(50)).unwrap();
    assert_eq!(a, b);
    let car = &a.agents[0];
    assert!(car.progress > 10.0, "{car:?}");
    // it drove at the model's 2 m/s
    let tr = &a.trajectory.as_ref().unwrap().agents[0];
    let top = tr.speed.iter().cloned().fold(0.0, f64::max);
    assert!((top - 2.0).abs() < 0.05, "top speed {top}");
}

#[test]
fn a_scan_of_the_wrong_size_is_refused_before_the_episode() {
    let name = onnx::register(
        &write::centering_on_scans(64, 4.7, 0.4, 2.0).bytes(),
        "m64.onnx",
    )
    .unwrap();
    let e = run_episode(
        &paddock_sim::circuit::Circuits::new(),
        &scenario(name),
        1,
        None,
    )
    .unwrap_err();
    assert!(matches!(e, RolloutError::Driver { agent: 0, .. }), "{e}");
    assert!(
        e.to_string()
            .contains("model m64.onnx: input scans has 64 beams, the vehicle's LIDAR 1080"),
        "{e}"
    );
}

#[test]
fn a_nan_action_ends_the_episode_as_a_crash() {
    let name = onnx::register(&write::nan_when_slow().bytes(), "nan.onnx").unwrap();
    let mut s = scenario(name);
    s.agents
        .push(paddock_rollout::AgentSpec::with_defaults("pure-pursuit").unwrap());
    let r = run_episode(&paddock_sim::circuit::Circuits::new(), &s, 3, None).unwrap();
    let nan = &r.agents[0];
    assert_eq!(nan.termination, Termination::Crashed);
    assert_eq!(nan.end_time, Some(0.0));
    assert_eq!(nan.episode_return, nan.progress - s.crash_penalty);
    // the other car races on
    assert!(r.agents[1].progress > 10.0, "{:?}", r.agents[1]);
    // alone, the episode ends at once
    let alone = run_episode(
        &paddock_sim::circuit::Circuits::new(),
        &scenario(name),
        3,
        None,
    )
    .unwrap();
    assert_eq!(alone.steps, 1, "the stop action of the faulting step");
    assert_eq!(alone.agents[0].termination, Termination::Crashed);
}
