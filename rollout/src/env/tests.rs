//! The vector env's behaviour: determinism, independence of copies, rewards, ends,
//! opponents, poses, refusals, and several learner cars per copy.

use super::*;
use crate::AgentSpec;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::Starts;

fn cfg(num_envs: usize) -> EnvConfig {
    let mut c = EnvConfig::single("lakeside", num_envs, 7);
    c.lidar.num_beams = 108;
    c
}

fn field_of(e: RolloutError) -> String {
    match e {
        RolloutError::Invalid { field, .. } => field,
        other => panic!("expected an Invalid error, got {other}"),
    }
}

/// Gentle constant actions: slow and straight-ish.
fn slow(n: usize) -> Vec<f32> {
    (0..n).flat_map(|i| [0.02 * i as f32, 1.5]).collect()
}

#[test]
fn same_seed_same_bits() {
    let mut a = VecEnv::new(&paddock_sim::circuit::Circuits::new(), cfg(3)).unwrap();
    let mut b = VecEnv::new(&paddock_sim::circuit::Circuits::new(), cfg(3)).unwrap();
    assert_eq!(a.frame(), b.frame());
    for _ in 0..20 {
        let fa = a.step(&slow(3), &[]).unwrap().clone();
        let fb = b.step(&slow(3), &[]).unwrap();
        assert_eq!(&fa, fb);
    }
    // a seeded reset restarts the stream: twice the same
    let r1 = a.reset(&[], &[5, 6, 7], None).unwrap().clone();
    a.step(&slow(3), &[]).unwrap();
    let r2 = a.reset(&[], &[5, 6, 7], None).unwrap().clone();
    assert_eq!(r1, r2);
    // different copies start in different places
    assert_ne!(r1.states[0], r1.states[STATE_SIZE]);
    // unseeded resets after a seeded one are deterministic too
    let u1 = a.reset(&[], &[], None).unwrap().clone();
    a.reset(&[], &[5, 6, 7], None).unwrap();
    let u2 = a.reset(&[], &[], None).unwrap().clone();
    assert_eq!(u1, u2);
    assert_ne!(u1.states, r1.states);
}

#[test]
fn copies_are_independent_of_batching() {
    // copy i of a 3-env session equals a 1-env session given the same seed and actions
    let mut batch = VecEnv::new(&paddock_sim::circuit::Circuits::new(), cfg(3)).unwrap();
    batch.reset(&[], &[11, 12, 13], None).unwrap();
    let acts = slow(3);
    for _ in 0..15 {
        batch.step(&acts, &[]).unwrap();
    }
    for i in 0..3 {
        let mut one = VecEnv::new(&paddock_sim::circuit::Circuits::new(), cfg(1)).unwrap();
        one.reset(&[], &[11 + i as u64], None).unwrap();
        for _ in 0..15 {
            one.step(&acts[2 * i..2 * i + 2], &[]).unwrap();
        }
        let (f, g) = (batch.frame(), one.frame());
        assert_eq!(&f.scans[i * 108..(i + 1) * 108], &g.scans[..]);
        assert_eq!(
            &f.states[i * STATE_SIZE..(i + 1) * STATE_SIZE],
            &g.states[..]
        );
        assert_eq!(f.rewards[i], g.rewards[0]);
        assert_eq!(f.progress[i], g.progress[0]);
    }
}

#[test]
fn a_given_pool_of_any_size_steps_the_same_bits() {
    // the copies cut into runs on a pool of 1 or 3 threads (a library's own pool), as on
    // the caller's rayon pool: the same frames, step by step, resets included
    let circuits = paddock_sim::circuit::Circuits::new();
    let circuit = circuits.get("lakeside").unwrap();
    let pool = |n| {
        Some(std::sync::Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap(),
        ))
    };
    let mut envs: Vec<VecEnv> = [None, pool(1), pool(3)]
        .into_iter()
        .map(|p| VecEnv::with_circuit_in(cfg(9), circuit.clone(), p).unwrap())
        .collect();
    for k in 0..30 {
        let frames: Vec<EnvFrame> = envs
            .iter_mut()
            .map(|e| {
                if k == 12 {
                    e.reset(&[2, 7], &[4, 5], None).unwrap().clone()
                } else {
                    e.step(&slow(9), &[]).unwrap().clone()
                }
            })
            .collect();
        assert_eq!(frames[0], frames[1], "step {k}");
        assert_eq!(frames[0], frames[2], "step {k}");
    }
}

