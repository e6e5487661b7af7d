//! Replay cost of vehicle files on a recording: `cargo run --release -p paddock-sysid
//! --example replay_cost -- REC.csv [VEHICLE.yaml ...]` (no files: the default vehicle).
//! Prints the noise-normalised residual sum and the per-channel RMSE of each.

use std::path::Path;

use paddock_sim::params::VehicleParams;
use paddock_sysid::recording::{Recording, RecordingTopics};
use paddock_sysid::replay::Replay;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(rec_path) = args.first() else {
        return Err("usage: replay_cost REC [VEHICLE.yaml ...]".into());
    };
    let rec = Recording::load(Path::new(rec_path), &RecordingTopics::default())?;
    let replay = Replay::new(&rec, 1.0);
    let mut vehicles: Vec<(String, VehicleParams)> = Vec::new();
    for p in &args[1..] {
        vehicles.push((p.clone(), VehicleParams::load(p)?));
    }
    if vehicles.is_empty() {
        vehicles.push(("default".into(), VehicleParams::default()));
    }
    for (name, p) in vehicles {
        let cost: f64 = replay.window_costs(&p).iter().sum();
        let rmse = replay.residuals(&p).rmse(|_| true);
        println!("{name}: cost {cost:.1} rmse {rmse:.4?}");
    }
    Ok(())
}
