//! What stepping many worlds in turn costs over stepping one (`cargo bench --workspace
//! --bench worlds_cycle -- [ROUNDS]`): the bound on what scanning all of a
//! vector env's cars in one pass could save by keeping the worlds' state and the scan's
//! working set in the cache. Three ways to take 64 one-car steps with 1080-beam scans,
//! the worlds of `env_session`'s 64-env session (lakeside, standing cars, seeds 0..64):
//!
//! - `poses`: the 64 worlds in one `Worlds::step` (what an env session does);
//! - `copies`: 64 worlds all at world 0's pose and state in one `Worlds::step` (the same
//!   scan work 64 times, the worlds' state cycled as in `poses`);
//! - `one`: world 0 alone stepped 64 times (the same work, one world's state, the cache
//!   at its warmest).
//!
//! `copies / one` is what cycling the worlds costs. The three run in turn, a 20 ms block
//! of CPU time each, ROUNDS times (default 300), on one thread; the medians of the blocks'
//! times and of the ratios of each round's blocks are printed (blocks that short see the
//! same host speed, so a ratio is told apart to about a per cent on a noisy host).

mod common;

use common::{BEAMS, ENVS, thread_cpu};
use paddock_sim::world::{Action, PackedObservations, Worlds};
use std::time::Duration;

/// Seconds of CPU per call of `f`, over calls filling 20 ms of CPU time.
fn block(f: &mut dyn FnMut()) -> f64 {
    let t0 = thread_cpu();
    let mut calls = 0u32;
    while thread_cpu() - t0 < Duration::from_millis(20) {
        f();
        calls += 1;
    }
    (thread_cpu() - t0).as_secs_f64() / f64::from(calls)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    // `cargo bench` passes `--bench`; a number is the rounds
    let rounds = std::env::args()
        .skip(1)
        .find_map(|a| a.parse::<usize>().ok())
        .unwrap_or(300)
        .max(1);
    let mut poses = common::session_worlds(&common::session());
    // clones of world 0, each with its pose and state
    let mut same = Worlds::of(poses.world(0), ENVS);
    let mut one = Worlds::of(poses.world(0), 1);
    let actions = vec![Action::default(); ENVS];
    let mut scans = vec![0u8; ENVS * BEAMS * 4];
    let mut t: [Vec<f64>; 3] = Default::default();
    for _ in 0..rounds {
        t[0].push(block(&mut || {
            let mut out = PackedObservations::scans(&mut scans, 1);
            poses.step(&actions, &[], Some(&mut out)).expect("a step");
        }));
        t[1].push(block(&mut || {
            let mut out = PackedObservations::scans(&mut scans, 1);
            same.step(&actions, &[], Some(&mut out)).expect("a step");
        }));
        t[2].push(block(&mut || {
            for k in 0..ENVS {
                let at = k * BEAMS * 4;
                let mut out = PackedObservations::scans(&mut scans[at..at + BEAMS * 4], 1);
                one.step(&actions[..1], &[], Some(&mut out))
                    .expect("a step");
            }
        }));
    }
    let ratio = |a: &[f64], b: &[f64]| median(a.iter().zip(b).map(|(x, y)| x / y).collect());
    let ms = |v: &[f64]| median(v.to_vec()) * 1e3;
    println!(
        "{} (ms per 64 one-car steps, medians of {rounds} rounds of 20 ms blocks)",
        paddock_sim::lidar::cpu_model()
    );
    println!("poses  (64 worlds, 64 poses)        {:.4} ms", ms(&t[0]));
    println!("copies (64 worlds, world 0's pose)  {:.4} ms", ms(&t[1]));
    println!("one    (world 0 stepped 64 times)   {:.4} ms", ms(&t[2]));
    println!(
        "copies / one {:.4}   poses / one {:.4}",
        ratio(&t[1], &t[2]),
        ratio(&t[0], &t[2])
    );
}
