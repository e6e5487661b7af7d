//! Env sessions on workers that do not hold the session's map: a worker with an empty
//! map cache (a container worker) fetches a map a client uploaded with `put_map` from
//! the broker before it opens the session, and so does the worker the broker replays a
//! lost session onto. The observations equal those of a worker that had the map.

use std::path::Path;
use std::time::Duration;

use paddock_e2e::{Cluster, serial};
use paddock_proto::{EnvOp, MapBundle, MapRef};
use paddock_sim::trackgen::{self, TrackGenConfig};
use paddock_wire::map_ref;
use prost::Message;

/// A generated track no machine ships, as a bundle.
fn generated_map(dir: &Path) -> MapBundle {
    let track = trackgen::generate(&TrackGenConfig {
        seed: 911,
        length_m: 120.0,
        ..TrackGenConfig::default()
    })
    .expect("the generator makes a track of seed 911");
    let folder = track.write(dir, "uploaded").expect("the track is written");
    paddock_proto::read_map_dir(&folder, "uploaded").expect("the track reads as a bundle")
}

fn open_request(map: MapRef) -> Vec<u8> {
    paddock_proto::EnvOpen {
        map: Some(map),
        num_envs: 2,
        seed: 5,
        lidar: Some(paddock_proto::Lidar {
            num_beams: 60,
            fov: 4.7,
            max_range: 30.0,
            noise_std: 0.01,
            mount_offset: 0.0,
        }),
        laps: 1,
        time_limit: 30.0,
        frame_skip: 2,
        ..Default::default()
    }
    .encode_to_vec()
}

/// The requests of the session after its open: a reset, then steps.
fn requests(steps: usize) -> Vec<(EnvOp, Vec<u8>)> {
    let actions = paddock_proto::pack_f32(&[0.1, 2.0, -0.05, 3.0]);
    let reset = paddock_proto::EnvReset {
        seeds: vec![11, 12],
        ..Default::default()
    };
    let mut out = vec![(EnvOp::EnvReset, reset.encode_to_vec())];
    out.extend((0..steps).map(|_| {
        let step = paddock_proto::EnvStep {
            actions: actions.clone(),
            reset_envs: vec![],
        };
        (EnvOp::EnvStep, step.encode_to_vec())
    }));
    out
}

fn open(client: &mut paddock_broker::client::Client, map: MapRef) -> u64 {
    let (reply, frames) = client
        .env(0, EnvOp::EnvOpen, Some(open_request(map)))
        .expect("the session opens");
    let o = paddock_proto::EnvOpened::decode(&frames[0][..]).unwrap();
    assert_eq!((o.num_envs, o.num_beams), (2, 60));
    reply.session_id
}

/// The payload frames a request gets (the observation message and the scans).
fn observe(
    client: &mut paddock_broker::client::Client,
    sid: u64,
    (op, payload): (EnvOp, Vec<u8>),
) -> Vec<Vec<u8>> {
    let (reply, frames) = client.env(sid, op, Some(payload)).expect("an observation");
    assert_eq!(reply.session_id, sid);
    frames.iter().map(|f| f.to_vec()).collect()
}

fn worker_has(c: &Cluster, worker: usize, hash: &str) -> bool {
    c.maps.path().join(format!("w{worker}")).join(hash).is_dir()
}

#[test]
fn env_sessions_fetch_an_uploaded_map_and_replay_onto_a_worker_without_it() {
    let _one = serial();
    let scratch = tempfile::tempdir().unwrap();
    let bundle = generated_map(scratch.path());
    let map = map_ref(&bundle);
    let steps = 4;

    // the reference: a worker whose cache holds the map before it starts
    let expected: Vec<Vec<Vec<u8>>> = {
        let mut c = Cluster::start(0, 1);
        let held = c.maps.path().join("w0").join(&bundle.hash).join("uploaded");
        paddock_proto::write_map_dir(&bundle, &held).unwrap();
        c.add_worker(1);
        c.wait_workers(1, Duration::from_secs(20));
        let mut client = c.client();
        client.put_map(bundle.clone()).unwrap();
        let sid = open(&mut client, map.clone());
        requests(steps)
            .into_iter()
            .map(|r| observe(&mut client, sid, r))
            .collect()
    };
    assert_eq!(expected.len(), steps + 1);

    // a worker with an empty cache: the map reaches it only through the broker
    let mut c = Cluster::start(1, 1);
    assert!(!worker_has(&c, 0, &bundle.hash));
    let mut client = c.client();
    client.put_map(bundle.clone()).unwrap();
    let sid = open(&mut client, map.clone());
    assert!(worker_has(&c, 0, &bundle.hash), "worker 0 fetched the map");
    let session = requests(steps);
    let split = 3;
    for (k, r) in session[..split].iter().enumerate() {
        assert_eq!(
            observe(&mut client, sid, r.clone()),
            expected[k],
            "request {k}"
        );
    }

    // its worker dies; the broker rebuilds the session on a second worker that has
    // never seen the map, which fetches it before the replayed open
    c.add_worker(1);
    c.wait_workers(2, Duration::from_secs(20));
    assert!(!worker_has(&c, 1, &bundle.hash));
    c.workers[0].kill9();
    c.wait_workers(1, Duration::from_secs(20));
    for (k, r) in session.iter().enumerate().skip(split) {
        assert_eq!(
            observe(&mut client, sid, r.clone()),
            expected[k],
            "request {k} after the replay"
        );
    }
    assert!(worker_has(&c, 1, &bundle.hash), "worker 1 fetched the map");
    let status = c.status();
    assert_eq!(status["sessions_replayed"], 1, "{status}");
}
