//! The ROS 2 loop on the command line, as a user runs it: `paddock bridge sil` and
//! `paddock bridge drive --driver model.onnx` as two processes over ROS 2 (DDS on
//! loopback, a domain of their own). The SIL car runs at twice real time, so this test
//! times a real-time loop: it lives with the other end-to-end tests, which
//! `scripts/test.sh` runs at normal priority (its "timed" track).

use std::process::{Command, Stdio};

use paddock_e2e::paddock_bin;
use paddock_policy::onnx::write;
use paddock_rollout::{AgentSpec, Scenario, StartSpec, run_episode};
use paddock_sim::circuit::Circuits;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::world::{Starts, World, WorldConfig};

/// The loop on the command line, as a user runs it: `paddock bridge sil` and `paddock
/// bridge drive --driver model.onnx` as two processes over ROS 2 (DDS on loopback, a
/// domain of their own); the SIL car's lap matches the plain rollout of the same model
/// from the SIL's start within the bridge's transport tolerance (1 %).
#[test]
fn bridge_drive_laps_the_sil_car_with_a_model_file_like_a_rollout() {
    let dir = tempfile::tempdir().unwrap();
    let lidar = LidarConfig::default();
    let bytes = write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.5).bytes();
    let path = dir.path().join("centering.onnx");
    std::fs::write(&path, &bytes).unwrap();
    let path = path.to_str().unwrap().to_string();

    // the rollout from the SIL's start: its grid at s = 0, LIDAR noise from seed 0
    let name = paddock_policy::onnx::register(&bytes, "centering.onnx").unwrap();
    let circuit = Circuits::new().get("lakeside").unwrap();
    let world = World::new(circuit, WorldConfig::default()).unwrap();
    let scenario = Scenario {
        map: "lakeside".into(),
        agents: vec![AgentSpec::with_defaults(name).unwrap()],
        starts: StartSpec::Poses(world.start_poses_for(0, &Starts::Grid { s: 0.0 }).unwrap()),
        laps: 1,
        time_limit: 120.0,
        ..Scenario::single(name).unwrap()
    };
    let want = run_episode(&paddock_sim::circuit::Circuits::new(), &scenario, 0, None)
        .unwrap()
        .agents[0]
        .lap_times[0];

    let exe = paddock_bin();
    let domain = "69";
    let sil = Command::new(&exe)
        .args([
            "bridge",
            "sil",
            "--map",
            "lakeside",
            "--rate",
            "2",
            "--scan-hz",
            "100",
            "--laps",
            "1",
            "--seconds",
            "120",
            "--wait-for-drive",
            "--json",
            "--domain-id",
            domain,
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let drive = Command::new(&exe)
        .args([
            "bridge",
            "drive",
            "--driver",
            &path,
            "--max-speed",
            "20",
            "--sensor-timeout",
            "0.5",
            "--domain-id",
            domain,
            "--seconds",
            "100",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // the SIL ends by itself after the lap (at most 120 simulated s at 2x)
    let sil = sil.wait_with_output().unwrap();
    // SIGINT: the drive node's clean stop (zero speed, its summary)
    let stopped = Command::new("kill")
        .args(["-INT", &drive.id().to_string()])
        .status()
        .unwrap();
    assert!(stopped.success());
    let drive = drive.wait_with_output().unwrap();
    let (drive_out, drive_err) = (
        String::from_utf8_lossy(&drive.stdout),
        String::from_utf8_lossy(&drive.stderr),
    );
    assert!(drive.status.success(), "{drive_out}\n{drive_err}");
    assert!(
        drive_err.contains("centering.onnx (onnx:") && drive_out.contains("zero speed sent"),
        "{drive_out}\n{drive_err}"
    );
    assert!(
        !drive_out.contains("faulted"),
        "the model did not fault: {drive_out}"
    );
    assert!(
        sil.status.success(),
        "{}",
        String::from_utf8_lossy(&sil.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&sil.stdout).unwrap();
    let got = summary["lap_times"][0][0]
        .as_f64()
        .unwrap_or_else(|| panic!("the SIL car lapped: {summary}"));
    assert_eq!(summary["collision_steps"][0], 0, "{summary}");
    let rel = (got - want).abs() / want;
    eprintln!("SIL lap {got:.3} s, rollout {want:.3} s; drive node: {drive_out}");
    assert!(
        rel < 0.01,
        "SIL lap {got:.3} s vs rollout {want:.3} s ({:.2} %)",
        rel * 1e2
    );
}
