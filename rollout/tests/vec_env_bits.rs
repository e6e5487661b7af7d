//! The vector env's results, bit for bit: a pinned digest of every frame of sessions
//! that exercise opponents, several learners, frame skip, crashes, the time limit,
//! autoresets in a step, seeded and unseeded resets of some envs and start poses. The
//! digests were taken from the implementation that stepped each copy's world alone; a
//! change of any bit of any frame fails here.

use paddock_rollout::AgentSpec;
use paddock_rollout::env::{EnvConfig, EnvFrame, VecEnv};
use paddock_sim::circuit::Circuits;
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::Pose;

/// FNV-1a over the bits of every field of a frame.
fn digest(h: &mut u64, f: &EnvFrame) {
    let mut word = |v: u64| {
        for b in v.to_le_bytes() {
            *h ^= u64::from(b);
            *h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    for &x in &f.scans {
        word(u64::from(x.to_bits()));
    }
    for v in [
        &f.states,
        &f.rewards,
        &f.progress,
        &f.time,
        &f.agent_lap_times,
    ] {
        for &x in v.iter() {
            word(x.to_bits());
        }
    }
    for v in [&f.terminated, &f.truncated, &f.agent_collisions] {
        for &x in v.iter() {
            word(u64::from(x));
        }
    }
    for v in [&f.laps, &f.agent_lap_counts] {
        for &x in v.iter() {
            word(u64::from(x));
        }
    }
}

/// Actions that vary by env, learner and step: some cars turn into walls.
fn actions(n: usize, learners: usize, step: usize) -> Vec<f32> {
    (0..n * learners)
        .flat_map(|k| {
            let steer = 0.3 * (((k * 7 + step) % 11) as f32 / 10.0 - 0.5);
            let speed = 1.0 + ((k * 3 + step) % 5) as f32;
            [steer, speed]
        })
        .collect()
}

/// A session's frames: steps with autoresets of the ended envs, a seeded reset of some
/// envs, an unseeded reset of others and a reset at given poses.
fn run(config: EnvConfig, steps: usize) -> u64 {
    let mut env = VecEnv::new(&Circuits::new(), config).unwrap();
    let (n, l) = (env.num_envs(), env.num_learners());
    let mut h = 0xcbf2_9ce4_8422_2325;
    digest(&mut h, env.frame());
    for s in 0..steps {
        let ended: Vec<usize> = (0..n).filter(|&i| env.frame().ended(i)).collect();
        let f = env.step(&actions(n, l, s), &ended).unwrap();
        digest(&mut h, f);
        if s == steps / 3 {
            digest(&mut h, env.reset(&[1, n - 1], &[77, 78], None).unwrap());
        }
        if s == steps / 2 {
            digest(&mut h, env.reset(&[0], &[], None).unwrap());
        }
        if s == 2 * steps / 3 {
            let x = env.frame().states[..3].to_vec();
            let a = env.num_agents();
            let poses: Vec<Pose> = (0..a)
                .map(|k| Pose::new(x[0] - k as f64 * 1.5, x[1], x[2]))
                .collect();
            digest(&mut h, env.reset(&[2], &[5], Some(&poses)).unwrap());
        }
    }
    h
}

fn base(n: usize) -> EnvConfig {
    let mut c = EnvConfig::single("lakeside", n, 3);
    c.lidar.num_beams = 216;
    c.time_limit = 2.0;
    c
}

#[test]
fn one_learner_bits_are_pinned() {
    let h = run(base(5), 120);
    assert_eq!(h, 0x7128_bd85_ab96_9f8e, "digest {h:#018x}");
}

#[test]
fn opponents_frame_skip_and_stop_mode_bits_are_pinned() {
    let mut c = base(4);
    c.opponents = vec![AgentSpec::with_defaults("pure-pursuit").unwrap()];
    c.frame_skip = 3;
    c.collision_mode = CollisionMode::Stop;
    let h = run(c, 80);
    assert_eq!(h, 0x59ed_984f_7bcf_10a2, "digest {h:#018x}");
}

#[test]
fn two_learners_bits_are_pinned() {
    let mut c = base(3);
    c.learners = 2;
    c.opponents = vec![AgentSpec::with_defaults("follow-the-gap").unwrap()];
    let h = run(c, 100);
    assert_eq!(h, 0x5d18_57cf_447d_297e, "digest {h:#018x}");
}
