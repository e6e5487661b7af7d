//! Frames of lakeside at 800 pixels: building a renderer (the background: walls sampled
//! 3 x 3 per pixel, the driving line, the start line; once per circuit and width) and
//! rendering one scene of two cars with car 0's 1080-beam scan (every frame).
//!
//! Recorded (2-core VM shared with other builds, so +-20 %): renderer_new_800 208 ms with
//! every pixel sampled 3 x 3, 57 ms sampling 3 x 3 only at wall edges (the same bytes on
//! the pinned frame); render_800 5.2-5.7 ms; render_320 2.7-2.9 ms.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use paddock_render::{Renderer, Scene};
use paddock_sim::circuit::Circuits;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, AgentConfig, Starts, World, WorldConfig};

fn frame(c: &mut Criterion) {
    let circuit = Circuits::new().get("lakeside").expect("the shipped map");
    let agent = |scan| AgentConfig {
        params: VehicleParams::default(),
        scan,
    };
    let mut world = World::new(
        circuit.clone(),
        WorldConfig {
            agents: vec![agent(true), agent(false)],
            ..WorldConfig::default()
        },
    )
    .expect("a world");
    world.reset(7, &Starts::Random).expect("a start");
    for _ in 0..100 {
        world
            .step(&[Action::new(0.0, 3.0), Action::new(0.0, 2.0)])
            .expect("a step");
    }
    let scene = Scene::from_world(&world).expect("a scene");
    c.bench_function("renderer_new_800", |b| {
        b.iter(|| Renderer::new(black_box(&circuit), 800).expect("a renderer"))
    });
    let r = Renderer::new(&circuit, 800).expect("a renderer");
    c.bench_function("render_800", |b| b.iter(|| r.render(black_box(&scene))));
    let r = Renderer::new(&circuit, 320).expect("a renderer");
    c.bench_function("render_320", |b| b.iter(|| r.render(black_box(&scene))));
}

criterion_group!(benches, frame);
criterion_main!(benches);
