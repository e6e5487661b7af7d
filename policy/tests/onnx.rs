//! ONNX policies: the observation contract, bad models refused by name, a NaN action as a
//! fault, determinism across calls and threads, and a rollout. The models are written as
//! protobuf by the tests (`paddock_policy::onnx::write`), so no Python or torch is needed.

use std::sync::Arc;

use paddock_policy::onnx::write::{
    D, Model, f32_input, f32_tensor, linear_on_scans, log_of_x, node, value_info, with_int_attr,
};
use paddock_policy::onnx::{self, OnnxDriver, OnnxError, OnnxPolicy};
use paddock_policy::{Driver, DriverSpec, OnnxModel, PolicyError, build_driver, driver_info};
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, Observation};
use tract_onnx::pb::tensor_proto::DataType;

fn obs_with_scan(scan: &[f64]) -> Observation {
    Observation {
        poses_x: vec![2.0],
        poses_theta: vec![0.25],
        linear_vels_x: vec![3.0],
        ..Observation::one_car(scan.to_vec())
    }
}

fn load(m: &Model) -> Result<OnnxPolicy, OnnxError> {
    OnnxPolicy::from_bytes(&m.bytes(), "test.onnx")
}

fn driver(m: &Model) -> OnnxDriver {
    OnnxDriver::new(
        onnx::NAME,
        Arc::new(load(m).expect("loads")),
        &VehicleParams::default(),
    )
}

/// Weights that are powers of two and scans in halves: every sum is exact in f32 in any
/// order, so the hand computation is exact.
fn linear_8() -> (Model, Vec<f32>, [f32; 2]) {
    let w: Vec<f32> = (0..8)
        .flat_map(|i| [if i < 4 { 0.125 } else { -0.125 }, 0.25])
        .collect();
    let b = [0.0, 0.5];
    (linear_on_scans(8, &w, b), w, b)
}

#[test]
fn linear_model_on_scans_gives_the_hand_computed_action() {
    let (m, w, b) = linear_8();
    let scan = [1.0, 1.5, 2.0, 2.5, 0.5, 1.0, 1.0, 3.0];
    let mut expect = b;
    for (i, r) in scan.iter().enumerate() {
        expect[0] += *r as f32 * w[2 * i];
        expect[1] += *r as f32 * w[2 * i + 1];
    }
    // 0.125 * (7 - 5.5) = 0.1875 steering; 0.5 + 0.25 * 12.5 = 3.625 m/s
    assert_eq!(expect, [0.1875, 3.625]);
    let policy = load(&m).unwrap();
    assert_eq!(policy.beams(), Some(8));
    assert_eq!(
        policy.infer(&obs_with_scan(&scan), 0, [0.0; 2]).unwrap(),
        expect
    );
    let a = driver(&m).act(&obs_with_scan(&scan), 0);
    assert_eq!(a, Action::new(0.1875, 3.625));
}

#[test]
fn actions_are_clamped_to_the_vehicle() {
    let w = vec![1.0f32; 16];
    let m = linear_on_scans(8, &w, [0.0, 0.0]);
    let v = VehicleParams::default();
    let mut d = driver(&m);
    let a = d.act(&obs_with_scan(&[10.0; 8]), 0);
    assert_eq!(a, Action::new(v.s_max, v.v_max));
    let a = d.act(&obs_with_scan(&[-10.0; 8]), 0);
    assert_eq!(a, Action::new(v.s_min, v.v_min));
}

#[test]
fn a_subset_of_scalar_inputs_and_the_previous_action() {
    let m = paddock_policy::onnx::write::scalars_and_prev([0.5, 2.0]);
    let policy = load(&m).unwrap();
    assert_eq!(policy.beams(), None);
    let names: Vec<&str> = policy.inputs().iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names.len(), 3);
    for n in ["poses_theta", "linear_vels_x", "prev_action"] {
        assert!(names.contains(&n), "{names:?}");
    }
    let mut d = driver(&m);
    assert!(!d.sensors().lidar, "no scans input: no LIDAR");
    let obs = obs_with_scan(&[]);
    // theta 0.25, v 3: [0.125, 6] + prev (0, 0)
    assert_eq!(d.act(&obs, 0), Action::new(0.125, 6.0));
    // + prev (0.125, 6) -> [0.25, 12], speed clamped to v_max
    let v = VehicleParams::default();
    assert_eq!(d.act(&obs, 0), Action::new(0.25, 12.0_f64.min(v.v_max)));
    d.reset();
    assert_eq!(
        d.act(&obs, 0),
        Action::new(0.125, 6.0),
        "reset forgets prev_action"
    );
}

