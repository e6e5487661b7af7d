//! World behaviour on a synthetic ring circuit: determinism, snapshots, collisions in
//! every mode, scans that see other cars and obstacles, laps, bad input.

use std::sync::Arc;

use paddock_sim::circuit::Circuit;
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::{Pose, wrap_angle};
use paddock_sim::map::Map;
use paddock_sim::track::{CenterPoint, Track};
use paddock_sim::world::{Action, AgentStatus, Starts, World, WorldConfig, WorldError, WorldState};

const R: f64 = 10.0;

/// A ring road: centre radius 10 m, 3 m wide, walls everywhere else; CCW centerline.
fn ring() -> Arc<Circuit> {
    let res = 0.05;
    let n = 560;
    let origin = Pose::new(-14.0, -14.0, 0.0);
    let mut occ = vec![true; n * n];
    for row in 0..n {
        for col in 0..n {
            let x = origin.x + (col as f64 + 0.5) * res;
            let y = origin.y + (row as f64 + 0.5) * res;
            let r = (x * x + y * y).sqrt();
            if (R - 1.5..=R + 1.5).contains(&r) {
                occ[row * n + col] = false;
            }
        }
    }
    let map = Map::from_grid("ring", n, n, res, origin, occ).unwrap();
    let pts = (0..400)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / 400.0;
            CenterPoint {
                x: R * a.cos(),
                y: R * a.sin(),
                w_right: 1.5,
                w_left: 1.5,
            }
        })
        .collect();
    Arc::new(Circuit::new(
        "ring",
        Arc::new(map),
        Arc::new(Track::new(pts, None).unwrap()),
    ))
}

/// Follow the ring: feed-forward curvature plus lateral and heading feedback.
fn ring_driver(world: &World, speed: f64) -> Vec<Action> {
    let obs = world.observation().unwrap();
    let track = &world.circuit().track;
    (0..world.num_agents())
        .map(|i| {
            let p = track.project(obs.poses_x[i], obs.poses_y[i]);
            let head = wrap_angle(p.heading - obs.poses_theta[i]);
            let steer = (0.33f64 / R).atan() - 0.4 * p.lateral + 0.8 * head;
            Action::new(steer, speed)
        })
        .collect()
}

fn run(world: &mut World, steps: usize, speed: f64) -> u64 {
    for _ in 0..steps {
        let a = ring_driver(world, speed);
        world.step(&a).unwrap();
    }
    world.observation().unwrap().digest()
}

fn two_car_world(seed: u64) -> World {
    let mut cfg = WorldConfig::with_agents(2);
    cfg.obstacles.count = 3;
    cfg.obstacles.start_clearance = 3.0;
    cfg.collision_mode = CollisionMode::Stop;
    let mut w = World::new(ring(), cfg).unwrap();
    w.reset(seed, &Starts::Random).unwrap();
    w
}

#[test]
fn same_seed_same_bits() {
    let mut a = two_car_world(7);
    let mut b = two_car_world(7);
    assert_eq!(
        a.observation().unwrap().digest(),
        b.observation().unwrap().digest()
    );
    assert_eq!(run(&mut a, 600, 4.0), run(&mut b, 600, 4.0));
    assert_eq!(a.snapshot().unwrap(), b.snapshot().unwrap());
    // A different seed: different starts, obstacles and noise.
    let mut c = two_car_world(8);
    assert_ne!(run(&mut c, 600, 4.0), a.observation().unwrap().digest());
}

#[test]
fn snapshot_restore_replays_exactly() {
    let mut w = two_car_world(3);
    run(&mut w, 200, 4.0);
    let snap = w.snapshot().unwrap();
    let straight = run(&mut w, 300, 4.0);
    let end_state = w.snapshot().unwrap();
    w.restore(&snap).unwrap();
    assert_eq!(run(&mut w, 300, 4.0), straight);
    assert_eq!(w.snapshot().unwrap(), end_state);
    // A snapshot survives serialisation bit for bit.
    let json = serde_json::to_string(&snap).unwrap();
    let back: WorldState = serde_json::from_str(&json).unwrap();
    assert_eq!(back, snap);
    let mut other = two_car_world(99);
    other.restore(&back).unwrap();
    assert_eq!(run(&mut other, 300, 4.0), straight);
}

