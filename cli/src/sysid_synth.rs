//! `paddock sysid synth`: a recording with physics effects hidden in it.
//!
//! A pure-pursuit driver laps a shipped map in closed loop, as a person drives a real car:
//! it sees only noisy measurements, at about 40 Hz with jitter, and some cycles are lost
//! (the command then stays as it was, and no row is logged). The car's physics carry the
//! given effects, and small random disturbances (slowly varying yaw and longitudinal
//! pushes) act on it. Everything comes from one seeded generator, so a seed gives the same
//! file every time.

use std::path::PathBuf;

use crate::args::{self, outln};
use anyhow::{Context, Result, bail};
use clap::Args;
use paddock_policy::{PurePursuit, PurePursuitParams};
use paddock_sim::circuit::{Circuits, DEFAULT_MAP};
use paddock_sim::dynamics::Vehicle;
use paddock_sim::geometry::Pose;
use paddock_sim::params::VehicleParams;
use paddock_sim::rng::Rng;
use paddock_sysid::effects::{EffectKind, parse_effect_spec};
use paddock_sysid::recording::{Recording, RecordingTopics, wrap_pi};
use serde_json::json;

use crate::sysid_synth_runs::{self, DayPlan, Manoeuvre};

const DT: f64 = 0.01;

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// An effect hidden in the car's physics: NAME[:param=value,...] (repeatable). Names:
    /// steering_delay, steering_lag, steering_offset, steering_gain, steering_backlash,
    /// drive_lag, speed_gain, drag, friction, friction_patch (params mu, xmin, ymin, xmax,
    /// ymax; without a region the box sits on the sharpest bend), tire_saturation, and
    /// measurement_delay (the logged state is that old). Missing parameters take typical
    /// values.
    #[arg(long = "effect")]
    effects: Vec<String>,
    /// Map name or directory.
    #[arg(long)]
    map: Option<String>,
    /// Length of the recording [s] (default 60, in [5, 3600]; with --manoeuvre, of each
    /// run: default 3, in [2, 120]).
    #[arg(long, value_parser = args::above(0.0, 3600.0))]
    seconds: Option<f64>,
    /// Short open-loop manoeuvres instead of laps (comma-separated, taken in turn):
    /// step (a steering step and its reversal), arc (constant radius), speed-step.
    #[arg(long, value_delimiter = ',')]
    manoeuvre: Vec<String>,
    /// Number of runs with --manoeuvre; --out is then a folder of run-NN.csv files and
    /// truth.json. Runs alternate low (1.5-2.5 m/s) and racing (4-5.5 m/s) speeds.
    #[arg(long, default_value_t = 1, value_parser = args::whole::<usize>(1, 500))]
    runs: usize,
    /// Logging rate with --manoeuvre [Hz].
    #[arg(long, default_value_t = 40.0, value_parser = args::number(5.0, 200.0))]
    rate: f64,
    /// Channels logged: `all`, or `pose+speed` (no vy, no yaw_rate, as a car with a
    /// localiser and the VESC's speed).
    #[arg(long, default_value = "all")]
    channels: String,
    /// How manoeuvre runs start: rest, moving, or mixed (every other run in motion).
    #[arg(long, default_value = "mixed")]
    start: String,
    /// Seed of the noise, the disturbances and the logging jitter.
    #[arg(long, default_value_t = 0, value_parser = args::seed())]
    seed: u64,
    /// Lateral acceleration the driver plans with [m/s^2].
    #[arg(long, default_value_t = 4.0, value_parser = args::above(0.0, 100.0))]
    lat_accel: f64,
    /// The driver's top speed [m/s].
    #[arg(long, default_value_t = 6.0, value_parser = args::above(0.0, 100.0))]
    max_speed: f64,
    /// Nominal vehicle the effects are added to (default: the simulator's default).
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Output: .csv, or .mcap for a ROS 2 bag. A `<out>.truth.json` sidecar records the
    /// hidden effects.
    #[arg(long)]
    out: PathBuf,
}

/// Measurement noise (standard deviations): x, y [m], yaw [rad], vx, vy [m/s], yaw rate [rad/s].
const NOISE: [f64; 6] = [0.02, 0.02, 0.01, 0.04, 0.03, 0.03];

/// A first-order random process (Ornstein-Uhlenbeck), stepped at `DT`.
struct Ou {
    value: f64,
    tau: f64,
    std: f64,
}

impl Ou {
    fn step(&mut self, rng: &mut Rng) -> f64 {
        let a = libm::exp(-DT / self.tau);
        self.value = a * self.value + self.std * libm::sqrt(1.0 - a * a) * rng.normal();
        self.value
    }
}

