//! `paddock maps generate`: writes a seeded, generated track in the f1tenth racetracks
//! layout (map YAML + PNG, centerline and raceline CSV).

use std::path::PathBuf;

use crate::args::{self, outln};
use anyhow::Context;
use paddock_sim::trackgen::{self, TrackGenConfig};

#[derive(Debug, Clone, clap::Args)]
pub struct GenerateArgs {
    /// Seed: the same seed and options give byte-identical files.
    #[arg(long, default_value_t = 0, value_parser = args::seed())]
    pub seed: u64,
    /// Target centerline length in metres.
    #[arg(long, default_value_t = 120.0, value_parser = args::number(40.0, 600.0))]
    pub length: f64,
    /// Map name: files go to <out>/<name>/<name>_*.
    #[arg(long)]
    pub name: String,
    /// Folder that receives the map's folder.
    #[arg(long, default_value = "maps")]
    pub out: PathBuf,
    /// Narrowest track width (m).
    #[arg(long, default_value_t = 2.0, value_parser = args::number(1.0, 8.0))]
    pub width_min: f64,
    /// Widest track width (m).
    #[arg(long, default_value_t = 4.0, value_parser = args::number(1.0, 8.0))]
    pub width_max: f64,
    /// Map resolution (m per cell).
    #[arg(long, default_value_t = 0.05, value_parser = args::number(0.01, 0.5))]
    pub resolution: f64,
    /// Replace the map's folder when it exists (else refuse to overwrite).
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &GenerateArgs) -> anyhow::Result<()> {
    let config = TrackGenConfig {
        seed: args.seed,
        length_m: args.length,
        width_min: args.width_min,
        width_max: args.width_max,
        resolution: args.resolution,
        ..TrackGenConfig::default()
    };
    let target = args.out.join(&args.name);
    if target.exists() && !args.force {
        anyhow::bail!(
            "{} exists: pass --force to overwrite it, or choose another --name or --out",
            target.display()
        );
    }
    tracing::debug!(?config, "generating track");
    let track = trackgen::generate(&config)?;
    let folder = track
        .write(&args.out, &args.name)
        .with_context(|| format!("writing map {:?} under {}", args.name, args.out.display()))?;
    let files: Vec<String> = ["map.yaml", "map.png", "centerline.csv", "raceline.csv"]
        .iter()
        .map(|f| {
            folder
                .join(format!("{}_{f}", args.name))
                .display()
                .to_string()
        })
        .collect();
    let lap_time: f64 = (0..track.raceline.len())
        .map(|i| {
            let (p, q) = (
                &track.raceline[i],
                &track.raceline[(i + 1) % track.raceline.len()],
            );
            ((q.x - p.x).hypot(q.y - p.y)) / (0.5 * (p.vx + q.vx))
        })
        .sum();
    if args.json {
        let summary = serde_json::json!({
            "name": args.name,
            "seed": args.seed,
            "length_m": track.length_m,
            "min_radius_m": track.min_radius_m,
            "width_px": track.occupancy.width,
            "height_px": track.occupancy.height,
            "free_cells": track.free_cells(),
            "raceline_lap_time_s": lap_time,
            "attempts": track.attempts,
            "files": files,
        });
        outln!("{summary}");
    } else {
        outln!(
            "{}: seed {}, {:.1} m, min radius {:.2} m, {}x{} cells ({} free), raceline lap {:.2} s -> {}",
            args.name,
            args.seed,
            track.length_m,
            track.min_radius_m,
            track.occupancy.width,
            track.occupancy.height,
            track.free_cells(),
            lap_time,
            files.join(", ")
        );
    }
    Ok(())
}