#[test]
fn progress_reward_sums_to_progress_and_frame_skip_advances_time() {
    let mut c = cfg(1);
    c.frame_skip = 4;
    c.reward = RewardWeights {
        progress: 1.0,
        collision: 0.0,
        lap: 0.0,
        time: 0.0,
    };
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), c).unwrap();
    env.reset(&[], &[3], None).unwrap();
    let mut total = 0.0;
    for k in 1..=10 {
        let f = env.step(&[0.0, 2.0], &[]).unwrap();
        total += f.rewards[0];
        assert!(
            (f.time[0] - 0.04 * k as f64).abs() < 1e-9,
            "time {}",
            f.time[0]
        );
        assert!(!f.terminated[0] && !f.truncated[0]);
    }
    let f = env.frame();
    assert!(f.progress[0] > 0.1, "the car moved: {}", f.progress[0]);
    assert!((total - f.progress[0]).abs() < 1e-9);
    // a time weight adds weight * seconds
    let mut c = cfg(1);
    c.reward = RewardWeights {
        progress: 0.0,
        collision: 0.0,
        lap: 0.0,
        time: -2.0,
    };
    c.frame_skip = 3;
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), c).unwrap();
    let r = env.step(&[0.0, 1.0], &[]).unwrap().rewards[0];
    assert!((r + 0.06).abs() < 1e-12, "reward {r}");
}

#[test]
fn time_limit_truncates() {
    let mut c = cfg(2);
    c.time_limit = 0.5;
    c.frame_skip = 5;
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), c).unwrap();
    for k in 1..=10 {
        let f = env.step(&slow(2), &[]).unwrap();
        assert_eq!(f.truncated, vec![k == 10; 2], "step {k}");
    }
    assert!((env.frame().time[0] - 0.5).abs() < 1e-12);
    // an ended copy stays as it is until reset
    let before = env.frame().clone();
    let f = env.step(&slow(2), &[]).unwrap();
    assert_eq!(f.rewards, vec![0.0; 2]);
    assert_eq!(f.states, before.states);
    assert_eq!(f.truncated, vec![true; 2]);
    // reset_envs in a step resets that copy and steps the other
    let f = env.step(&slow(2), &[1]).unwrap();
    assert_eq!(f.truncated, vec![true, false]);
    assert_eq!(f.time[1], 0.0);
    assert_eq!(f.rewards[1], 0.0);
}

#[test]
fn a_crash_terminates_with_the_collision_penalty() {
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), cfg(1)).unwrap();
    let mut crashed = None;
    for k in 0..2000 {
        let f = env.step(&[0.4, 8.0], &[]).unwrap();
        if f.terminated[0] {
            crashed = Some((k, f.rewards[0]));
            break;
        }
    }
    let (_, reward) = crashed.expect("full lock at speed hits a wall");
    let f = env.frame();
    assert!(f.agent_collisions[0]);
    assert!(!f.truncated[0]);
    // progress part is small; the penalty dominates
    assert!(reward < -9.0, "reward {reward}");
}

#[test]
fn opponents_drive_themselves() {
    let mut c = cfg(2);
    c.opponents = vec![AgentSpec::with_defaults("pure-pursuit").unwrap()];
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), c).unwrap();
    assert_eq!(env.num_agents(), 2);
    let start = env.frame().states.clone();
    for _ in 0..100 {
        env.step(&[0.0, 0.0, 0.0, 0.0], &[]).unwrap();
    }
    let f = env.frame();
    assert_eq!(f.states.len(), 2 * 2 * STATE_SIZE);
    assert_eq!(f.agent_lap_counts.len(), 4);
    // the opponent (car 1) moved, the learner standing still did not go far
    let opp = STATE_SIZE;
    let moved = (f.states[opp] - start[opp]).hypot(f.states[opp + 1] - start[opp + 1]);
    assert!(moved > 1.0, "opponent moved {moved} m");
    assert!(f.states[3].abs() < 0.5, "learner speed {}", f.states[3]);
}

#[test]
fn reset_to_given_poses() {
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), cfg(2)).unwrap();
    let p0 = *env
        .world(0)
        .unwrap()
        .start_poses_for(99, &Starts::Random)
        .unwrap()
        .first()
        .unwrap();
    let p1 = Pose::new(p0.x, p0.y, p0.theta + 0.1);
    let f = env.reset(&[1], &[], Some(&[p1])).unwrap();
    let row = &f.states[STATE_SIZE..2 * STATE_SIZE];
    assert_eq!((row[0], row[1], row[2]), (p1.x, p1.y, p1.theta));
    assert_eq!(f.time[1], 0.0);
}