#[test]
fn action_repeat_metadata_holds_each_action() {
    let (m, _, _) = linear_8();
    let m = m.meta(onnx::META_ACTION_REPEAT, "3");
    let mut d = driver(&m);
    let obs = |r: f64| obs_with_scan(&[r; 8]);
    // speed = 0.5 + 0.25 * 8 r = 0.5 + 2 r
    let speeds: Vec<f64> = [1.0, 2.0, 3.0, 1.5, 0.5]
        .iter()
        .map(|&r| d.act(&obs(r), 0).speed)
        .collect();
    assert_eq!(speeds, [2.5, 2.5, 2.5, 3.5, 3.5]);
    let bad = linear_8().0.meta(onnx::META_ACTION_REPEAT, "0");
    assert!(
        matches!(load(&bad), Err(OnnxError::Metadata { key, .. }) if key == "paddock.action_repeat")
    );
}

#[test]
fn beam_count_and_field_of_view_are_checked_against_the_lidar() {
    let (m, _, _) = linear_8();
    let lidar = |n: usize, fov: f64| LidarConfig {
        num_beams: n,
        fov,
        ..LidarConfig::default()
    };
    let p = load(&m).unwrap();
    p.check_lidar(&lidar(8, 4.7)).unwrap();
    let e = p.check_lidar(&lidar(1080, 4.7)).unwrap_err();
    assert_eq!(
        e.to_string(),
        "model test.onnx: input scans has 8 beams, the vehicle's LIDAR 1080"
    );
    let p = load(&linear_8().0.meta(onnx::META_LIDAR_FOV, "3.0")).unwrap();
    assert_eq!(p.lidar_fov(), Some(3.0));
    p.check_lidar(&lidar(8, 3.0)).unwrap();
    assert!(matches!(
        p.check_lidar(&lidar(8, 4.7)),
        Err(OnnxError::FieldOfView { .. })
    ));
    // at run time a scan of another size faults the driver rather than panicking
    let mut d = driver(&m);
    assert_eq!(d.act(&obs_with_scan(&[1.0; 9]), 0), OnnxDriver::STOP);
    assert!(d.fault().unwrap().contains("8 beams"), "{:?}", d.fault());
}

fn refused(m: &Model) -> String {
    load(m).expect_err("refused").to_string()
}

#[test]
fn wrong_input_names_and_shapes_are_refused_naming_the_input() {
    let unknown = Model::new(
        vec![node("Identity", &["lidar"], &["action"])],
        vec![f32_input("lidar", &[D::Batch, D::N(2)])],
    );
    let e = refused(&unknown);
    assert!(
        e.starts_with(
            "model test.onnx: input \"lidar\" is not an observation key (known: scans, poses_x"
        ),
        "{e}"
    );

    let cases: [(&str, &[D], &str); 6] = [
        (
            "scans",
            &[D::Batch],
            "input \"scans\" has shape [?], expected [batch, beams] with a fixed beam count",
        ),
        (
            "scans",
            &[D::Batch, D::Batch],
            "input \"scans\" has shape [?, ?], expected [batch, beams]",
        ),
        (
            "scans",
            &[D::N(4), D::N(8)],
            "input \"scans\" has shape [4, 8], expected [batch, beams]",
        ),
        (
            "poses_x",
            &[D::Batch, D::N(3)],
            "input \"poses_x\" has shape [?, 3], expected [batch] or [batch, 1]",
        ),
        (
            "poses_x",
            &[D::Batch, D::N(1), D::N(1)],
            "input \"poses_x\" has shape [?, 1, 1], expected [batch] or [batch, 1]",
        ),
        (
            "prev_action",
            &[D::Batch, D::N(3)],
            "input \"prev_action\" has shape [?, 3], expected [batch, 2]",
        ),
    ];
    for (name, dims, want) in cases {
        let m = Model::new(
            vec![node("Identity", &[name], &["action"])],
            vec![f32_input(name, dims)],
        );
        let e = refused(&m);
        assert!(e.contains(want), "{name} {e}");
    }
    let double = Model::new(
        vec![node("Identity", &["scans"], &["action"])],
        vec![value_info("scans", DataType::Double, &[D::Batch, D::N(2)])],
    );
    assert_eq!(
        refused(&double),
        "model test.onnx: input \"scans\" has element type double, expected float32"
    );
    let none = Model::new(vec![node("Constant", &[], &["action"])], vec![]);
    assert!(refused(&none).contains("no inputs"));
}

