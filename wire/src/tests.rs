//! Round trips and refusals of the scenario and result conversions.

use std::sync::Arc;

use paddock_proto::ErrorCode;
use paddock_rollout::{AgentSpec, EpisodeTask, Scenario, StartSpec, run_episode};
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::Pose;

use crate::*;

fn scenario() -> Scenario {
    let mut s = Scenario::single("pure-pursuit").unwrap();
    s.time_limit = 3.0;
    s.agents
        .push(AgentSpec::with_defaults("follow-the-gap").unwrap());
    s.agents[1].vehicle.m = 3.0 + 0.1 + 0.2; // not exactly representable
    s.agents[1].params[0] *= 1.0 + f64::EPSILON;
    s.lidar.num_beams = 270;
    s.obstacles.count = 2;
    s.collision_mode = CollisionMode::Stop;
    s
}

/// The project's lakeside folder: the files of the shipped map.
fn map_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../maps/lakeside")
        .canonicalize()
        .unwrap()
}

#[test]
fn scenario_round_trips_bit_for_bit() {
    let s = scenario();
    let bundle = local_map(&paddock_sim::circuit::Circuits::new(), &s.map).unwrap();
    assert_eq!(bundle.name, "lakeside");
    paddock_proto::check_bundle(&bundle).unwrap();
    let wire = scenario_to_proto(&s, map_ref(&bundle));
    // through bytes, as on the socket
    let bytes = prost::Message::encode_to_vec(&wire);
    let wire: paddock_proto::Scenario = prost::Message::decode(bytes.as_slice()).unwrap();
    let back = scenario_from_proto(&wire, &map_dir()).unwrap();
    let mut expected = s.clone();
    expected.map = map_dir().display().to_string();
    assert_eq!(back, expected);
    let mut poses = s.clone();
    poses.agents.truncate(1);
    poses.starts = StartSpec::Poses(vec![Pose {
        x: 0.1,
        y: -2.5,
        theta: 1.0 / 3.0,
    }]);
    let back =
        scenario_from_proto(&scenario_to_proto(&poses, map_ref(&bundle)), &map_dir()).unwrap();
    assert_eq!(back.starts, poses.starts);
}

#[test]
fn bad_values_are_named() {
    let s = scenario();
    let bundle = local_map(&paddock_sim::circuit::Circuits::new(), &s.map).unwrap();
    let good = scenario_to_proto(&s, map_ref(&bundle));
    let dir = map_dir();
    let check = |mutate: &dyn Fn(&mut paddock_proto::Scenario), field: &str| {
        let mut w = good.clone();
        mutate(&mut w);
        let e = scenario_from_proto(&w, &dir).unwrap_err();
        assert_eq!(e.code, ErrorCode::InvalidArgument as i32, "{e:?}");
        assert_eq!(e.field, field, "{e:?}");
        assert!(!e.message.is_empty());
    };
    check(&|w| w.agents[1].params[2] = f64::NAN, "agents[1].params[2]");
    check(&|w| w.agents[0].params[0] = 1e9, "agents[0].params[0]");
    check(
        &|w| w.agents[0].params.pop().map(|_| ()).unwrap(),
        "agents[0].params",
    );
    check(
        &|w| w.agents[1].driver = "nobody".into(),
        "agents[1].driver",
    );
    check(&|w| w.time_limit = f64::NAN, "time_limit");
    check(&|w| w.laps = 0, "laps");
    check(&|w| w.crash_penalty = -1.0, "crash_penalty");
    check(&|w| w.start_kind = 17, "start_kind");
    check(&|w| w.collision_mode = -3, "collision_mode");
    check(
        &|w| w.lidar.as_mut().unwrap().num_beams = 0,
        "lidar.num_beams",
    );
    check(
        &|w| w.lidar.as_mut().unwrap().fov = f64::INFINITY,
        "lidar.fov",
    );
    check(
        &|w| w.obstacles.as_mut().unwrap().count = 5000,
        "obstacles.count",
    );
    check(&|w| w.agents.clear(), "agents");
    check(
        &|w| w.agents[0].vehicle_yaml = "m: .nan\n".into(),
        "agents[0].vehicle_yaml.m",
    );
    check(
        &|w| w.agents[0].vehicle_yaml = "m: [1, 2\n".into(),
        "agents[0].vehicle_yaml",
    );
    check(
        &|w| {
            w.start_kind = paddock_proto::StartKind::StartPoses as i32;
            w.start_poses = vec![paddock_proto::Pose {
                x: f64::NAN,
                y: 0.0,
                theta: 0.0,
            }];
        },
        "start_poses[0].x",
    );
    let mut bad = good.clone();
    bad.laps = 0;
    let e = scenario_from_bytes(&prost::Message::encode_to_vec(&bad), &dir).unwrap_err();
    assert_eq!(e.field, "laps");
    let e = scenario_from_bytes(&[0xff, 0xff, 0x01], &dir).unwrap_err();
    assert_eq!(e.code, ErrorCode::BadMessage as i32);
    let e = with_prefix(crate::invalid("agents[1].params[2]", "x"), "scenarios[0]");
    assert_eq!(e.field, "scenarios[0].agents[1].params[2]");
}