#[test]
fn bad_requests_name_the_field_and_change_nothing() {
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), cfg(2)).unwrap();
    env.step(&slow(2), &[]).unwrap();
    let before = env.frame().clone();
    let e = env.step(&[0.0; 3], &[]).unwrap_err();
    assert!(
        e.to_string()
            .contains("expected num_envs x [steer, speed] = 4"),
        "{e}"
    );
    assert_eq!(field_of(e), "actions");
    let e = env.step(&[0.0, 1.0, 0.0, f32::NAN], &[]).unwrap_err();
    assert!(e.to_string().contains("env 1 speed"), "{e}");
    assert_eq!(field_of(e), "actions[3]");
    assert_eq!(
        field_of(env.step(&slow(2), &[2]).unwrap_err()),
        "reset_envs[0]"
    );
    assert_eq!(field_of(env.reset(&[5], &[], None).unwrap_err()), "envs[0]");
    assert_eq!(
        field_of(env.reset(&[0, 0], &[], None).unwrap_err()),
        "envs[1]"
    );
    assert_eq!(field_of(env.reset(&[], &[1], None).unwrap_err()), "seeds");
    assert_eq!(
        field_of(env.reset(&[0], &[], Some(&[])).unwrap_err()),
        "poses"
    );
    let nan = Pose::new(0.0, f64::NAN, 0.0);
    assert_eq!(
        field_of(env.reset(&[0], &[], Some(&[nan])).unwrap_err()),
        "poses[0]"
    );
    assert_eq!(env.frame(), &before);

    let check = |f: fn(&mut EnvConfig), field: &str| {
        let mut c = cfg(1);
        f(&mut c);
        let e = VecEnv::new(&paddock_sim::circuit::Circuits::new(), c).unwrap_err();
        assert!(e.to_string().contains(field), "{field}: {e}");
    };
    check(|c| c.num_envs = 0, "num_envs");
    check(|c| c.frame_skip = 0, "frame_skip");
    check(|c| c.time_limit = f64::NAN, "time_limit");
    check(|c| c.reward.collision = f64::INFINITY, "reward.collision");
    check(|c| c.lidar.num_beams = 0, "lidar.num_beams");
    check(|c| c.laps = 0, "laps");
    check(
        |c| {
            c.opponents = vec![AgentSpec {
                driver: "nobody".into(),
                params: vec![],
                vehicle: VehicleParams::default(),
            }]
        },
        "opponents[0].driver",
    );
    check(
        |c| {
            let mut o = AgentSpec::with_defaults("pure-pursuit").unwrap();
            o.params[0] = f64::NAN;
            c.opponents = vec![o];
        },
        "opponents[0].params",
    );
    let e = VecEnv::new(
        &paddock_sim::circuit::Circuits::new(),
        EnvConfig::single("no-such-map", 1, 0),
    )
    .unwrap_err();
    assert!(e.to_string().contains("no-such-map"), "{e}");
}

/// `n` copies of two learner cars (no opponents) on 108-beam scans.
fn two_learners(n: usize) -> EnvConfig {
    let mut c = cfg(n);
    c.learners = 2;
    c
}

#[test]
fn every_learner_gets_its_own_scan_reward_and_flags() {
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), two_learners(2)).unwrap();
    assert_eq!((env.num_agents(), env.num_learners()), (2, 2));
    let f = env.frame();
    assert_eq!(f.scans.len(), 2 * 2 * 108);
    assert_eq!(f.rewards.len(), 4);
    assert_eq!(f.terminated.len(), 4);
    assert_eq!(f.truncated.len(), 2);
    // learner k's scan is car k's: the rows of a copy differ (the cars stand apart)
    assert_ne!(&f.scans[..108], &f.scans[108..216]);
    let w = env.world(1).unwrap().observation().unwrap();
    let car1: Vec<f32> = w.scan(1).iter().map(|&r| r.max(0.0) as f32).collect();
    assert_eq!(&f.scans[3 * 108..], &car1[..]);
    // env 0: learner 0 slow, learner 1 still; env 1: both slow
    let progress0 = f.progress.clone();
    for _ in 0..30 {
        env.step(&[0.0, 2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 2.0], &[])
            .unwrap();
    }
    let f = env.frame();
    let gained: Vec<f64> = f
        .progress
        .iter()
        .zip(&progress0)
        .map(|(a, b)| a - b)
        .collect();
    assert!(
        gained[0] > 0.2 && gained[2] > 0.2 && gained[3] > 0.2,
        "{gained:?}"
    );
    assert!(
        gained[1].abs() < 1e-9,
        "the still car did not move: {gained:?}"
    );
    assert_eq!(f.rewards[1], 0.0);
    assert!(f.rewards[0] > 0.0);
    // learner 1 of env 0 reads its own speed in the states
    assert_eq!(f.states[STATE_SIZE + 3], 0.0);
    assert_eq!(f.terminated, vec![false; 4]);
}

