//! `paddock sysid`: the reality-gap tool (analysis of a recording), and `paddock sysid
//! synth` (a recording with hidden effects, for proofs and demos).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use paddock_sim::params::VehicleParams;
use paddock_sysid::effects::EffectKind;
use paddock_sysid::recording::CHANNELS;
use paddock_sysid::{AnalysisOptions, Recording, RecordingTopics, Stage, analyze, report};

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

/// `--channels`: the channels to fit, and the words given.
#[derive(Debug, Clone)]
struct Channels {
    keep: [bool; 6],
    given: String,
}

fn channels(text: &str) -> Result<Channels, String> {
    paddock_sysid::recording::parse_channels(text).map(|keep| Channels {
        keep,
        given: text.trim().to_string(),
    })
}

#[derive(Args, Debug)]
struct AnalyseArgs {
    /// A recording: CSV (t,steer_cmd,speed_cmd,x,y,yaw[,vx,vy,yaw_rate]) or MCAP (ROS 2
    /// bag), or a folder of them. Repeatable: all runs are fitted jointly with one
    /// parameter set, and whole runs are held out.
    #[arg(long)]
    recording: Vec<PathBuf>,
    /// Nominal vehicle YAML (default: the simulator's default vehicle).
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Output directory: report.json, report.md, vehicle.yaml, plots.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Bag topic of the drive commands (ackermann_msgs/AckermannDriveStamped).
    #[arg(long, default_value = "/drive")]
    drive_topic: String,
    /// Bag topic of the odometry (nav_msgs/Odometry): the velocities, and the pose unless
    /// --pose-topic.
    #[arg(long, default_value = "/odom")]
    odom_topic: String,
    /// Bag topic of the pose, a localiser's or motion capture's (nav_msgs/Odometry,
    /// geometry_msgs/PoseStamped or PoseWithCovarianceStamped, or the transforms: /tf);
    /// the velocities at each pose are interpolated from --odom-topic. Default:
    /// --odom-topic.
    #[arg(long)]
    pose_topic: Option<String>,
    /// With the transforms as the pose topic (--pose-topic /tf, with /tf_static): the
    /// frames, PARENT,CHILD, whose pose is read [default: map,base_link].
    #[arg(long, value_parser = args::frame_pair)]
    pose_frames: Option<[String; 2]>,
    /// Channels to fit: `all` (those measured), or the pose joined by `+` with any of
    /// speed (vx), vy, yaw_rate; `pose+speed` when the odometry's yaw rate is computed
    /// from the steering command (the VESC's) rather than measured.
    #[arg(long, default_value = "all", value_parser = channels)]
    channels: Channels,
    /// Replay window [s].
    #[arg(long, default_value_t = 1.0, value_parser = args::number(0.2, 5.0))]
    window: f64,
    /// Cross-validation folds (contiguous time blocks).
    #[arg(long, default_value_t = 3, value_parser = args::whole::<usize>(2, 10))]
    folds: usize,
    /// Held-out improvement an effect must beat, per parameter (0.03 = 3 %).
    #[arg(long, default_value_t = 0.03, value_parser = args::number(0.0, 1.0))]
    margin: f64,
    /// Only test these effects (comma-separated names; default: every effect of the
    /// vocabulary).
    #[arg(long, value_delimiter = ',')]
    effects: Vec<String>,
    /// Optimiser seed.
    #[arg(long, default_value_t = 1, value_parser = args::seed())]
    seed: u64,
    /// Skip the plots.
    #[arg(long)]
    no_plots: bool,
    /// The car's VESC driver parameters (f1tenth_system `vesc.yaml`): the report gives the
    /// corrected `steering_angle_to_servo_*` and `speed_to_erpm_gain` for a fitted
    /// calibration error.
    #[arg(long)]
    vesc_config: Option<PathBuf>,
    /// Worker threads of the analysis (default, or 0: one per core).
    #[arg(long, value_parser = args::threads())]
    threads: Option<usize>,
}

/// A rosbag2 bag folder (a `metadata.yaml` beside its storage files): one recording.
fn is_bag_folder(path: &Path) -> bool {
    path.is_dir() && path.join("metadata.yaml").is_file()
}

