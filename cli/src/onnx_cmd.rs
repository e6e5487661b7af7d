//! `paddock onnx-check`: check a model against the observation contract and print its raw
//! actions on seeded sample inputs as JSON, for comparison with another runtime
//! (`paddock.onnx.check` in Python runs onnxruntime on the same inputs).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use paddock_policy::onnx::OnnxPolicy;

use crate::args::{self, outln};

#[derive(Args)]
pub struct OnnxCheckArgs {
    /// The model file (.onnx).
    model: PathBuf,
    /// Sample inputs to run.
    #[arg(long, default_value_t = 8, value_parser = args::whole::<u64>(1, 100_000))]
    samples: u64,
    /// Seed of the sample inputs.
    #[arg(long, default_value_t = 0, value_parser = args::seed())]
    seed: u64,
}

pub fn run(args: &OnnxCheckArgs) -> Result<()> {
    let policy = OnnxPolicy::load(&args.model)?;
    let mut samples = Vec::new();
    for k in 0..args.samples {
        let feeds = policy.sample_inputs(args.seed.wrapping_add(k));
        let action = policy.run(&feeds)?;
        let inputs: serde_json::Map<String, serde_json::Value> = policy
            .inputs()
            .iter()
            .zip(&feeds)
            .map(|(slot, v)| (slot.name.clone(), serde_json::json!(v)))
            .collect();
        samples.push(serde_json::json!({ "inputs": inputs, "action": action }));
    }
    let doc = serde_json::json!({
        "model": args.model.display().to_string(),
        "sha256": policy.hash(),
        "inputs": policy.inputs().iter().map(|s| serde_json::json!({
            "name": s.name,
            "shape": s.shape,
        })).collect::<Vec<_>>(),
        "beams": policy.beams(),
        "action_repeat": policy.action_repeat(),
        "lidar_fov": policy.lidar_fov(),
        "samples": samples,
    });
    outln!("{}", serde_json::to_string_pretty(&doc)?);
    Ok(())
}