#[test]
fn a_crashed_learner_is_out_and_the_others_race_on() {
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), two_learners(1)).unwrap();
    env.reset(&[], &[5], None).unwrap();
    // learner 0 at full lock and speed into a wall; learner 1 gently on
    let mut crashed_at = None;
    for k in 0..3000 {
        let f = env.step(&[0.4, 8.0, 0.0, 1.0], &[]).unwrap();
        if f.terminated[0] {
            crashed_at = Some(k);
            break;
        }
    }
    crashed_at.expect("full lock at speed hits a wall");
    let f = env.frame().clone();
    assert!(!f.terminated[1] && !f.ended(0), "{:?}", f.terminated);
    assert!(f.agent_collisions[0]);
    // out of the race: no reward, its action ignored; the other learner still earns
    let f2 = env.step(&[0.0, 5.0, 0.0, 1.0], &[]).unwrap();
    assert_eq!(f2.rewards[0], 0.0);
    assert_eq!(&f2.states[..3], &f.states[..3]);
    assert!(f2.rewards[1] != 0.0);
    assert!(f2.time[0] > f.time[0]);
    // both out: the copy has ended and stays as it is
    let mut ended = false;
    for _ in 0..3000 {
        if env.step(&[0.0, 0.0, 0.4, 8.0], &[]).unwrap().ended(0) {
            ended = true;
            break;
        }
    }
    assert!(ended);
    let before = env.frame().clone();
    let after = env.step(&[0.0, 1.0, 0.0, 1.0], &[]).unwrap();
    assert_eq!(after.states, before.states);
    assert_eq!(after.rewards, vec![0.0; 2]);
}

#[test]
fn learner_requests_name_the_field() {
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), two_learners(2)).unwrap();
    let e = env.step(&[0.0; 4], &[]).unwrap_err();
    assert!(
        e.to_string()
            .contains("expected num_envs x 2 learners x [steer, speed] = 8 values"),
        "{e}"
    );
    let mut a = [0.0f32; 8];
    a[7] = f32::INFINITY;
    let e = env.step(&a, &[]).unwrap_err();
    assert!(e.to_string().contains("env 1 learner 1 speed"), "{e}");
    assert_eq!(field_of(e), "actions[7]");
    let check = |f: fn(&mut EnvConfig), field: &str, says: &str| {
        let mut c = two_learners(1);
        f(&mut c);
        let e = VecEnv::new(&paddock_sim::circuit::Circuits::new(), c).unwrap_err();
        assert!(e.to_string().contains(field), "{field}: {e}");
        assert!(e.to_string().contains(says), "{says}: {e}");
    };
    check(|c| c.learners = 0, "learners", "1..=16");
    check(|c| c.learners = 17, "learners", "1..=16");
    check(
        |c| {
            c.learners = 10;
            c.opponents = vec![AgentSpec::with_defaults("pure-pursuit").unwrap(); 7];
        },
        "opponents",
        "at most 6 opponents beside 10 learners",
    );
    check(
        |c| {
            c.num_envs = 1024;
            c.learners = 2;
            c.lidar.num_beams = 10_000;
        },
        "lidar.num_beams",
        "scan values",
    );
}

#[test]
fn opponents_follow_the_learners() {
    let mut c = two_learners(1);
    c.opponents = vec![AgentSpec::with_defaults("pure-pursuit").unwrap()];
    let mut env = VecEnv::new(&paddock_sim::circuit::Circuits::new(), c).unwrap();
    assert_eq!((env.num_agents(), env.num_learners()), (3, 2));
    let start = env.frame().states.clone();
    for _ in 0..100 {
        env.step(&[0.0; 4], &[]).unwrap();
    }
    let f = env.frame();
    let opp = 2 * STATE_SIZE;
    let moved = (f.states[opp] - start[opp]).hypot(f.states[opp + 1] - start[opp + 1]);
    assert!(moved > 1.0, "the opponent (car 2) moved {moved} m");
    assert_eq!(f.agent_lap_counts.len(), 3);
}
