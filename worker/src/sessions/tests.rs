use paddock_proto::{
    EnvObservation, EnvOpened, Lidar, MapRef, pack_f32, pack_f64, unpack_f32, unpack_f64,
};
use paddock_rollout::env::STATE_SIZE;

use super::*;

const OPEN: i32 = EnvOp::EnvOpen as i32;
const RESET: i32 = EnvOp::EnvReset as i32;
const STEP: i32 = EnvOp::EnvStep as i32;
const CLOSE: i32 = EnvOp::EnvClose as i32;

fn lakeside() -> MapRef {
    paddock_wire::map_ref(&paddock_wire::local_map(&Circuits::new(), "lakeside").unwrap()) // ok: test
}

fn open_msg(num_envs: u32) -> EnvOpen {
    EnvOpen {
        map: Some(lakeside()),
        num_envs,
        seed: 4,
        lidar: Some(Lidar {
            num_beams: 64,
            fov: 4.7,
            max_range: 30.0,
            noise_std: 0.01,
            mount_offset: 0.0,
        }),
        laps: 1,
        time_limit: 60.0,
        frame_skip: 2,
        ..Default::default()
    }
}

fn expect_err(r: Reply) -> Error {
    assert!(r.frames.is_empty(), "an error carries no payload");
    let header = r.header.clone();
    r.header
        .error
        .unwrap_or_else(|| panic!("expected an error, got {header:?}"))
}

fn expect_obs(r: Reply) -> (EnvObservation, Vec<u8>) {
    assert!(r.header.error.is_none(), "{:?}", r.header.error);
    assert_eq!(r.frames.len(), 2);
    let views: Vec<&[u8]> = r.frames.iter().map(Vec::as_slice).collect();
    assert_eq!(r.header.fingerprint, paddock_proto::fingerprint(&views));
    (
        EnvObservation::decode(r.frames[0].as_slice()).unwrap(), // ok: test
        r.frames[1].clone(),
    )
}

fn open(s: &mut Sessions, id: u64, n: u32) -> EnvOpened {
    let r = s.handle(id, OPEN, &open_msg(n).encode_to_vec());
    assert!(r.header.error.is_none(), "{:?}", r.header.error);
    assert_eq!(r.header.session_id, id);
    EnvOpened::decode(r.frames[0].as_slice()).unwrap() // ok: test
}

fn actions(n: usize) -> Vec<u8> {
    pack_f32(&(0..n).flat_map(|_| [0.0f32, 2.0]).collect::<Vec<_>>())
}

fn step(actions: Vec<u8>) -> Vec<u8> {
    EnvStep {
        actions,
        reset_envs: vec![],
    }
    .encode_to_vec()
}

#[test]
fn open_reset_step_close() {
    let mut s = Sessions::new();
    let id = 0x1234_5678;
    let o = open(&mut s, id, 3);
    assert_eq!((o.num_envs, o.num_beams, o.num_agents), (3, 64, 1));
    assert_eq!(o.action_low.len(), 2);
    assert!(o.action_low[0] < 0.0 && o.action_high[1] > 0.0);
    assert_eq!(s.count(), 1);
    let reset = EnvReset {
        seeds: vec![1, 2, 3],
        ..Default::default()
    };
    let r = s.handle(id, RESET, &reset.encode_to_vec());
    assert!(
        r.header.restart,
        "a seeded reset of every env is a restart point"
    );
    let (meta, scans) = expect_obs(r);
    assert_eq!(scans.len(), 3 * 64 * 4);
    assert_eq!(meta.states.len(), 3 * STATE_SIZE * 8);
    assert_eq!(meta.terminated, vec![0; 3]);
    assert_eq!(meta.agent_lap_counts.len(), 3 * 4);
    let scans = unpack_f32(&scans, "scans").unwrap(); // ok: test
    assert!(scans.iter().all(|&x| x > 0.0 && x < 31.0));
    let r = s.handle(id, STEP, &step(actions(3)));
    assert!(!r.header.restart);
    let fingerprint = r.header.fingerprint;
    let (st, st_scans) = expect_obs(r);
    let time = unpack_f64(&st.time, "time").unwrap(); // ok: test
    assert_eq!(time, vec![0.02; 3]);
    // the same through a VecEnv directly: the frames are its frame, packed (the
    // session's worlds write the scans frame themselves: the same bytes)
    let cfg = paddock_wire::env::config_from_proto(&open_msg(3), "lakeside", None).unwrap(); // ok: test
    let mut env = VecEnv::new(&Circuits::new(), cfg).unwrap(); // ok: test
    env.reset(&[], &[1, 2, 3], None).unwrap(); // ok: test
    let f = env.step(&[0.0, 2.0, 0.0, 2.0, 0.0, 2.0], &[]).unwrap(); // ok: test
    let (meta, packed) = paddock_wire::env::observation_frames(f);
    assert_eq!(meta, st);
    assert_eq!(packed, st_scans);
    // and the fingerprint is the same on a second worker replaying the requests
    let mut other = Sessions::new();
    open(&mut other, id, 3);
    other.handle(id, RESET, &reset.encode_to_vec());
    assert_eq!(
        other.handle(id, STEP, &step(actions(3))).header.fingerprint,
        fingerprint
    );
    // the broker rebuilding the session on this same worker (it took the worker for
    // dead, then heard from it again): the open replaces the stale copy, and the
    // replayed requests give the same observations
    open(&mut s, id, 3);
    assert_eq!(s.count(), 1);
    s.handle(id, RESET, &reset.encode_to_vec());
    assert_eq!(
        s.handle(id, STEP, &step(actions(3))).header.fingerprint,
        fingerprint
    );
    let r = s.handle(id, CLOSE, &[]);
    assert!(r.header.error.is_none() && r.frames.is_empty());
    assert_eq!(s.count(), 0);
    let e = expect_err(s.handle(id, CLOSE, &[]));
    assert_eq!(e.code, ErrorCode::NotFound as i32);
    assert_eq!(e.field, "env_request.session_id");
}