#[test]
fn scan_noise_is_per_car_and_seeded() {
    let mut cfg = WorldConfig::with_agents(2);
    cfg.collision_mode = CollisionMode::Ignore;
    let mut w = World::new(ring(), cfg.clone()).unwrap();
    // Both cars at the same place (collision ignored): same geometry, so any difference
    // between their scans is their own noise.
    let p = Pose::new(R, 0.0, std::f64::consts::FRAC_PI_2);
    w.reset(1, &Starts::Poses(vec![p, p])).unwrap();
    let obs = w.observation().unwrap();
    // each car sees the other one at range ~0 in some beams; compare beams far from it
    let d: Vec<f64> = (0..1080)
        .map(|k| obs.scan(0)[k] - obs.scan(1)[k])
        .filter(|d| d.abs() < 0.2)
        .collect();
    assert!(d.len() > 500);
    let std = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
    // difference of two independent N(0, 0.01): std 0.0141
    assert!((0.010..0.018).contains(&std), "noise difference std {std}");
    // noise off: exact and equal
    cfg.lidar.noise_std = 0.0;
    let mut w = World::new(ring(), cfg).unwrap();
    w.reset(1, &Starts::Poses(vec![p, p])).unwrap();
    let obs = w.observation().unwrap();
    assert_eq!(obs.scan(0), obs.scan(1));
}

#[test]
fn scan_sees_the_car_ahead() {
    let mut cfg = WorldConfig::with_agents(2);
    cfg.lidar.noise_std = 0.0;
    let mut w = World::new(ring(), cfg).unwrap();
    // car 1 two metres ahead along the ring (chord), car 0 looking straight at it
    let a1 = 2.0 / R;
    let p1 = Pose::new(R * a1.cos(), R * a1.sin(), std::f64::consts::FRAC_PI_2 + a1);
    let theta0 = (p1.y).atan2(p1.x - R);
    let p0 = Pose::new(R, 0.0, theta0);
    w.reset(0, &Starts::Poses(vec![p0, p1])).unwrap();
    let obs = w.observation().unwrap();
    let centre = obs.scan(0)[539].min(obs.scan(0)[540]);
    let dist = (p1.x - R).hypot(p1.y);
    // the rear face of car 1 is ~0.29 m before its centre (it is turned by a1/2)
    assert!(
        centre < dist - 0.25 && centre > dist - 0.35,
        "centre beam {centre}, car at {dist}"
    );
}

/// Regression: the world added `lidar.mount_offset` to the pose and the LIDAR added it
/// again, so a laser mounted 0.25 m ahead scanned from 0.5 m ahead.
#[test]
fn a_mounted_laser_scans_from_its_mount_once() {
    let p0 = Pose::new(R, 0.0, std::f64::consts::FRAC_PI_2);
    let scan_with = |offset: f64| {
        let mut cfg = WorldConfig::with_agents(1);
        cfg.lidar.noise_std = 0.0;
        cfg.lidar.mount_offset = offset;
        let mut w = World::new(ring(), cfg).unwrap();
        w.reset(0, &Starts::Poses(vec![p0])).unwrap();
        w.observation().unwrap().scan(0).to_vec()
    };
    let at_base = scan_with(0.0);
    let mounted = scan_with(0.25);
    // the same as an unmounted laser on a car 0.25 m further along its heading
    let mut cfg = WorldConfig::with_agents(1);
    cfg.lidar.noise_std = 0.0;
    let mut w = World::new(ring(), cfg).unwrap();
    let ahead = Pose::new(R, 0.25, std::f64::consts::FRAC_PI_2);
    w.reset(0, &Starts::Poses(vec![ahead])).unwrap();
    let from_mount = w.observation().unwrap().scan(0).to_vec();
    assert_eq!(mounted, from_mount);
    assert_ne!(mounted, at_base);
}