#[test]
fn outputs_of_the_wrong_shape_are_refused() {
    // [batch, 3]
    let m = linear_on_scans(2, &[1.0; 4], [0.0; 2]);
    let three = Model {
        initializers: vec![
            f32_tensor("w", &[2, 3], &[1.0; 6]),
            f32_tensor("b", &[3], &[0.0; 3]),
        ],
        outputs: vec![f32_input("action", &[D::Batch, D::N(3)])],
        ..m
    };
    let e = refused(&three);
    assert!(e.contains("expected float32 [batch, 2]"), "{e}");
    // [batch, 2, 1]... rank 1 here: a ReduceSum to [batch]
    let flat = Model::new(
        vec![with_int_attr(
            node("ReduceSum", &["scans"], &["action"]),
            "keepdims",
            0,
        )],
        vec![f32_input("scans", &[D::Batch, D::N(2)])],
    );
    assert!(refused(&flat).contains("expected float32 [batch, 2]"));
    // two outputs, none called "action"
    let two = Model {
        nodes: vec![
            node("Identity", &["scans"], &["mean"]),
            node("Identity", &["scans"], &["value"]),
        ],
        outputs: vec![
            f32_input("mean", &[D::Batch, D::N(2)]),
            f32_input("value", &[D::Batch, D::N(2)]),
        ],
        ..Model::new(vec![], vec![f32_input("scans", &[D::Batch, D::N(2)])])
    };
    assert_eq!(
        refused(&two),
        "model test.onnx: 2 outputs (mean, value) and none named \"action\""
    );
    // ... but an output named "action" among others is picked
    let mut named = two;
    named.nodes[1].output[0] = "action".into();
    named.outputs[1].name = "action".into();
    load(&named).expect("the output named action is used");
}

