//! What the worker's benches share: the 64-env session of `client-py/benchmarks/env_steps.py`
//! (lakeside, one car, 1080-beam scans, reset with seeds 0..64), its worlds, and the
//! thread's CPU clock.

use paddock_proto::{EnvOp, EnvOpen, EnvReset};
use paddock_sim::circuit::Circuits;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::world::Worlds;
use paddock_worker::sessions::Sessions;
use prost::Message;
use std::time::Duration;

pub const ENVS: usize = 64;
pub const BEAMS: usize = 1080;

/// Session 1 of a fresh `Sessions`: `ENVS` envs of one car with a `BEAMS`-beam scan on
/// lakeside, reset with seeds 0..64 (as the Python bench's `reset(seed=0)`: the same start
/// poses).
pub fn session() -> Sessions {
    assert_eq!(
        LidarConfig::default().num_beams,
        BEAMS,
        "the default LIDAR's beams"
    );
    let circuits = Circuits::new();
    let mut sessions = Sessions::new();
    sessions.set_circuits(circuits.clone());
    // on the path `PADDOCK_SCAN_PATH` names, as the learner's process and the server
    // would take (scripts/vecenv_rounds.sh compares them)
    sessions.set_scan_path(Ok(paddock_worker::scan_path::scan_path_from_env()
        .expect("PADDOCK_SCAN_PATH names a path this CPU runs")));
    let bundle = paddock_wire::local_map(&circuits, "lakeside").expect("a shipped map");
    let open = EnvOpen {
        map: Some(paddock_wire::map_ref(&bundle)),
        num_envs: ENVS as u32,
        seed: 0,
        // the default LIDAR (`LidarConfig::default()`: 1080 beams over 4.7 rad to 30 m,
        // noise 0.01), as the Python bench's envs have it
        lidar: None,
        laps: 100,
        time_limit: 36_000.0,
        frame_skip: 1,
        ..Default::default()
    };
    let opened = sessions.handle(1, EnvOp::EnvOpen as i32, &open.encode_to_vec());
    assert!(opened.header.error.is_none(), "{:?}", opened.header.error);
    let reset = EnvReset {
        seeds: (0..ENVS as u64).collect(),
        ..Default::default()
    };
    let reply = sessions.handle(1, EnvOp::EnvReset as i32, &reset.encode_to_vec());
    assert!(reply.header.error.is_none(), "{:?}", reply.header.error);
    sessions
}

/// A copy of session 1's worlds (stepped without the session).
pub fn session_worlds(sessions: &Sessions) -> Worlds {
    let env = sessions.env(1).expect("session 1 is open");
    let first = env.world(0).expect("one env at least");
    let mut worlds = Worlds::of(first, env.num_envs());
    for i in 1..env.num_envs() {
        worlds
            .world_mut(i)
            .clone_from(env.world(i).expect("one of the session's envs"));
    }
    worlds
}

/// This thread's CPU time so far.
pub fn thread_cpu() -> Duration {
    use nix::time::{ClockId, clock_gettime};
    clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(Duration::from)
        .expect("this thread's CPU clock")
}
