//! Where a driver goes wrong: `cargo run --release -p paddock-policy --example probe --
//! <driver> <map name or dir> <seed> [name=value ...]` runs one lap from the seeded random
//! start and prints the car's last two seconds (pose, speed, command, wall clearance).

use std::collections::VecDeque;

use paddock_sim::circuit::Circuits;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, AgentConfig, Starts, World, WorldConfig};

#[path = "../tests/common/mod.rs"]
mod common;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        eprintln!("usage: probe <driver> <map> <seed> [name=value ...]");
        std::process::exit(2);
    }
    let seed: u64 = args[2].parse().expect("seed is a number");
    let overrides: Vec<(String, f64)> = args[3..]
        .iter()
        .filter_map(|a| a.split_once('='))
        .map(|(k, v)| (k.to_string(), v.parse().expect("number")))
        .collect();
    let o: Vec<(&str, f64)> = overrides.iter().map(|(k, v)| (k.as_str(), *v)).collect();
    let c = Circuits::new().get(&args[1]).expect("map");
    let mut d = common::driver(&args[0], &c, &o);
    // H2H=1: a pure-pursuit car at 0.6 of its profile starts 3 m ahead (as the tests'
    // head to head); OBSTACLES=N: N static boxes
    let h2h = std::env::var("H2H").is_ok();
    let obstacles: usize = std::env::var("OBSTACLES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    // GRID=1: B3's start instead (a seeded grid, the opponent at full speed behind;
    // GRID=2 with the grid reversed)
    let grid: u32 = std::env::var("GRID")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let h2h = h2h || grid > 0;
    let scale = if grid > 0 { 1.0 } else { 0.6 };
    let mut opp = common::driver("pure-pursuit", &c, &[("speed_scale", scale)]);
    let n = if h2h { 2 } else { 1 };
    let config = WorldConfig {
        agents: vec![
            AgentConfig {
                params: VehicleParams::default(),
                scan: true,
            };
            n
        ],
        laps: Some(1),
        obstacles: paddock_sim::world::ObstacleConfig {
            count: obstacles,
            ..Default::default()
        },
        ..WorldConfig::default()
    };
    let mut world = World::new(c.clone(), config).expect("config");
    let starts = if grid > 0 {
        let world0 = World::new(c.clone(), WorldConfig::with_agents(2)).expect("config");
        let mut poses = world0
            .start_poses_for(seed, &Starts::Random)
            .expect("poses");
        if grid == 2 {
            poses.reverse();
        }
        Starts::Poses(poses)
    } else if h2h {
        let mut rng = paddock_sim::rng::Rng::new(seed);
        let s = rng.uniform_range(0.0, c.track.length());
        let pose = |s: f64| {
            let (p, _, _) = c.track.at(s);
            paddock_sim::geometry::Pose::new(p.x, p.y, p.theta)
        };
        Starts::Poses(vec![pose(s), pose(s + 3.0)])
    } else {
        Starts::Random
    };
    world.reset(seed, &starts).expect("reset");
    d.reset();
    opp.reset();
    let mut last: VecDeque<String> = VecDeque::new();
    let mut trail: VecDeque<(f64, f64)> = VecDeque::new();
    let steps = ((20.0 + c.track.length() / 1.2) / 0.01) as usize;
    let mut min_clear = f64::INFINITY;
    let mut vmax = 0.0f64;
    for k in 0..steps {
        let obs = world.observation().expect("reset").clone();
        let a: Action = d.act(&obs, 0);
        let clear = c.map.clearance(obs.poses_x[0], obs.poses_y[0]);
        min_clear = min_clear.min(clear);
        vmax = vmax.max(obs.linear_vels_x[0]);
        trail.push_back((obs.poses_x[0], obs.poses_y[0]));
        if trail.len() > 300 {
            trail.pop_front();
        }
        if k % 10 == 0 {
            last.push_back(format!(
                "t {:6.2} x {:7.2} y {:7.2} th {:5.2} v {:5.2} steer {:5.2} | cmd {:5.2} {:5.2} | clear {:4.2} prog {:6.1}",
                k as f64 * 0.01,
                obs.poses_x[0],
                obs.poses_y[0],
                obs.poses_theta[0],
                obs.linear_vels_x[0],
                obs.steering_angles[0],
                a.steer,
                a.speed,
                clear,
                obs.progress[0]
            ));
            if last.len() > 25 {
                last.pop_front();
            }
        }
        if h2h {
            let b = opp.act(&obs, 1);
            world.step(&[a, b]).expect("step");
        } else {
            world.step(&[a]).expect("step");
        }
        let me_out = world.state().expect("reset").agents[0].status
            != paddock_sim::world::AgentStatus::Racing;
        if world.done() || me_out {
            break;
        }
    }
    for l in &last {
        println!("{l}");
    }
    // the map around the last position, 0.15 m a character; '#' wall, 'o' the car's
    // last three seconds, '@' where it ended
    let &(ex, ey) = trail.back().expect("stepped");
    for row in 0..40 {
        let y = ey + (20 - row) as f64 * 0.15;
        let line: String = (0..80)
            .map(|col| {
                let x = ex + (col as f64 - 40.0) * 0.15;
                let obs = world.observation().expect("reset");
                if (x - ex).abs() < 0.075 && (y - ey).abs() < 0.075 {
                    '@'
                } else if obs.poses_x.len() > 1
                    && (x - obs.poses_x[1]).abs() < 0.2
                    && (y - obs.poses_y[1]).abs() < 0.2
                {
                    'X'
                } else if trail
                    .iter()
                    .any(|&(px, py)| (px - x).abs() < 0.075 && (py - y).abs() < 0.075)
                {
                    'o'
                } else if c.map.occupied_at(x, y) {
                    '#'
                } else {
                    '.'
                }
            })
            .collect();
        println!("{line}");
    }
    let s = world.state().expect("state");
    println!(
        "{:?} laps {:?} t {:.2} min clearance {:.2} max speed {:.2}",
        s.agents[0].status, s.agents[0].laps.lap_times, s.time, min_clear, vmax
    );
}