pub fn run(args: &SynthArgs, circuits: &Circuits) -> Result<()> {
    let full_state = match args.channels.as_str() {
        "all" => true,
        "pose+speed" => false,
        other => bail!("--channels {other:?}: all or pose+speed"),
    };
    if !args.manoeuvre.is_empty() {
        return run_day(args, full_state);
    }
    let seconds = args.seconds.unwrap_or(60.0);
    if !(5.0..=3600.0).contains(&seconds) {
        bail!(
            "--seconds {seconds} is out of range: must be a number in [5, 3600] without --manoeuvre"
        );
    }
    let map = args.map.clone().unwrap_or_else(|| DEFAULT_MAP.into());
    let circuit = circuits
        .get(&map)
        .with_context(|| format!("loading map {map:?}"))?;
    let nominal = match &args.vehicle {
        Some(p) => VehicleParams::load(p)?,
        None => VehicleParams::default(),
    };
    let line = circuit.driving_line();
    let mut truth = nominal.clone();
    let mut hidden = Vec::new();
    for spec in &args.effects {
        let (kind, mut v) = parse_effect_spec(spec)?;
        if kind == EffectKind::FrictionPatch && v[1..].iter().any(|x| x.is_nan()) {
            // the sharpest bend of the driving line, in a 5 m box
            let p = line
                .iter()
                .max_by(|a, b| a.kappa.abs().total_cmp(&b.kappa.abs()))
                .context("the map has no driving line")?;
            v = vec![v[0], p.x - 2.5, p.y - 2.5, p.x + 2.5, p.y + 2.5];
        }
        if hidden.iter().any(|(k, _)| *k == kind) {
            bail!("--effect {} given twice", kind.name());
        }
        kind.apply(&mut truth, &v);
        hidden.push((kind, v));
    }
    truth
        .validate()
        .context("the effects give an invalid vehicle")?;

    let defaults: Vec<f64> = paddock_policy::pure_pursuit::param_specs()
        .iter()
        .map(|s| s.default)
        .collect();
    let mut pp_params = PurePursuitParams::from_vector(&defaults, &nominal);
    pp_params.lat_accel = args.lat_accel;
    pp_params.max_speed = args.max_speed;
    let mut driver = PurePursuit::on_circuit(&circuit, pp_params);

    let start = line[0];
    let mut car = Vehicle::new(Pose::new(start.x, start.y, start.psi));
    let mut rng = Rng::new(args.seed);
    let mut yaw_push = Ou {
        value: 0.0,
        tau: 0.4,
        std: 0.4,
    };
    let mut speed_push = Ou {
        value: 0.0,
        tau: 0.6,
        std: 0.2,
    };
    let mut rec = Recording::default();
    let mut next_row = 0.0f64;
    let mut cmd = (0.0, 0.0);
    let mut prev = car.state;
    let mut prev_body = car.body_velocity();
    let steps = (seconds / DT).floor() as usize;
    let delay = measurement_delay(&hidden);
    let mut hist = sysid_synth_runs::History {
        t0: 0.0,
        states: Vec::new(),
    };
    for k in 0..=steps {
        let tk = k as f64 * DT;
        hist.push(&car);
        // controller cycles that fall in (t_{k-1}, t_k]: measure, decide, log
        while next_row <= tk + 1e-9 {
            let f = if k == 0 {
                1.0
            } else {
                ((next_row - (tk - DT)) / DT).clamp(0.0, 1.0)
            };
            let now = car.state;
            let lerp = |a: f64, b: f64| a + f * (b - a);
            let (vx0, vy0) = prev_body;
            let (vx1, vy1) = car.body_velocity();
            let exact = if delay > 0.0 {
                // a sensor that lags: the state it reports is `delay` old
                hist.at(next_row - delay)
            } else {
                [
                    lerp(prev.x, now.x),
                    lerp(prev.y, now.y),
                    prev.yaw + f * wrap_pi(now.yaw - prev.yaw),
                    lerp(vx0, vx1),
                    lerp(vy0, vy1),
                    lerp(prev.yaw_rate, now.yaw_rate),
                ]
            };
            let m: [f64; 6] = std::array::from_fn(|c| exact[c] + NOISE[c] * rng.normal());
            let dropped = next_row > 0.0 && rng.uniform() < 0.03;
            if !dropped {
                let a = driver.act_pose(Pose::new(m[0], m[1], m[2]), m[3]);
                cmd = (a.steer, a.speed);
                sysid_synth_runs::push_row(&mut rec, next_row, cmd, &m, full_state);
            }
            next_row = ((next_row + 0.025 + rng.uniform_range(-0.005, 0.005)) * 1e4).round() / 1e4;
        }
        if k == steps {
            break;
        }
        prev = car.state;
        prev_body = car.body_velocity();
        car.step(&truth, cmd.0, cmd.1, DT);
        // random disturbances: small pushes in yaw and speed while moving
        let moving = (car.state.v.abs() / 1.0).min(1.0);
        let r = yaw_push.step(&mut rng);
        let a = speed_push.step(&mut rng);
        car.state.yaw_rate += moving * r * DT;
        car.state.v += moving * a * DT;
        if !car.state.v.is_finite() || car.state.v.abs() > 50.0 {
            bail!("the car became unstable at t = {tk:.2} s with these effects; try milder values");
        }
    }

    let out = &args.out;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let is_mcap = out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    if is_mcap {
        std::fs::write(out, rec.to_mcap(&RecordingTopics::default())?)
    } else {
        std::fs::write(out, rec.to_csv_string())
    }
    .with_context(|| format!("writing {}", out.display()))?;
    let truth_json = json!({
        "map": circuit.name,
        "seed": args.seed,
        "seconds": seconds,
        "effects": hidden.iter().map(|(k, v)| json!({"name": k.name(), "params": k.params_json(v)})).collect::<Vec<_>>(),
        "noise_std": {"x": NOISE[0], "y": NOISE[1], "yaw": NOISE[2], "vx": NOISE[3], "vy": NOISE[4], "yaw_rate": NOISE[5]},
    });
    let mut sidecar = out.as_os_str().to_owned();
    sidecar.push(".truth.json");
    let sidecar = PathBuf::from(sidecar);
    std::fs::write(&sidecar, serde_json::to_string_pretty(&truth_json)?)
        .with_context(|| format!("writing {}", sidecar.display()))?;
    outln!(
        "wrote {} ({} rows over {:.1} s on {}, hidden: {}) and {}",
        out.display(),
        rec.states.len(),
        seconds,
        circuit.name,
        if hidden.is_empty() {
            "nothing".to_string()
        } else {
            hidden
                .iter()
                .map(|(k, v)| format!("{} {}", k.name(), k.params_json(v)))
                .collect::<Vec<_>>()
                .join(", ")
        },
        sidecar.display()
    );
    Ok(())
}