/// A laser mount in the vehicle parameters: the default (none) is today's scan; a mount
/// 0.25 m ahead scans from there; an upside-down one sweeps the other way.
#[test]
fn a_vehicle_laser_mount_moves_and_flips_the_scan() {
    use paddock_sim::params::{LaserMount, VehicleParams};
    let p0 = Pose::new(R, 0.0, std::f64::consts::FRAC_PI_2);
    let scan = |mount: Option<LaserMount>, pose: Pose| {
        let mut cfg = WorldConfig::with_agents(1);
        cfg.lidar.noise_std = 0.0;
        cfg.agents[0].params = VehicleParams {
            laser_mount: mount,
            ..VehicleParams::default()
        };
        let mut w = World::new(ring(), cfg).unwrap();
        w.reset(0, &Starts::Poses(vec![pose])).unwrap();
        w.observation().unwrap().scan(0).to_vec()
    };
    let base = scan(None, p0);
    assert_eq!(scan(Some(LaserMount::default()), p0), base);
    let ahead = Pose::new(R, 0.25, std::f64::consts::FRAC_PI_2);
    let mounted = scan(
        Some(LaserMount {
            x: 0.25,
            ..LaserMount::default()
        }),
        p0,
    );
    let from_ahead = scan(None, ahead);
    for (a, b) in mounted.iter().zip(&from_ahead) {
        assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    }
    let mut flipped = scan(
        Some(LaserMount {
            flipped: true,
            ..LaserMount::default()
        }),
        p0,
    );
    flipped.reverse();
    assert_eq!(flipped, base);
    // the YAML: absent by default (files written before stay byte-identical), read back
    let text = VehicleParams::default().to_yaml_string();
    assert!(!text.contains("laser_mount"), "{text}");
    let p = VehicleParams::from_yaml_str("laser_mount: {x: 0.27, flipped: true}\n").unwrap();
    assert_eq!(
        p.laser_mount,
        Some(LaserMount {
            x: 0.27,
            flipped: true,
            ..LaserMount::default()
        })
    );
    let e = VehicleParams::from_yaml_str("laser_mount: {x: .nan}\n").unwrap_err();
    assert!(e.to_string().contains("laser_mount.x"), "{e}");
}

fn crash_world(mode: CollisionMode) -> World {
    let mut cfg = WorldConfig::with_agents(1);
    cfg.collision_mode = mode;
    cfg.agents[0].scan = false;
    let mut w = World::new(ring(), cfg).unwrap();
    // heading straight out of the ring towards the outer wall
    w.reset(0, &Starts::Poses(vec![Pose::new(R, 0.0, 0.0)]))
        .unwrap();
    w
}

fn drive_straight(w: &mut World, steps: usize) {
    for _ in 0..steps {
        w.step(&[Action::new(0.0, 3.0)]).unwrap();
    }
}

#[test]
fn collision_terminate_freezes_the_car() {
    let mut w = crash_world(CollisionMode::Terminate);
    drive_straight(&mut w, 300);
    let s = w.state().unwrap();
    assert_eq!(s.agents[0].status, AgentStatus::Crashed);
    assert!(w.done());
    let obs = w.observation().unwrap();
    assert!(obs.collisions[0]);
    // the car stopped at the wall: its front is within one step of R + 1.5
    let front = obs.poses_x[0] + 0.29;
    assert!((front - (R + 1.5)).abs() < 0.1, "front at {front}");
    let x = obs.poses_x[0];
    drive_straight(&mut w, 10);
    assert_eq!(w.observation().unwrap().poses_x[0], x);
}

#[test]
fn collision_stop_halts_before_the_wall() {
    let mut w = crash_world(CollisionMode::Stop);
    drive_straight(&mut w, 300);
    let s = w.state().unwrap();
    assert_eq!(s.agents[0].status, AgentStatus::Racing);
    let obs = w.observation().unwrap();
    let front = obs.poses_x[0] + 0.29;
    assert!(front < R + 1.5 && front > R + 1.3, "front at {front}");
    assert!(obs.linear_vels_x[0].abs() < 0.5);
    let x_stopped = obs.poses_x[0];
    // it can still drive away: reverse
    for _ in 0..200 {
        w.step(&[Action::new(0.0, -1.0)]).unwrap();
    }
    assert!(w.observation().unwrap().poses_x[0] < x_stopped - 0.3);
}

