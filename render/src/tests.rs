use std::sync::Arc;

use paddock_rollout::{Scenario, run_episode};
use paddock_sim::circuit::Circuits;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, AgentConfig, Starts, World, WorldConfig};

use super::*;

fn lakeside() -> Arc<Circuit> {
    Circuits::new().get("lakeside").unwrap()
}

fn fnv(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
    })
}

fn rgb_at(f: &Frame, x: f64, y: f64) -> Rgb {
    let k = ((y.floor() as usize) * f.width as usize + x.floor() as usize) * 3;
    Rgb(f.rgb[k], f.rgb[k + 1], f.rgb[k + 2])
}

/// One car (defaults: 0.58 x 0.31 m) at `pose`, nothing else.
fn one_car(pose: Pose) -> Scene {
    let v = VehicleParams::default();
    Scene {
        time: 1.5,
        laps: Some(2),
        cars: vec![CarView {
            pose,
            length: v.length,
            width: v.width,
            speed: 3.0,
            laps: 0,
            status: CarStatus::Racing,
        }],
        ..Scene::default()
    }
}

#[test]
fn a_car_is_drawn_where_it_is_with_its_heading() {
    let circuit = lakeside();
    let r = Renderer::new(&circuit, 800).unwrap();
    assert_eq!(r.width(), 800);
    assert_eq!(r.height() % 2, 0, "even height for video encoders");
    let (p, _, _) = circuit.track.at(40.0);
    let v = VehicleParams::default();
    let ahead = |pose: Pose, d: f64| {
        r.to_px(
            pose.x + d * libm::cos(pose.theta),
            pose.y + d * libm::sin(pose.theta),
        )
    };
    for theta in [p.theta, p.theta + std::f64::consts::PI, 0.3] {
        let pose = Pose::new(p.x, p.y, theta);
        let f = r.render(&one_car(pose));
        // the body's rear half is the car's colour, its front half shows the white nose
        let (bx, by) = ahead(pose, -0.25 * v.length);
        assert_eq!(rgb_at(&f, bx, by), CAR_COLOURS[0], "theta {theta}");
        let (nx, ny) = ahead(pose, 0.3 * v.length);
        let nose = rgb_at(&f, nx, ny);
        assert!(
            nose.0 > 240 && nose.1 > 200 && nose.2 > 200,
            "theta {theta}: nose pixel {nose:?}"
        );
        // beside the car: the background, not the car
        let (sx, sy) = r.to_px(
            pose.x - 1.2 * libm::sin(theta),
            pose.y + 1.2 * libm::cos(theta),
        );
        assert_ne!(rgb_at(&f, sx, sy), CAR_COLOURS[0]);
    }
}

#[test]
fn every_car_gets_its_colour_and_a_crashed_car_is_crossed_out() {
    let circuit = lakeside();
    let r = Renderer::new(&circuit, 640).unwrap();
    let (p, _, _) = circuit.track.at(10.0);
    let (q, _, _) = circuit.track.at(20.0);
    let mut scene = one_car(p);
    let mut other = scene.cars[0].clone();
    other.pose = q;
    scene.cars.push(other);
    let f = r.render(&scene);
    let back = |pose: Pose| {
        r.to_px(
            pose.x - 0.15 * libm::cos(pose.theta),
            pose.y - 0.15 * libm::sin(pose.theta),
        )
    };
    let (x, y) = back(q);
    assert_eq!(rgb_at(&f, x, y), CAR_COLOURS[1]);
    scene.cars[1].status = CarStatus::Crashed;
    let crashed = r.render(&scene);
    assert_ne!(crashed.rgb, f.rgb);
    let (cx, cy) = r.to_px(q.x, q.y);
    assert_eq!(rgb_at(&crashed, cx, cy), INK, "the cross's centre");
}