/// The recordings a `--recording` names: the file itself, a rosbag2 bag folder, or a
/// folder's recordings (CSV, MCAP and `.db3` files, compressed whole or not, and bag
/// folders, by name), in name order.
fn recording_files(path: &Path) -> Result<Vec<PathBuf>> {
    if !path.is_dir() || is_bag_folder(path) {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .with_context(|| format!("reading the folder {}", path.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            is_bag_folder(p)
                || (p.is_file()
                    && p.extension().is_some_and(|e| {
                        e.eq_ignore_ascii_case("csv")
                            || e.eq_ignore_ascii_case("mcap")
                            || e.eq_ignore_ascii_case("db3")
                    }))
                // a rosbag2 storage file compressed whole
                || p.file_name().is_some_and(|n| {
                    let n = n.to_string_lossy().to_ascii_lowercase();
                    n.ends_with(".mcap.zstd") || n.ends_with(".db3.zstd")
                })
        })
        .collect();
    files.sort();
    if files.is_empty() {
        anyhow::bail!(
            "the folder {} holds no recordings (*.csv, *.mcap, *.db3, *.mcap.zstd, *.db3.zstd, rosbag2 bag folders)",
            path.display()
        );
    }
    Ok(files)
}

/// The name each recording file's runs are reported under: its file name, or, when two
/// files of different folders share it, its folder and file name (`day2/run-01.csv`).
fn run_names(files: &[std::path::PathBuf]) -> Vec<String> {
    let base = |f: &std::path::PathBuf| {
        f.file_name().map_or_else(
            || f.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    files
        .iter()
        .map(|f| {
            let name = base(f);
            let shared = files.iter().filter(|g| base(g) == name).count() > 1;
            match f.parent().and_then(|p| p.file_name()) {
                Some(dir) if shared => format!("{}/{name}", dir.to_string_lossy()),
                _ => name,
            }
        })
        .collect()
}

pub fn run(args: &SysidArgs, circuits: &paddock_sim::circuit::Circuits) -> Result<()> {
    if let Some(SysidCommand::Synth(s)) = &args.command {
        return sysid_synth::run(s, circuits);
    }
    let a = &args.analyse;
    let (false, Some(out)) = (a.recording.is_empty(), &a.out) else {
        anyhow::bail!(
            "paddock sysid needs --recording FILE (or FOLDER, repeatable) and --out DIR (or the `synth` subcommand)"
        );
    };
    // 0, as for every --threads: one per core (the thread pool's default)
    if let Some(n) = a.threads.filter(|&n| n > 0) {
        paddock_sysid::set_threads(n)?;
    }
    let topics = RecordingTopics {
        drive: a.drive_topic.clone(),
        odom: a.odom_topic.clone(),
        pose: a.pose_topic.clone(),
        pose_frames: a.pose_frames.clone(),
    };
    let mut files = Vec::new();
    for path in &a.recording {
        files.extend(recording_files(path)?);
    }
    let names = run_names(&files);
    let mut parts = Vec::new();
    for (file, name) in files.iter().zip(names) {
        let mut rec = Recording::read(file, &topics)
            .with_context(|| format!("loading the recording {}", file.display()))?;
        let base = file
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        for (k, r) in rec.run_info.iter_mut().enumerate() {
            if r.name == "recording" || r.name == "bag" {
                r.name = name.clone();
            } else if r.name.starts_with("bag#") {
                r.name = format!("{name}#{}", k + 1);
            } else if let Some(rest) = r.name.strip_prefix(base.as_str())
                && !base.is_empty()
            {
                // a CSV file's own run names start with its file name
                r.name = format!("{name}{rest}");
            }
        }
        parts.push(rec);
    }
    let mut rec = Recording::join(parts);
    rec.keep_channels(a.channels.keep, &a.channels.given);
    for w in &rec.warnings {
        tracing::warn!("{w}");
    }
    rec.check()?;
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
    // read before the analysis: a bad file is told at once, not after it
    let vesc = match &a.vesc_config {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("reading the VESC config {}", p.display()))?;
            Some(
                paddock_sysid::explain::vesc_params(&text)
                    .with_context(|| format!("the VESC config {}", p.display()))?,
            )
        }
        None => None,
    };
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
    report::write_with(out, &analysis, &rec, vesc.as_deref())?;
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

#[cfg(test)]
mod tests {
    use super::{recording_files, run_names};
    use std::path::PathBuf;

    #[test]
    fn a_folder_gives_its_recordings_compressed_or_not_and_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let names = [
            "a.csv",
            "b.MCAP",
            "c.db3",
            "d.mcap.zstd",
            "e.db3.ZSTD",
            "f.zstd",
            "g.txt",
        ];
        for n in names {
            std::fs::write(dir.path().join(n), b"x").unwrap();
        }
        let bag = dir.path().join("h_bag");
        std::fs::create_dir(&bag).unwrap();
        std::fs::write(bag.join("metadata.yaml"), b"x").unwrap();
        std::fs::create_dir(dir.path().join("i_plain")).unwrap();
        let got: Vec<String> = recording_files(dir.path())
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            got,
            [
                "a.csv",
                "b.MCAP",
                "c.db3",
                "d.mcap.zstd",
                "e.db3.ZSTD",
                "h_bag"
            ]
        );
        let e = recording_files(&dir.path().join("i_plain")).unwrap_err();
        assert!(e.to_string().contains("*.mcap.zstd"), "{e}");
    }

    #[test]
    fn runs_of_files_with_the_same_name_in_two_folders_are_told_apart() {
        let files: Vec<PathBuf> = [
            "a/day1/run-01.csv",
            "a/day2/run-01.csv",
            "a/day2/run-02.csv",
            "lap.mcap",
        ]
        .iter()
        .map(PathBuf::from)
        .collect();
        assert_eq!(
            run_names(&files),
            [
                "day1/run-01.csv",
                "day2/run-01.csv",
                "run-02.csv",
                "lap.mcap"
            ]
        );
    }
}