#[test]
fn learner_cars_take_one_action_row_each() {
    let mut s = Sessions::new();
    let mut o = open_msg(2);
    o.learners = 2;
    o.opponents = vec![paddock_proto::AgentSpec {
        driver: "pure-pursuit".into(),
        ..Default::default()
    }];
    let r = s.handle(1, OPEN, &o.encode_to_vec());
    let opened = EnvOpened::decode(r.frames[0].as_slice()).unwrap(); // ok: test
    assert_eq!((opened.num_agents, opened.num_learners), (3, 2));
    let e = expect_err(s.handle(1, STEP, &step(actions(2))));
    assert!(
        e.message
            .contains("expected 2 envs x 2 learners x [steer, speed] as f32 = 32 bytes"),
        "{}",
        e.message
    );
    let (st, scans) = expect_obs(s.handle(1, STEP, &step(actions(4))));
    assert_eq!(scans.len(), 2 * 2 * 64 * 4);
    assert_eq!(st.rewards.len(), 2 * 2 * 8);
    assert_eq!(st.terminated.len(), 2 * 2);
    assert_eq!(st.truncated.len(), 2);
    assert_eq!(st.progress.len(), 2 * 2 * 8);
    assert_eq!(st.agent_lap_counts.len(), 2 * 3 * 4);
    // an opponent's error names it among the opponents, after the learners
    let mut bad = open_msg(1);
    bad.learners = 2;
    bad.opponents = vec![paddock_proto::AgentSpec {
        driver: "nobody".into(),
        ..Default::default()
    }];
    let e = expect_err(Sessions::new().handle(4, OPEN, &bad.encode_to_vec()));
    assert_eq!(e.field, "env_open.opponents[0].driver");
}

#[test]
fn a_worker_vehicle_replaces_only_the_default_one() {
    let fitted = VehicleParams {
        mu: 0.6,
        ..Default::default()
    };
    let mut o = open_msg(1);
    o.opponents = vec![paddock_proto::AgentSpec {
        driver: "pure-pursuit".into(),
        ..Default::default()
    }];
    let cfg = paddock_wire::env::config_from_proto(&o, "lakeside", Some(&fitted)).unwrap(); // ok: test
    assert_eq!(cfg.vehicle, fitted);
    assert_eq!(cfg.opponents[0].vehicle, fitted);
    // a request that carries its own vehicle keeps it
    let own = VehicleParams {
        m: 4.0,
        ..Default::default()
    };
    o.vehicle_yaml = own.to_yaml_string();
    assert_eq!(
        paddock_wire::env::config_from_proto(&o, "lakeside", Some(&fitted))
            .unwrap() // ok: test
            .vehicle,
        own
    );
    let plain = paddock_wire::env::config_from_proto(&open_msg(1), "lakeside", None).unwrap(); // ok: test
    assert_eq!(plain.vehicle, VehicleParams::default());
}