#[test]
fn frames_are_deterministic_and_pinned() {
    let circuit = lakeside();
    let r = Renderer::new(&circuit, 800).unwrap();
    let mut world = World::new(
        circuit.clone(),
        WorldConfig {
            agents: vec![
                AgentConfig {
                    params: VehicleParams::default(),
                    scan: true,
                },
                AgentConfig {
                    params: VehicleParams::default(),
                    scan: false,
                },
            ],
            laps: Some(1),
            ..WorldConfig::default()
        },
    )
    .unwrap();
    world.reset(7, &Starts::Random).unwrap();
    for _ in 0..50 {
        world
            .step(&[Action::new(0.0, 3.0), Action::new(0.0, 2.0)])
            .unwrap();
    }
    let scene = Scene::from_world(&world).unwrap();
    assert_eq!(scene.cars.len(), 2);
    assert_eq!(scene.scan.as_ref().map(|s| s.ranges.len()), Some(1080));
    assert!((scene.time - 0.5).abs() < 1e-9);
    let a = r.render(&scene);
    // a second renderer, a clone of the world: the same bytes
    let b = Renderer::new(&circuit, 800)
        .unwrap()
        .render(&Scene::from_world(&world.clone()).unwrap());
    assert_eq!(a, b);
    assert_eq!(a.rgb.len(), (a.width * a.height * 3) as usize);
    // the scan's returns are drawn: some pixels carry the scan dots' colour mix
    assert_ne!(
        a.rgb,
        r.render(&Scene {
            scan: None,
            ..scene.clone()
        })
        .rgb
    );
    // pinned: a change to the picture shows here (update the value when intended)
    assert_eq!((a.width, a.height), (800, 788), "frame size");
    let hash = fnv(&a.rgb);
    assert_eq!(hash, 0xdc08_1e4d_f754_b6f4, "frame hash {hash:#018x}");
}

#[test]
fn a_recorded_episode_replays_scene_by_scene() {
    let mut scenario = Scenario::single("pure-pursuit").unwrap();
    scenario
        .agents
        .push(paddock_rollout::AgentSpec::with_defaults("pure-pursuit").unwrap());
    scenario.obstacles.count = 3;
    scenario.time_limit = 3.0;
    let episode = run_episode(
        &paddock_sim::circuit::Circuits::new(),
        &scenario,
        11,
        Some(5),
    )
    .unwrap();
    let replay =
        replay::Replay::new(&paddock_sim::circuit::Circuits::new(), &scenario, &episode).unwrap();
    let tr = episode.trajectory.as_ref().unwrap();
    assert_eq!(replay.len(), tr.t.len());
    assert!(replay.len() >= 20, "{} samples", replay.len());
    let last = replay.len() - 1;
    let s = replay.scene(last);
    assert_eq!(s.time, tr.t[last]);
    assert_eq!(s.obstacles.len(), 3);
    for (i, car) in s.cars.iter().enumerate() {
        assert_eq!(car.pose.x, tr.agents[i].x[last]);
        assert_eq!(car.pose.theta, tr.agents[i].theta[last]);
    }
    // the obstacles are the episode's: the world of the same seed has them
    let world =
        paddock_rollout::episode_world(&scenario, replay.circuit().clone(), 11, &[]).unwrap();
    assert_eq!(world.obstacles().unwrap(), &s.obstacles[..]);
    // the scan sees something nearer than its range
    let scan = s.scan.as_ref().unwrap();
    assert!(scan.ranges.iter().any(|&r| r < 5.0));
    let r = Renderer::new(replay.circuit(), 320).unwrap();
    assert_eq!(r.render(&replay.scene(3)), r.render(&replay.scene(3)));

    let mut unrecorded = episode.clone();
    unrecorded.trajectory = None;
    let e = replay::Replay::new(
        &paddock_sim::circuit::Circuits::new(),
        &scenario,
        &unrecorded,
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("trajectory"), "{e}");
}

#[test]
fn a_width_out_of_range_is_refused_by_name() {
    let circuit = lakeside();
    for w in [0, MIN_WIDTH - 1, MAX_WIDTH + 1] {
        let e = Renderer::new(&circuit, w).unwrap_err();
        assert!(e.to_string().starts_with(&format!("width = {w}")), "{e}");
    }
}
