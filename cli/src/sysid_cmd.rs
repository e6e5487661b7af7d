//! `paddock sysid`: the reality-gap tool (analysis of a recording), and `paddock sysid
//! synth` (a recording with hidden effects, for proofs and demos).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use paddock_sim::params::VehicleParams;
use paddock_sysid::effects::EffectKind;
use paddock_sysid::recording::CHANNELS;
use paddock_sysid::{AnalysisOptions, McapTopics, Recording, Stage, analyze, report};

use crate::args::{self, outln};
use crate::{sysid_plots, sysid_synth};

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct SysidArgs {
    #[command(subcommand)]
    command: Option<SysidCommand>,
    #[command(flatten)]
    analyse: AnalyseArgs,
}

#[derive(Subcommand, Debug)]
enum SysidCommand {
    /// Write a recording of a car with effects hidden in its physics.
    Synth(sysid_synth::SynthArgs),
}

#[derive(Args, Debug)]
struct AnalyseArgs {
    /// The recording: CSV (t,steer_cmd,speed_cmd,x,y,yaw,vx,vy,yaw_rate) or MCAP (ROS 2 bag).
    #[arg(long)]
    recording: Option<PathBuf>,
    /// Nominal vehicle YAML (default: the simulator's default vehicle).
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Output directory: report.json, report.md, vehicle.yaml, plots.
    #[arg(long)]
    out: Option<PathBuf>,
    /// MCAP topic of the AckermannDriveStamped commands.
    #[arg(long, default_value = "/drive")]
    drive_topic: String,
    /// MCAP topic of the Odometry.
    #[arg(long, default_value = "/odom")]
    odom_topic: String,
    /// Replay window [s].
    #[arg(long, default_value_t = 1.0, value_parser = args::number(0.2, 5.0))]
    window: f64,
    /// Cross-validation folds (contiguous time blocks).
    #[arg(long, default_value_t = 3, value_parser = args::whole::<usize>(2, 10))]
    folds: usize,
    /// Held-out improvement an effect must beat, per parameter (0.03 = 3 %).
    #[arg(long, default_value_t = 0.03, value_parser = args::number(0.0, 1.0))]
    margin: f64,
    /// Only test these effects (comma-separated names; default: all).
    #[arg(long, value_delimiter = ',')]
    effects: Vec<String>,
    /// Optimiser seed.
    #[arg(long, default_value_t = 1, value_parser = args::seed())]
    seed: u64,
    /// Skip the plots.
    #[arg(long)]
    no_plots: bool,
}

pub fn run(args: &SysidArgs) -> Result<()> {
    if let Some(SysidCommand::Synth(s)) = &args.command {
        return sysid_synth::run(s);
    }
    let a = &args.analyse;
    let (Some(recording), Some(out)) = (&a.recording, &a.out) else {
        anyhow::bail!(
            "paddock sysid needs --recording FILE and --out DIR (or the `synth` subcommand)"
        );
    };
    let topics = McapTopics {
        drive: a.drive_topic.clone(),
        odom: a.odom_topic.clone(),
    };
    let rec = Recording::load(recording, &topics)
        .with_context(|| format!("loading the recording {}", recording.display()))?;
    for w in &rec.warnings {
        tracing::warn!("{w}");
    }
    let nominal = match &a.vehicle {
        Some(p) => VehicleParams::load(p)?,
        None => VehicleParams::default(),
    };
    let mut opts = AnalysisOptions {
        window_s: a.window,
        folds: a.folds,
        margin_per_param: a.margin,
        seed: a.seed,
        ..AnalysisOptions::default()
    };
    if !a.effects.is_empty() {
        opts.candidates = a
            .effects
            .iter()
            .map(|n| EffectKind::from_name(n.trim()))
            .collect::<Result<_, _>>()?;
    }
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template("sysid [{bar:25}] {pos}/{len} {elapsed} {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message("replaying the nominal model");
    let progress = |s: Stage| {
        bar.set_length(s.total as u64);
        bar.set_position(s.done as u64);
        bar.set_message(s.message);
    };
    let analysis = analyze(&rec, &nominal, &opts, &progress)?;
    bar.finish_and_clear();
    report::write(out, &analysis, &rec)?;
    if !a.no_plots {
        sysid_plots::write_all(out, &rec, &analysis)?;
    }
    let kept: Vec<String> = analysis
        .candidates
        .iter()
        .filter(|c| c.selected)
        .map(|c| {
            format!(
                "{} {}",
                c.evidence.kind.name(),
                c.evidence.kind.params_json(&c.values)
            )
        })
        .collect();
    outln!(
        "effects: {}",
        if kept.is_empty() {
            "nothing significant".to_string()
        } else {
            kept.join(", ")
        }
    );
    outln!("held-out rmse  nominal -> fitted:");
    for (c, name) in CHANNELS.iter().enumerate() {
        outln!(
            "  {:<9} {:>9.4} -> {:>9.4}",
            name,
            analysis.rmse_before[c],
            analysis.rmse_after[c]
        );
    }
    outln!(
        "wrote {}/report.json, report.md, vehicle.yaml{} in {:.1} s",
        out.display(),
        if a.no_plots { "" } else { " and plots" },
        analysis.seconds
    );
    Ok(())
}