#[test]
fn bad_requests_name_the_field() {
    let mut s = Sessions::new();
    let id = 7;
    open(&mut s, id, 2);
    let e = expect_err(s.handle(id, STEP, &step(vec![0; 12])));
    assert_eq!(e.field, "env_step.actions");
    assert!(
        e.message
            .contains("expected 2 envs x [steer, speed] as f32 = 16 bytes"),
        "{}",
        e.message
    );
    assert!(e.message.contains("12 bytes"), "{}", e.message);
    let e = expect_err(s.handle(id, STEP, &step(pack_f32(&[0.0, 1.0, f32::NAN, 1.0]))));
    assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
    assert_eq!(e.field, "env_step.actions[2]");
    assert!(e.message.contains("NaN"), "{}", e.message);
    let e = expect_err(s.handle(99, STEP, &step(actions(2))));
    assert_eq!(
        (e.code, e.field.as_str()),
        (ErrorCode::NotFound as i32, "env_request.session_id")
    );
    let poses = EnvReset {
        poses: pack_f64(&[1.0, 2.0]),
        ..Default::default()
    };
    let e = expect_err(s.handle(id, RESET, &poses.encode_to_vec()));
    assert_eq!(e.field, "env_reset.poses");
    let envs = EnvReset {
        envs: vec![7],
        ..Default::default()
    };
    let e = expect_err(s.handle(id, RESET, &envs.encode_to_vec()));
    assert_eq!(e.field, "env_reset.envs[0]");
    let e = expect_err(s.handle(id, STEP, &[0xff, 0xff, 0xff]));
    assert_eq!(
        (e.code, e.field.as_str()),
        (ErrorCode::BadMessage as i32, "env_step")
    );
    // the session survived all of that
    expect_obs(s.handle(id, STEP, &step(actions(2))));

    let bad_open = |f: fn(&mut EnvOpen)| {
        let mut o = open_msg(1);
        f(&mut o);
        expect_err(Sessions::new().handle(1, OPEN, &o.encode_to_vec()))
    };
    let e = bad_open(|o| o.num_envs = 0);
    assert_eq!(e.field, "env_open.num_envs");
    let e = bad_open(|o| o.frame_skip = 0);
    assert_eq!(e.field, "env_open.frame_skip");
    let e = bad_open(|o| o.map = None);
    assert_eq!(e.field, "env_open.map");
    let e = bad_open(|o| o.map.as_mut().unwrap().hash = "ab".repeat(32)); // ok: test
    assert_eq!(
        (e.code, e.field.as_str()),
        (ErrorCode::NotFound as i32, "env_open.map.hash")
    );
    let e = bad_open(|o| {
        o.opponents = vec![paddock_proto::AgentSpec {
            driver: "nobody".into(),
            ..Default::default()
        }]
    });
    assert_eq!(e.field, "env_open.opponents[0].driver");
    assert!(e.message.contains("nobody"), "{}", e.message);
    let mut with_opponent = open_msg(1);
    with_opponent.opponents = vec![paddock_proto::AgentSpec {
        driver: "pure-pursuit".into(),
        ..Default::default()
    }];
    let r = Sessions::new().handle(1, OPEN, &with_opponent.encode_to_vec());
    let o = EnvOpened::decode(r.frames[0].as_slice()).unwrap(); // ok: test
    assert_eq!(o.num_agents, 2, "no parameters = the defaults");
    let e = bad_open(|o| o.vehicle_yaml = "v_max: .nan".into());
    assert!(e.field.starts_with("env_open.vehicle_yaml"), "{}", e.field);
    let e = bad_open(|o| o.lidar.as_mut().unwrap().fov = -1.0); // ok: test
    assert_eq!(e.field, "env_open.lidar.fov");
    let e = expect_err(s.handle(id, 42, &[]));
    assert_eq!(e.field, "env_request.op");
}