#[test]
fn collision_ignore_drives_through() {
    let mut w = crash_world(CollisionMode::Ignore);
    drive_straight(&mut w, 150);
    let obs = w.observation().unwrap();
    assert!(obs.collisions[0]);
    assert!(obs.poses_x[0] > R + 1.5, "x {}", obs.poses_x[0]);
    assert_eq!(w.state().unwrap().agents[0].status, AgentStatus::Racing);
}

#[test]
fn car_car_collision_in_both_cars() {
    let mut cfg = WorldConfig::with_agents(2);
    cfg.collision_mode = CollisionMode::Terminate;
    let mut w = World::new(ring(), cfg).unwrap();
    let p0 = Pose::new(R, 0.0, std::f64::consts::FRAC_PI_2);
    let p1 = Pose::new(R + 0.2, 0.3, std::f64::consts::FRAC_PI_2);
    w.reset(0, &Starts::Poses(vec![p0, p1])).unwrap();
    let s = w.state().unwrap();
    assert_eq!(s.agents[0].status, AgentStatus::Crashed);
    assert_eq!(s.agents[1].status, AgentStatus::Crashed);
    // a car driving into a crashed car collides too
    let mut cfg = WorldConfig::with_agents(2);
    cfg.collision_mode = CollisionMode::Terminate;
    let mut w = World::new(ring(), cfg).unwrap();
    let behind = Pose::new(R, -1.0, std::f64::consts::FRAC_PI_2);
    w.reset(0, &Starts::Poses(vec![behind, p0])).unwrap();
    for _ in 0..200 {
        w.step(&[Action::new(0.0, 3.0), Action::new(0.0, 0.0)])
            .unwrap();
    }
    assert_eq!(w.state().unwrap().agents[0].status, AgentStatus::Crashed);
}

#[test]
fn laps_and_lap_times() {
    let mut cfg = WorldConfig::with_agents(1);
    cfg.laps = Some(2);
    cfg.agents[0].scan = false;
    let mut w = World::new(ring(), cfg).unwrap();
    w.reset(5, &Starts::Random).unwrap();
    for _ in 0..10_000 {
        let a = ring_driver(&w, 4.0);
        w.step(&a).unwrap();
        if w.done() {
            break;
        }
    }
    let s = w.state().unwrap();
    assert_eq!(
        s.agents[0].status,
        AgentStatus::Finished,
        "{:?}",
        s.agents[0]
    );
    let laps = w.lap_times(0).unwrap();
    assert_eq!(laps.len(), 2);
    // steady state at 4 m/s around a 62.8 m loop (first lap includes the start)
    let l = w.circuit().track.length();
    assert!(
        (laps[1] - l / 4.0).abs() < 0.3,
        "lap {} vs {}",
        laps[1],
        l / 4.0
    );
    assert!(laps[0] > laps[1]);
    let obs = w.observation().unwrap();
    assert_eq!(obs.lap_counts[0], 2);
    assert!((obs.lap_times[0] - (laps[0] + laps[1])).abs() < 0.011);
}

