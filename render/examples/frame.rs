//! Writes one frame of a short race to a PNG: `cargo run --release -p paddock-render
//! --example frame -- OUT.png [MAP] [WIDTH]`. Two pure-pursuit cars race from a seeded
//! grid with three obstacles; the frame shows them after four simulated seconds.

use paddock_render::{Renderer, Scene};
use paddock_rollout::{AgentSpec, Scenario, episode_world};
use paddock_sim::circuit::Circuits;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = args.first().map_or("frame.png", String::as_str);
    let map = args.get(1).map_or("lakeside", String::as_str);
    let width: u32 = args.get(2).map_or(Ok(800), |w| w.parse())?;
    let mut scenario = Scenario::single("pure-pursuit")?;
    scenario.map = map.into();
    scenario
        .agents
        .push(AgentSpec::with_defaults("follow-the-gap")?);
    scenario.obstacles.count = 3;
    let circuit = Circuits::new().get(map)?;
    let mut world = episode_world(&scenario, circuit.clone(), 3, &[true, true])?;
    let mut drivers = scenario
        .agents
        .iter()
        .map(|a| paddock_policy::build_driver(&a.driver, &a.params, &circuit, &a.vehicle))
        .collect::<Result<Vec<_>, _>>()?;
    for _ in 0..400 {
        let obs = world.observation()?.clone();
        let actions: Vec<_> = drivers
            .iter_mut()
            .enumerate()
            .map(|(i, d)| d.act(&obs, i))
            .collect();
        world.step(&actions)?;
    }
    let frame = Renderer::new(&circuit, width)?.render(&Scene::from_world(&world)?);
    image::RgbImage::from_raw(frame.width, frame.height, frame.rgb)
        .ok_or("frame size")?
        .save(out)?;
    println!("wrote {out} ({} x {})", frame.width, frame.height);
    Ok(())
}