#[test]
fn maps_from_the_cache_by_hash() {
    let tmp = std::env::temp_dir().join(format!("paddock-sessions-{}", std::process::id()));
    let cache = MapCache::open(&tmp).unwrap(); // ok: test
    let mut bundle = paddock_wire::local_map(&Circuits::new(), "lakeside").unwrap(); // ok: test
    bundle.name = "custom-name".into();
    cache.store(&bundle).unwrap(); // ok: test
    let mut s = Sessions::new();
    s.set_map_cache(cache);
    let mut o = open_msg(1);
    o.map = Some(paddock_wire::map_ref(&bundle));
    assert_eq!(s.missing_map(&o.encode_to_vec()), None);
    let reply = s.handle(3, OPEN, &o.encode_to_vec());
    let _ = std::fs::remove_dir_all(&tmp);
    assert!(reply.header.error.is_none(), "{reply:?}");
    let mut gone = open_msg(1);
    gone.map.as_mut().unwrap().hash = "cd".repeat(32); // ok: test
    assert_eq!(s.missing_map(&gone.encode_to_vec()), Some("cd".repeat(32)));
}

#[test]
fn scans_go_into_the_callers_buffer_and_fingerprints_can_be_left_out() {
    // twin sessions: one as a worker runs it, one as the in-process library does
    let (mut worker, mut local) = (Sessions::new(), Sessions::new());
    local.set_fingerprints(false);
    let opened = open(&mut worker, 3, 2);
    open(&mut local, 3, 2);
    let len = 2 * opened.num_beams as usize * 4;
    let mut buf = vec![0x5au8; len];
    let reset = EnvReset::default().encode_to_vec();
    for (op, payload) in [
        (RESET, reset),
        (STEP, step(actions(2))),
        (STEP, step(actions(2))),
    ] {
        let want = worker.handle(3, op, &payload);
        let (meta, scans) = expect_obs(want.clone());
        let got = local.handle_into(3, op, &payload, Some(&mut buf));
        assert!(got.header.error.is_none(), "{:?}", got.header.error);
        assert_eq!(got.header.fingerprint, 0, "left out");
        assert_eq!(
            (got.header.restart, got.header.op),
            (want.header.restart, op)
        );
        assert_eq!(got.frames[0], meta.encode_to_vec());
        assert!(got.frames[1].is_empty(), "the scans are in the buffer");
        assert!(buf == scans, "the worker's scans, bit for bit");
    }
    // a buffer of another size is not written: the scans come as a frame
    let mut short = vec![0x5au8; len - 4];
    let want = worker.handle(3, STEP, &step(actions(2)));
    let got = local.handle_into(3, STEP, &step(actions(2)), Some(&mut short));
    assert_eq!(got.frames, want.frames);
    assert!(short.iter().all(|&b| b == 0x5a));
    // errors are as from `handle`, and the buffer is left alone
    let got = local.handle_into(3, STEP, &step(actions(1)), Some(&mut buf));
    assert!(expect_err(got).field.contains("actions"));
}

#[test]
fn the_scan_path_setting_reaches_the_worlds_and_a_refused_one_refuses_opens() {
    // the default: the widest path this CPU has
    let mut widest = Sessions::new();
    open(&mut widest, 1, 2);
    assert_eq!(widest.env(1).unwrap().scan_path(), ScanPath::best()); // ok: test
    // a path set: every world of the sessions opened since takes it, with the same bits
    let mut portable = Sessions::new();
    portable.set_scan_path(Ok(Some(ScanPath::Portable)));
    open(&mut portable, 1, 2);
    let env = portable.env(1).unwrap(); // ok: test
    assert_eq!(env.scan_path(), ScanPath::Portable);
    for i in 0..env.num_envs() {
        assert_eq!(env.world(i).unwrap().scan_path(), ScanPath::Portable); // ok: test
    }
    let mut scans = Vec::new();
    for s in [&mut widest, &mut portable] {
        let reset = EnvReset {
            seeds: vec![3, 4],
            ..Default::default()
        };
        expect_obs(s.handle(1, RESET, &reset.encode_to_vec()));
        let (obs, frame) = expect_obs(s.handle(1, STEP, &step(actions(2))));
        assert!(frame.iter().any(|&b| b != 0), "scans");
        scans.push((obs.encode_to_vec(), frame));
    }
    assert_eq!(scans[0], scans[1], "every path gives the same bits");
    // a refused setting: every open is refused, naming the variable and its value
    let mut refused = Sessions::new();
    refused.set_scan_path(crate::scan_path::scan_path_from_var("sse9"));
    for id in [1, 2] {
        let e = expect_err(refused.handle(id, OPEN, &open_msg(1).encode_to_vec()));
        assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
        assert_eq!(e.field, "PADDOCK_SCAN_PATH");
        assert!(e.message.contains("\"sse9\""), "{}", e.message);
    }
    assert_eq!(refused.count(), 0);
}