#[test]
fn obstacles_are_placed_seen_and_hit() {
    let mut cfg = WorldConfig::with_agents(1);
    cfg.obstacles.count = 6;
    cfg.obstacles.start_clearance = 3.0;
    cfg.lidar.noise_std = 0.0;
    let mut w = World::new(ring(), cfg.clone()).unwrap();
    w.reset(11, &Starts::Random).unwrap();
    let obstacles = w.obstacles().unwrap().to_vec();
    assert_eq!(obstacles.len(), 6);
    let mut again = World::new(ring(), cfg.clone()).unwrap();
    again.reset(11, &Starts::Random).unwrap();
    assert_eq!(again.obstacles().unwrap(), &obstacles[..]);
    // placed inside the corridor
    for o in &obstacles {
        let r = o.cx.hypot(o.cy);
        assert!((R - 1.5..R + 1.5).contains(&r), "obstacle at r = {r}");
    }
    // the scan is shorter with obstacles than without from the same pose
    let obs_with = w.observation().unwrap().scans.clone();
    let mut cfg0 = cfg;
    cfg0.obstacles.count = 0;
    let mut w0 = World::new(ring(), cfg0).unwrap();
    let s = w.state().unwrap();
    w0.reset(11, &Starts::Poses(vec![s.agents[0].vehicle.pose()]))
        .unwrap();
    let obs_without = &w0.observation().unwrap().scans;
    assert!(obs_with.iter().zip(obs_without).all(|(a, b)| a <= b));
    // drive around until an obstacle is hit or two laps are done: with 6 obstacles on a
    // 63 m ring and no avoidance, the car hits one
    let mut cfg = WorldConfig::with_agents(1);
    cfg.obstacles.count = 6;
    cfg.obstacles.start_clearance = 3.0;
    cfg.obstacles.passage = 0.0;
    cfg.obstacles.width = 1.2;
    cfg.agents[0].scan = false;
    let mut w = World::new(ring(), cfg).unwrap();
    w.reset(11, &Starts::Random).unwrap();
    for _ in 0..4000 {
        let a = ring_driver(&w, 3.0);
        w.step(&a).unwrap();
        if w.done() {
            break;
        }
    }
    assert_eq!(w.state().unwrap().agents[0].status, AgentStatus::Crashed);
}

#[test]
fn bad_input_is_an_error_and_the_world_goes_on() {
    let mut w = two_car_world(1);
    let before = w.snapshot().unwrap();
    let e = w
        .step(&[Action::new(0.0, 1.0), Action::new(f64::NAN, 1.0)])
        .unwrap_err();
    assert!(
        matches!(e, WorldError::NonFiniteAction { agent: 1, field: "steer", value } if value.is_nan()),
        "{e:?}"
    );
    assert!(e.to_string().contains("agent 1") && e.to_string().contains("steer"));
    let e = w.step(&[Action::new(0.0, 1.0)]).unwrap_err();
    assert!(matches!(
        e,
        WorldError::ActionCount {
            expected: 2,
            got: 1
        }
    ));
    let e = w
        .step(&[Action::new(0.0, f64::INFINITY), Action::new(0.0, 1.0)])
        .unwrap_err();
    assert!(e.to_string().contains("speed"), "{e}");
    // nothing moved, and the world still steps
    assert_eq!(w.snapshot().unwrap(), before);
    w.step(&[Action::new(0.0, 1.0), Action::new(0.0, 1.0)])
        .unwrap();
    // bad configs name the field
    let mut cfg = WorldConfig::with_agents(1);
    cfg.dt = f64::NAN;
    let e = World::new(ring(), cfg).unwrap_err();
    assert!(e.to_string().contains("dt"), "{e}");
    let mut cfg = WorldConfig::with_agents(1);
    cfg.agents[0].params.m = -1.0;
    let e = World::new(ring(), cfg).unwrap_err();
    assert!(e.to_string().contains("agents[0]"), "{e}");
    let mut w = World::new(ring(), WorldConfig::with_agents(2)).unwrap();
    let e = w
        .reset(0, &Starts::Poses(vec![Pose::default()]))
        .unwrap_err();
    assert!(matches!(
        e,
        WorldError::PoseCount {
            expected: 2,
            got: 1
        }
    ));
    assert!(matches!(
        World::new(ring(), WorldConfig::with_agents(1))
            .unwrap()
            .step(&[Action::default()]),
        Err(WorldError::NotReset)
    ));
}

#[test]
fn random_starts_are_free_and_seeded() {
    for n in [1, 2, 4] {
        let cfg = WorldConfig::with_agents(n);
        for seed in 0..20 {
            let mut w = World::new(ring(), cfg.clone()).unwrap();
            w.reset(seed, &Starts::Random).unwrap();
            let obs = w.observation().unwrap();
            assert!(
                obs.collisions.iter().all(|c| !c),
                "n {n} seed {seed}: {:?}",
                obs.collisions
            );
            let mut w2 = World::new(ring(), cfg.clone()).unwrap();
            w2.reset(seed, &Starts::Random).unwrap();
            assert_eq!(w2.observation().unwrap().poses_x, obs.poses_x);
        }
    }
}