#[test]
fn results_round_trip_bit_for_bit() {
    let mut s = scenario();
    s.agents.truncate(1);
    s.time_limit = 1.5;
    let local = run_episode(&paddock_sim::circuit::Circuits::new(), &s, 7, Some(5)).unwrap();
    assert!(local.trajectory.as_ref().unwrap().t.len() > 10);
    let bytes = outcome_to_bytes(&Ok(local.clone()));
    assert_eq!(outcome_from_bytes(&bytes).unwrap(), local);
    assert!(outcome_from_bytes(&[0xff, 0xff]).is_err());

    // the same episode run from the wire scenario (map from its directory) is equal
    let bundle = local_map(&paddock_sim::circuit::Circuits::new(), &s.map).unwrap();
    let bytes = prost::Message::encode_to_vec(&scenario_to_proto(&s, map_ref(&bundle)));
    let assign = paddock_proto::TaskAssign {
        task_id: 9,
        scenario_hash: paddock_proto::blob_hash(&bytes),
        seed: 7,
        record_decimation: record_to_proto(Some(5)),
    };
    let scenario = Arc::new(scenario_from_bytes(&bytes, &map_dir()).unwrap());
    let task = task_from_assign(&assign, scenario);
    let remote = run_episode(
        &paddock_sim::circuit::Circuits::new(),
        &task.scenario,
        task.seed,
        task.record,
    )
    .unwrap();
    assert_eq!(remote, local);

    // errors travel with their field
    let err = run_episode(
        &paddock_sim::circuit::Circuits::new(),
        &Scenario {
            laps: 0,
            ..s.clone()
        },
        1,
        None,
    )
    .unwrap_err();
    let back = outcome_from_proto(&outcome_to_proto(&Err(err))).unwrap_err();
    assert!(back.to_string().contains("laps"), "{back}");

    // ragged trajectories are refused
    let mut bad = episode_result_to_proto(&local);
    bad.trajectory.as_mut().unwrap().agents[0].x.pop();
    let e = episode_result_from_proto(&bad).unwrap_err();
    assert_eq!(e.field, "trajectory.agents[0].x");
    let mut bad = episode_result_to_proto(&local);
    bad.trajectory.as_mut().unwrap().agents[0].y.truncate(8);
    assert_eq!(
        episode_result_from_proto(&bad).unwrap_err().field,
        "trajectory.agents[0].y"
    );
    let mut bad = episode_result_to_proto(&local);
    bad.agents[0].termination = 99;
    let _ = &bad;
    assert_eq!(
        episode_result_from_proto(&bad).unwrap_err().field,
        "agents[0].termination"
    );
}

#[test]
fn batches_share_scenarios() {
    let s = Arc::new(scenario());
    let other = Arc::new(Scenario {
        laps: 2,
        ..scenario()
    });
    let tasks: Vec<EpisodeTask> = (0..5)
        .map(|i| EpisodeTask {
            scenario: if i == 3 { other.clone() } else { s.clone() },
            seed: i,
            record: (i == 1).then_some(0),
        })
        .collect();
    let mut asked = 0;
    let batch = batch_to_proto(
        &tasks,
        |m| {
            asked += 1;
            paddock_proto::MapRef {
                name: m.into(),
                hash: "h".into(),
            }
        },
        true,
    );
    assert_eq!(asked, 2);
    assert_eq!(batch.scenarios.len(), 2);
    let idx: Vec<u32> = batch.tasks.iter().map(|t| t.scenario).collect();
    assert_eq!(idx, [0, 0, 0, 1, 0]);
    assert_eq!(batch.tasks[1].record_decimation, 1);
    assert_eq!(batch.tasks[2].record_decimation, 0);
    // each scenario is encoded once, as the broker stores it
    let first: paddock_proto::Scenario =
        prost::Message::decode(batch.scenarios[0].as_slice()).unwrap();
    assert_eq!(first.laps, 1);
}