#[test]
fn files_that_are_not_onnx_or_too_large_are_refused() {
    for bytes in [&b""[..], b"hello, not a model", &[0xff; 64]] {
        let e = OnnxPolicy::from_bytes(bytes, "x.onnx").unwrap_err();
        assert!(matches!(e, OnnxError::NotOnnx { .. }), "{e}");
        assert!(
            e.to_string().starts_with("model x.onnx: not an ONNX model"),
            "{e}"
        );
    }
    let big = vec![0u8; onnx::MAX_MODEL_BYTES + 1];
    assert!(matches!(
        OnnxPolicy::from_bytes(&big, "big.onnx"),
        Err(OnnxError::TooLarge { .. })
    ));
    assert!(matches!(
        OnnxModel::from_bytes(big, None),
        Err(PolicyError::Onnx(OnnxError::TooLarge { .. }))
    ));
    // a file over the cap is refused from its size, before it is read (sparse file)
    let dir = std::env::temp_dir().join(format!("paddock-onnx-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("huge.onnx");
    let f = std::fs::File::create(&path).unwrap();
    f.set_len(onnx::MAX_MODEL_BYTES as u64 + 1).unwrap();
    let e = DriverSpec::parse(path.to_str().unwrap()).unwrap_err();
    assert!(
        e.to_string().contains("over the 67108864-byte limit"),
        "{e}"
    );
    let missing = DriverSpec::parse("no/such/model.onnx").unwrap_err();
    assert!(
        missing
            .to_string()
            .starts_with("model no/such/model.onnx: cannot read it"),
        "{missing}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_nan_action_faults_the_driver_which_stops_the_car() {
    let mut d = driver(&log_of_x());
    let mut obs = obs_with_scan(&[]);
    let a = d.act(&obs, 0);
    // ln 2 twice: the speed as is, the steering clamped to the car's limit
    assert_eq!(
        a,
        Action::new(VehicleParams::default().s_max, (2.0f32).ln() as f64)
    );
    assert!(d.fault().is_none());
    obs.poses_x[0] = -1.0;
    assert_eq!(d.act(&obs, 0), OnnxDriver::STOP);
    let why = d.fault().expect("faulted").to_string();
    assert_eq!(
        why,
        "model test.onnx: non-finite action (steering NaN, speed NaN)"
    );
    obs.poses_x[0] = 2.0;
    assert_eq!(d.act(&obs, 0), OnnxDriver::STOP, "a fault latches");
    d.reset();
    assert!(d.fault().is_none());
    assert_eq!(d.act(&obs, 0), a);
}

#[test]
fn same_observation_same_bits_across_calls_and_threads() {
    let beams = 1080;
    let w: Vec<f32> = (0..beams * 2)
        .map(|i| ((i * 7919) % 1000) as f32 * 1e-4 - 0.05)
        .collect();
    let m = linear_on_scans(beams, &w, [0.01, 1.0]);
    let policy = Arc::new(load(&m).unwrap());
    let scans: Vec<Vec<f64>> = (0..16)
        .map(|k| {
            (0..beams)
                .map(|i| 0.5 + ((i * 31 + k * 17) % 97) as f64 * 0.3)
                .collect()
        })
        .collect();
    let run = |p: Arc<OnnxPolicy>| -> Vec<(u32, u32)> {
        scans
            .iter()
            .map(|s| {
                let [a, b] = p.infer(&obs_with_scan(s), 0, [0.0; 2]).unwrap();
                (a.to_bits(), b.to_bits())
            })
            .collect()
    };
    let first = run(policy.clone());
    assert_eq!(run(policy.clone()), first);
    let threads: Vec<_> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..4)
            .map(|_| {
                let p = policy.clone();
                let run = &run;
                s.spawn(move || run(p))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for t in threads {
        assert_eq!(t, first);
    }
    // a second load of the same bytes gives the same bits too
    assert_eq!(run(Arc::new(load(&m).unwrap())), first);
}

#[test]
fn registered_models_have_names_the_registry_builds() {
    let (m, _, _) = linear_8();
    let bytes = m.bytes();
    let name = onnx::register(&bytes, "lin8.onnx").unwrap();
    assert_eq!(name, format!("onnx:{}", onnx::model_hash(&bytes)));
    assert_eq!(
        onnx::register(&bytes, "again").unwrap(),
        name,
        "registered once"
    );
    let info = driver_info(name).unwrap();
    assert_eq!(info.name, name);
    assert!(info.sensors.lidar && info.params.is_empty());
    let circuit = paddock_sim::circuit::Circuits::new()
        .get("lakeside")
        .unwrap();
    let mut d = build_driver(name, &[], &circuit, &VehicleParams::default()).unwrap();
    assert_eq!(d.name(), name);
    assert_eq!(d.act(&obs_with_scan(&[1.0; 8]), 0), Action::new(0.0, 2.5));
    assert!(matches!(
        build_driver(name, &[1.0], &circuit, &VehicleParams::default()),
        Err(PolicyError::ParamCount {
            expected: 0,
            got: 1,
            ..
        })
    ));
    // an unregistered hash is unknown: names never open files
    let e = driver_info(&format!("onnx:{}", "0".repeat(64))).unwrap_err();
    assert!(matches!(e, PolicyError::UnknownDriver { .. }), "{e}");
    assert!(matches!(
        driver_info("model.onnx"),
        Err(PolicyError::UnknownDriver { .. })
    ));
    // a spec from a file registers the same model under the same name
    let path = std::env::temp_dir().join(format!("paddock-lin8-{}.onnx", std::process::id()));
    std::fs::write(&path, &bytes).unwrap();
    let spec = DriverSpec::parse(path.to_str().unwrap()).unwrap();
    std::fs::remove_file(&path).unwrap();
    let DriverSpec::Onnx(model) = &spec else {
        panic!("{spec:?}")
    };
    assert_eq!(model.hash(), onnx::model_hash(&bytes));
    assert_eq!(spec.register().unwrap(), name);
    assert_eq!(
        DriverSpec::parse("pure-pursuit").unwrap(),
        DriverSpec::Named("pure-pursuit".into())
    );
}