/// The hidden measurement delay (0 without one).
fn measurement_delay(hidden: &[(EffectKind, Vec<f64>)]) -> f64 {
    hidden
        .iter()
        .find(|(k, _)| *k == EffectKind::MeasurementDelay)
        .map_or(0.0, |(_, v)| v[0])
}

/// `--manoeuvre`: a test day of short runs into the folder `--out`.
fn run_day(args: &SynthArgs, full_state: bool) -> Result<()> {
    let seconds = args.seconds.unwrap_or(3.0);
    if !(seconds.is_finite() && (2.0..=120.0).contains(&seconds)) {
        bail!("--seconds {seconds} is out of range: must be a number in [2, 120] with --manoeuvre");
    }
    if !["rest", "moving", "mixed"].contains(&args.start.as_str()) {
        bail!("--start {:?}: rest, moving or mixed", args.start);
    }
    let manoeuvres: Vec<Manoeuvre> = args
        .manoeuvre
        .iter()
        .map(|m| Manoeuvre::parse(m))
        .collect::<Result<_>>()?;
    let nominal = match &args.vehicle {
        Some(p) => VehicleParams::load(p)?,
        None => VehicleParams::default(),
    };
    let mut truth = nominal.clone();
    let mut hidden = Vec::new();
    for spec in &args.effects {
        let (kind, v) = parse_effect_spec(spec)?;
        if kind == EffectKind::FrictionPatch && v[1..].iter().any(|x| x.is_nan()) {
            bail!(
                "--effect friction_patch needs its region (xmin, ymin, xmax, ymax) with --manoeuvre"
            );
        }
        if hidden.iter().any(|(k, _)| *k == kind) {
            bail!("--effect {} given twice", kind.name());
        }
        kind.apply(&mut truth, &v);
        hidden.push((kind, v));
    }
    truth
        .validate()
        .context("the effects give an invalid vehicle")?;
    let plan = DayPlan {
        manoeuvres,
        runs: args.runs,
        seconds,
        rate_hz: args.rate,
        full_state,
        start: args.start.clone(),
        seed: args.seed,
        noise: NOISE,
        measurement_delay: measurement_delay(&hidden),
    };
    let dir = &args.out;
    let runs = sysid_synth_runs::write_day(&plan, &truth, dir)?;
    let truth_json = json!({
        "seed": args.seed,
        "seconds_per_run": seconds,
        "rate_hz": args.rate,
        "channels": args.channels,
        "runs": runs,
        "effects": hidden.iter().map(|(k, v)| json!({"name": k.name(), "params": k.params_json(v)})).collect::<Vec<_>>(),
        "noise_std": {"x": NOISE[0], "y": NOISE[1], "yaw": NOISE[2], "vx": NOISE[3], "vy": NOISE[4], "yaw_rate": NOISE[5]},
    });
    let sidecar = dir.join("truth.json");
    std::fs::write(&sidecar, serde_json::to_string_pretty(&truth_json)?)
        .with_context(|| format!("writing {}", sidecar.display()))?;
    outln!(
        "wrote {} runs of {seconds} s into {} (hidden: {}) and {}",
        args.runs,
        dir.display(),
        if hidden.is_empty() {
            "nothing".to_string()
        } else {
            hidden
                .iter()
                .map(|(k, v)| format!("{} {}", k.name(), k.params_json(v)))
                .collect::<Vec<_>>()
                .join(", ")
        },
        sidecar.display()
    );
    Ok(())
}
