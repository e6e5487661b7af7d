//! ONNX models in the bridge: `DriverSpec::resolve("model.onnx")` loads the very plan a
//! local rollout runs, so one model and one observation give the same action bits in a
//! rollout and in the drive node; a non-finite action holds the car stopped; a model whose
//! scan does not fit the LIDAR is refused before the node starts.

use paddock_bridge::drive::{DriveCore, DriverSpec};
use paddock_bridge::msg::{Header, LaserScan, Odometry, Quaternion, Time};
use paddock_bridge::safety::SafetyConfig;
use paddock_policy::build_driver;
use paddock_policy::onnx::write::{self, D, Model, f32_input, f32_tensor, node};
use paddock_sim::circuit::Circuits;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Observation, Starts, World, WorldConfig};

fn model_file(name: &str, bytes: &[u8]) -> String {
    let dir = std::env::temp_dir().join(format!("paddock-bridge-onnx-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p.to_str().unwrap().to_string()
}

/// action = scans @ w + linear_vels_x * k + prev_action * 0.5 + b: reads the scan, an
/// odometry value and its own previous action.
fn scan_speed_prev_model(beams: usize) -> Model {
    let w: Vec<f32> = (0..beams * 2)
        .map(|i| {
            let (beam, out) = (i / 2, i % 2);
            let side = if beam < beams / 2 { -1.0 } else { 1.0 };
            if out == 0 {
                side * 0.4 / beams as f32
            } else {
                1.5 / beams as f32
            }
        })
        .collect();
    Model::new(
        vec![
            node("MatMul", &["scans", "w"], &["sw"]),
            node("Mul", &["linear_vels_x", "k"], &["vk"]),
            node("Mul", &["prev_action", "half"], &["ph"]),
            node("Add", &["sw", "vk"], &["a1"]),
            node("Add", &["a1", "ph"], &["a2"]),
            node("Add", &["a2", "b"], &["action"]),
        ],
        vec![
            f32_input("scans", &[D::Batch, D::N(beams as i64)]),
            f32_input("linear_vels_x", &[D::Batch, D::N(1)]),
            f32_input("prev_action", &[D::Batch, D::N(2)]),
        ],
    )
    .init(f32_tensor("w", &[beams as i64, 2], &w))
    .init(f32_tensor("k", &[1, 2], &[0.01, 0.2]))
    .init(f32_tensor("half", &[1, 2], &[0.5, 0.5]))
    .init(f32_tensor("b", &[1, 2], &[0.0, 0.3]))
}

/// The scan message the SIL car publishes for car 0 of `obs`.
fn scan_msg(obs: &Observation, lidar: &LidarConfig, t: f64) -> LaserScan {
    let n = lidar.num_beams;
    LaserScan {
        header: Header::new(Time::from_secs(t), "laser"),
        angle_min: (-0.5 * lidar.fov) as f32,
        angle_max: (0.5 * lidar.fov) as f32,
        angle_increment: (lidar.fov / (n - 1) as f64) as f32,
        range_min: 0.0,
        range_max: lidar.max_range as f32,
        ranges: obs.scan(0).iter().map(|&r| r as f32).collect(),
        ..LaserScan::default()
    }
}

/// The odometry message the SIL car publishes for car 0 of `obs`.
fn odom_msg(obs: &Observation, t: f64) -> Odometry {
    let mut o = Odometry {
        header: Header::new(Time::from_secs(t), "map"),
        ..Odometry::default()
    };
    o.pose.pose.position.x = obs.poses_x[0];
    o.pose.pose.position.y = obs.poses_y[0];
    o.pose.pose.orientation = Quaternion::from_yaw(obs.poses_theta[0]);
    o.twist.twist.linear.x = obs.linear_vels_x[0];
    o.twist.twist.linear.y = obs.linear_vels_y[0];
    o.twist.twist.angular.z = obs.ang_vels_z[0];
    o
}

/// The safety layer out of the way: no clamp tighter than the vehicle's, no TTC stop.
fn open_safety(v: &VehicleParams) -> SafetyConfig {
    SafetyConfig {
        max_steer: v.s_max,
        max_speed: v.v_max,
        min_speed: v.v_min,
        sensor_timeout: 10.0,
        ttc_threshold: 0.0,
        max_invalid_ahead: 1.0,
        ..SafetyConfig::default()
    }
}

#[test]
fn a_model_gives_the_same_action_bits_in_a_rollout_and_in_the_bridge() {
    let lidar = LidarConfig::default();
    let path = model_file(
        "scan_speed_prev.onnx",
        &scan_speed_prev_model(lidar.num_beams).bytes(),
    );
    let spec = DriverSpec::resolve(&path, &[]).unwrap();
    assert!(spec.name.starts_with("onnx:"), "{}", spec.name);
    assert_eq!(spec.source, path);
    spec.check_lidar(&lidar).unwrap();
    let circuit = Circuits::new().get("lakeside").unwrap();
    let vehicle = VehicleParams::default();
    // the rollout's driver, by the same registered name
    let mut rollout_driver = build_driver(&spec.name, &[], &circuit, &vehicle).unwrap();
    rollout_driver.reset();
    let mut core = DriveCore::new(
        spec.build(&circuit, &vehicle).unwrap(),
        lidar.clone(),
        open_safety(&vehicle),
    )
    .unwrap();
    assert!(core.lidar_driver());
    let mut world = World::new(circuit.clone(), WorldConfig::default()).unwrap();
    world.reset(3, &Starts::Random).unwrap();
    let mut moved = 0.0;
    for step in 0..300 {
        let t = 0.01 * (step + 1) as f64;
        let obs = world.observation().unwrap().clone();
        let want = rollout_driver.act(&obs, 0);
        assert!(core.on_odom(&odom_msg(&obs, t), t));
        assert!(core.on_scan(&scan_msg(&obs, &lidar, t), t));
        let got = core.command(t).unwrap();
        assert_eq!(got.stop, None, "step {step}: {got:?}");
        assert_eq!(
            (got.action.steer.to_bits(), got.action.speed.to_bits()),
            (want.steer.to_bits(), want.speed.to_bits()),
            "step {step}: bridge {:?} vs rollout {want:?}",
            got.action
        );
        world.step(&[want]).unwrap();
        moved = world.observation().unwrap().progress[0];
    }
    assert!(moved > 2.0, "the model drove {moved} m");
}

#[test]
fn a_nan_action_holds_the_car_stopped() {
    let path = model_file("nan.onnx", &write::nan_when_slow().bytes());
    let spec = DriverSpec::resolve(&path, &[]).unwrap();
    let circuit = Circuits::new().get("lakeside").unwrap();
    let vehicle = VehicleParams::default();
    let mut core = DriveCore::new(
        spec.build(&circuit, &vehicle).unwrap(),
        LidarConfig::default(),
        open_safety(&vehicle),
    )
    .unwrap();
    let mut odom = Odometry::default();
    odom.header.stamp = Time::from_secs(0.01);
    assert!(core.on_odom(&odom, 0.01));
    let v = core.command(0.02).unwrap();
    assert_eq!((v.action.steer, v.action.speed), (0.0, 0.0));
    let fault = core
        .fault()
        .expect("the NaN faulted the driver")
        .to_string();
    assert!(fault.contains("non-finite action"), "{fault}");
    // faster now: the network would give a number, but a faulted driver stays stopped
    let mut odom = Odometry::default();
    odom.header.stamp = Time::from_secs(0.02);
    odom.twist.twist.linear.x = 3.0;
    assert!(core.on_odom(&odom, 0.03));
    let v = core.command(0.04).unwrap();
    assert_eq!((v.action.steer, v.action.speed), (0.0, 0.0));
}

#[test]
fn bad_models_are_refused_naming_the_file() {
    let junk = model_file("junk.onnx", b"not a model");
    let e = DriverSpec::resolve(&junk, &[]).unwrap_err().to_string();
    assert!(e.contains("junk.onnx: not an ONNX model"), "{e}");
    let small = model_file(
        "m64.onnx",
        &write::centering_on_scans(64, 4.7, 0.4, 2.0).bytes(),
    );
    let spec = DriverSpec::resolve(&small, &[]).unwrap();
    let e = spec
        .check_lidar(&LidarConfig::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("m64.onnx: input scans has 64 beams, the vehicle's LIDAR 1080"),
        "{e}"
    );
    let e = DriverSpec::resolve(&small, &[("gain".into(), 1.0)])
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown parameter \"gain\""), "{e}");
    let e = DriverSpec::resolve("no/such/model.onnx", &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("no/such/model.onnx: cannot read it"), "{e}");
}
