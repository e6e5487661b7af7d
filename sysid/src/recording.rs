//! Recordings of a real (or synthetic) car: commands sent and states measured.
//!
//! Commands and states are kept as two event lists, because a ROS 2 bag logs them on
//! separate topics at separate times; a CSV row carries both at one time. A command holds
//! from its own time until the next one; the physics step at `t_k = k dt` uses the last
//! command with `t <= t_k` (0 before the first).

use std::path::Path;

pub use paddock_recordings::track::RecordingTopics;

use crate::SysidError;

mod bag;
pub mod clean;
pub mod csv;

/// Columns of a CSV recording (any order; extra columns are ignored). The first six are
/// required; `vx`, `vy` and `yaw_rate` may be absent or empty (not measured).
pub const CSV_COLUMNS: [&str; 9] = [
    "t",
    "steer_cmd",
    "speed_cmd",
    "x",
    "y",
    "yaw",
    "vx",
    "vy",
    "yaw_rate",
];

/// Shortest recording the analysis accepts, all runs together [s].
pub const MIN_DURATION_S: f64 = 5.0;
/// Fewest state samples the analysis accepts, all runs together.
pub const MIN_SAMPLES: usize = 100;
/// Shortest run kept [s]; shorter runs are dropped with a warning.
pub const MIN_RUN_S: f64 = 2.0;
/// Space left between runs when several are put on one time axis [s].
const RUN_SPACING_S: f64 = 0.1;

/// A command as sent to the car.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    pub t: f64,
    /// Steering angle command [rad].
    pub steer: f64,
    /// Speed command [m/s].
    pub speed: f64,
}

/// A measured state of the centre of gravity. A channel that was not measured at a sample
/// is NaN (pose-and-speed logs have no `vy` and `yaw_rate`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StateSample {
    pub t: f64,
    pub x: f64,
    pub y: f64,
    /// [rad], wrapped to [-pi, pi).
    pub yaw: f64,
    /// Body-frame velocities [m/s].
    pub vx: f64,
    pub vy: f64,
    pub yaw_rate: f64,
}

/// The six compared channels, in report order.
pub const CHANNELS: [&str; 6] = ["x", "y", "yaw", "vx", "vy", "yaw_rate"];

impl StateSample {
    /// The channels in [`CHANNELS`] order.
    pub fn channels(&self) -> [f64; 6] {
        [self.x, self.y, self.yaw, self.vx, self.vy, self.yaw_rate]
    }
}

/// A loaded recording: one or more runs on one time axis, one after the other.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    pub commands: Vec<Command>,
    pub states: Vec<StateSample>,
    /// Problems that did not stop the load (for the report).
    pub warnings: Vec<String>,
    /// The runs; empty means one run holding every sample (see [`Recording::runs`]).
    pub run_info: Vec<RunInfo>,
}

/// One run (a stretch of continuous logging) inside a [`Recording`].
#[derive(Debug, Clone, PartialEq)]
pub struct RunInfo {
    /// File name, with `#k` when a file held several runs.
    pub name: String,
    /// Time of its first and last sample on the recording's time axis [s].
    pub start: f64,
    pub end: f64,
    /// Its samples: `states[first_state..first_state + n_states]`.
    pub first_state: usize,
    pub n_states: usize,
    /// The source's own time of the run's first sample (epoch seconds in a ROS log).
    pub t_offset: f64,
}

/// The channels to fit, in [`CHANNELS`] order, from `all` or a `+`-joined list of
/// `pose` (x, y, yaw: always fitted, so it must be named), `speed` (or `vx`), `vy` and
/// `yaw_rate`: `pose+speed` for a car whose odometry's yaw rate is computed from the
/// steering command rather than measured.
pub fn parse_channels(text: &str) -> Result<[bool; 6], String> {
    let text = text.trim();
    if text == "all" {
        return Ok([true; 6]);
    }
    let mut keep = [false; 6];
    for part in text.split('+').map(str::trim) {
        match part {
            "pose" => keep[..3].fill(true),
            "speed" | "vx" => keep[3] = true,
            "vy" => keep[4] = true,
            "yaw_rate" => keep[5] = true,
            other => {
                return Err(format!(
                    "{other:?} is not a channel; use all, or pose joined by + with any of speed (vx), \
                     vy, yaw_rate (pose+speed)"
                ));
            }
        }
    }
    if !keep[0] {
        return Err(format!(
            "{text:?} leaves out the pose, which is always fitted: name it (pose, pose+speed, ...)"
        ));
    }
    Ok(keep)
}

/// What to record when there is not enough.
pub const SHORT_HINT: &str = "record more: a few 3-s runs of steering steps at 2 and at 5 m/s, \
constant-radius arcs and speed steps are enough";

/// Wrap an angle to [-pi, pi): the simulator's own wrap.
pub use paddock_sim::geometry::wrap_angle as wrap_pi;

impl Recording {
    /// Load a recording: a ROS 2 bag (an `.mcap` file, one never finalised read up to its
    /// last complete chunk; a rosbag2 bag folder in SQLite3 or MCAP storage; a `.db3`
    /// file), or else a CSV file.
    pub fn load(path: &Path, topics: &RecordingTopics) -> Result<Self, SysidError> {
        let rec = Self::load_inner(path, topics)?;
        rec.check()?;
        Ok(rec)
    }

    fn load_inner(path: &Path, topics: &RecordingTopics) -> Result<Self, SysidError> {
        let rec = if paddock_recordings::is_bag(path) {
            let bag = paddock_recordings::read_bag(
                path,
                &topics.all().iter().map(String::as_str).collect::<Vec<_>>(),
            )
            .map_err(|e| SysidError::Format {
                message: e.to_string(),
            })?;
            Self::from_bag(bag, topics, path)?
        } else {
            let bytes = std::fs::read(path).map_err(|source| SysidError::Io {
                path: path.display().to_string(),
                source,
            })?;
            let text = String::from_utf8(bytes).map_err(|e| SysidError::Format {
                message: format!(
                    "{} is not UTF-8 text (byte {}): not a CSV recording",
                    path.display(),
                    e.utf8_error().valid_up_to()
                ),
            })?;
            let name = path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            Self::from_csv_named(&text, &name)?
        };
        Ok(rec)
    }

    /// Every run, in time order (one covering everything when [`Self::run_info`] is empty).
    pub fn runs(&self) -> Vec<RunInfo> {
        if !self.run_info.is_empty() {
            return self.run_info.clone();
        }
        vec![RunInfo {
            name: "recording".into(),
            start: self.states.first().map_or(0.0, |s| s.t),
            end: self.duration(),
            first_state: 0,
            n_states: self.states.len(),
            t_offset: 0.0,
        }]
    }

    /// Put several recordings on one time axis, each run after the previous one
    /// (commands before a run's start count from its start). Runs shorter than
    /// [`MIN_RUN_S`] are dropped with a warning.
    pub fn join(parts: Vec<Recording>) -> Recording {
        let mut out = Recording::default();
        // short runs go only when something longer stays (else `check` says "too short")
        let any_long = parts
            .iter()
            .flat_map(|p| p.runs())
            .any(|r| r.end - r.start >= MIN_RUN_S);
        for part in parts {
            for w in &part.warnings {
                // the same words from many files once (the count is in the report's runs)
                let generic = w.split_once(": ").map_or(w.as_str(), |(_, rest)| rest);
                if !out.warnings.iter().any(|o| o == w || o.ends_with(generic)) {
                    out.warnings.push(w.clone());
                }
            }
            for run in part.runs() {
                if any_long && run.end - run.start < MIN_RUN_S {
                    out.warnings.push(format!(
                        "{}: run of {:.2} s ({} samples) dropped: shorter than {MIN_RUN_S} s",
                        run.name,
                        run.end - run.start,
                        run.n_states
                    ));
                    continue;
                }
                let shift = if out.states.is_empty() {
                    -run.start
                } else {
                    ((out.duration() + RUN_SPACING_S) / RUN_SPACING_S).ceil() * RUN_SPACING_S
                        - run.start
                };
                let first_state = out.states.len();
                let states = &part.states[run.first_state..run.first_state + run.n_states];
                out.states.extend(states.iter().map(|s| StateSample {
                    t: s.t + shift,
                    ..*s
                }));
                // the commands of this run: from the last one in force at its start
                let lo = part.commands.partition_point(|c| c.t <= run.start);
                let hi = part.commands.partition_point(|c| c.t <= run.end);
                let from = lo.saturating_sub(1);
                out.commands
                    .extend(part.commands[from..hi].iter().map(|c| Command {
                        t: c.t.max(run.start) + shift,
                        ..*c
                    }));
                out.run_info.push(RunInfo {
                    start: run.start + shift,
                    end: run.end + shift,
                    first_state,
                    ..run
                });
            }
        }
        out
    }

    /// [`Self::load`] without the length check (for recordings joined afterwards).
    pub fn read(path: &Path, topics: &RecordingTopics) -> Result<Self, SysidError> {
        Self::load_inner(path, topics)
    }

    /// Leave out the velocity channels that `keep` (in [`CHANNELS`] order, from
    /// [`parse_channels`]) does not hold, as if they were not measured; a warning names
    /// them and `given` (the user's words).
    pub fn keep_channels(&mut self, keep: [bool; 6], given: &str) {
        let dropped: Vec<&str> = (0..6)
            .filter(|&c| !keep[c] && self.states.iter().any(|s| s.channels()[c].is_finite()))
            .map(|c| CHANNELS[c])
            .collect();
        if dropped.is_empty() {
            return;
        }
        for s in &mut self.states {
            for (c, v) in [&mut s.vx, &mut s.vy, &mut s.yaw_rate]
                .into_iter()
                .enumerate()
            {
                if !keep[3 + c] {
                    *v = f64::NAN;
                }
            }
        }
        self.warnings.push(format!(
            "measured but left out (--channels {given}): {}",
            dropped.join(", ")
        ));
    }

    /// Channels (in [`CHANNELS`] order) with no measurement at all.
    pub fn missing_channels(&self) -> [bool; 6] {
        std::array::from_fn(|c| self.states.iter().all(|s| !s.channels()[c].is_finite()))
    }

    /// The run holding time `t` and the time inside it.
    pub fn run_at(&self, t: f64) -> (String, f64) {
        let runs = self.runs();
        let i = runs.partition_point(|r| r.start <= t).saturating_sub(1);
        runs.get(i)
            .map_or((String::new(), t), |r| (r.name.clone(), t - r.start))
    }

    /// Sum of the runs' durations [s].
    pub fn total_duration(&self) -> f64 {
        self.runs().iter().map(|r| r.end - r.start).sum()
    }

    /// Parse CSV text with the header [`CSV_COLUMNS`] (extra columns ignored), leniently
    /// ([`csv::parse`]), and cut it into runs ([`clean::split`]).
    pub fn from_csv_str(text: &str) -> Result<Self, SysidError> {
        Self::from_csv_named(text, "recording")
    }

    /// [`Self::from_csv_str`], naming the runs after `name`.
    pub fn from_csv_named(text: &str, name: &str) -> Result<Self, SysidError> {
        let p = csv::parse(text)?;
        let runs = clean::into_runs(p.commands, p.states, true, p.warnings, name)?;
        Ok(Self::join(runs))
    }

    /// Refuse recordings too short to say anything (all runs together).
    pub fn check(&self) -> Result<(), SysidError> {
        let n = self.states.len();
        let duration = self.total_duration();
        if n < MIN_SAMPLES || duration < MIN_DURATION_S {
            return Err(SysidError::TooShort {
                samples: n,
                duration_s: duration,
                runs: self.runs().len(),
                min_samples: MIN_SAMPLES,
                min_duration_s: MIN_DURATION_S,
                hint: SHORT_HINT.into(),
            });
        }
        if self.commands.is_empty() {
            return Err(SysidError::Format {
                message: "the recording has no commands".into(),
            });
        }
        Ok(())
    }

    /// Time of the last state sample [s] (the end of the last run).
    pub fn duration(&self) -> f64 {
        self.states.last().map_or(0.0, |s| s.t)
    }

    /// Commands held onto the physics grid: entry k is the command acting at `k dt`.
    pub fn commands_on_grid(&self, dt: f64, steps: usize) -> Vec<(f64, f64)> {
        let mut out = Vec::with_capacity(steps);
        let mut j = 0usize;
        let mut cur = (0.0, 0.0);
        for k in 0..steps {
            // a small tolerance so a row logged at exactly k dt counts for step k
            let tk = k as f64 * dt + 1e-9;
            while j < self.commands.len() && self.commands[j].t <= tk {
                cur = (self.commands[j].steer, self.commands[j].speed);
                j += 1;
            }
            out.push(cur);
        }
        out
    }

    /// Write the CSV form (one row per state sample, with the command in force then). A
    /// channel never measured has no column; one not measured at a sample, an empty cell.
    pub fn to_csv_string(&self) -> String {
        let missing = self.missing_channels();
        let cols: Vec<&str> = CSV_COLUMNS
            .iter()
            .enumerate()
            .filter(|(k, _)| *k < 3 || !missing[k - 3])
            .map(|(_, c)| *c)
            .collect();
        let mut s = cols.join(",");
        s.push('\n');
        let mut j = 0usize;
        let mut cur = (0.0, 0.0);
        let prec = [5usize, 5, 6, 5, 5, 5];
        for st in &self.states {
            while j < self.commands.len() && self.commands[j].t <= st.t {
                cur = (self.commands[j].steer, self.commands[j].speed);
                j += 1;
            }
            s.push_str(&format!("{:.4},{:.6},{:.5}", st.t, cur.0, cur.1));
            for (c, v) in st.channels().iter().enumerate() {
                if missing[c] {
                    continue;
                }
                if v.is_finite() {
                    s.push_str(&format!(",{:.*}", prec[c], v));
                } else {
                    s.push(',');
                }
            }
            s.push('\n');
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn csv(rows: usize) -> String {
        let mut s = String::from("t,steer_cmd,speed_cmd,x,y,yaw,vx,vy,yaw_rate,extra\n");
        for i in 0..rows {
            let t = i as f64 * 0.025;
            s.push_str(&format!("{t},0.1,2.0,{t},0,0,1.0,0,0,7\n"));
        }
        s
    }

    #[test]
    fn csv_loads_with_extra_columns_and_any_order() {
        let r = Recording::from_csv_str(&csv(300)).unwrap();
        r.check().unwrap();
        assert_eq!(r.states.len(), 300);
        assert_eq!(r.commands[3].speed, 2.0);
        let swapped = "yaw_rate,t,steer_cmd,speed_cmd,x,y,yaw,vx,vy\n0.5,0,0.1,2,0,0,0,0,0\n";
        let r = Recording::from_csv_str(swapped).unwrap();
        assert_eq!(r.states[0].yaw_rate, 0.5);
    }

    #[test]
    fn csv_errors_name_the_problem() {
        let e = Recording::from_csv_str("t,steer_cmd,x\n0,0,0\n").unwrap_err();
        assert!(e.to_string().contains("speed_cmd"), "{e}");
        let e =
            Recording::from_csv_str("t,steer_cmd,speed_cmd,x,y,yaw\n0,a,b,c,d,e\n").unwrap_err();
        assert!(
            e.to_string().contains("no usable rows") && e.to_string().contains("\"a\""),
            "{e}"
        );
        let e = Recording::from_csv_str(&csv(20))
            .unwrap()
            .check()
            .unwrap_err();
        assert!(e.to_string().contains("too short"), "{e}");
    }

    /// Rows that cannot be used are skipped and counted, naming the first ones.
    #[test]
    fn regression_one_nan_or_text_row_no_longer_rejects_the_file() {
        let mut bad = csv(300);
        bad.push_str("7.5,abc,2,0,0,0,0,0,0,0\n");
        bad.push_str("7.525,NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN\n");
        bad.push_str("7.55,0.1\n");
        let r = Recording::from_csv_str(&bad).unwrap();
        assert_eq!(r.states.len(), 300);
        let w = r.warnings.join(" | ");
        assert!(w.contains("3 of 303 rows skipped"), "{w}");
        assert!(w.contains("row 302") && w.contains("abc"), "{w}");
    }

    /// ROS logs stamp rows with epoch seconds: time is taken from the first row, and the
    /// offset kept (it used to size a 2.7 TB allocation).
    #[test]
    fn regression_epoch_timestamps_start_at_zero() {
        let text = csv(300).replace("\n0,", "\n1700000000,");
        let mut s = String::from("t,steer_cmd,speed_cmd,x,y,yaw,vx,vy,yaw_rate\n");
        for i in 0..300 {
            let t = 1_700_000_000.0 + i as f64 * 0.025;
            s.push_str(&format!("{t:.3},0.1,2,{},0,0,1,0,0\n", i as f64 * 0.025));
        }
        let r = Recording::from_csv_str(&s).unwrap();
        r.check().unwrap();
        assert_eq!(r.states[0].t, 0.0);
        assert!((r.duration() - 7.475).abs() < 1e-6, "{}", r.duration());
        assert_eq!(r.runs()[0].t_offset, 1_700_000_000.0);
        assert!(!text.is_empty());
    }

    /// One stray row far in the future used to hang the replay (10^7 steps).
    #[test]
    fn regression_a_stray_row_is_skipped_not_simulated() {
        let mut text = csv(300);
        text.push_str("100000,0,0,0,0,0,0,0,0,0\n");
        let r = Recording::from_csv_str(&text).unwrap();
        assert_eq!(r.states.len(), 300);
        assert!(r.duration() < 8.0);
        assert!(
            r.warnings.iter().any(|w| w.contains("stray")),
            "{:?}",
            r.warnings
        );
        let mut back = csv(300);
        back.insert_str(back.find("\n5,").unwrap(), "\n0.1,0,0,0,0,0,0,0,0,0");
        let r = Recording::from_csv_str(&back).unwrap();
        assert_eq!(r.states.len(), 300);
        assert_eq!(r.runs().len(), 1);
    }

    /// A byte-order mark used to read as a missing `t` column.
    #[test]
    fn regression_a_byte_order_mark_is_ignored() {
        let text = format!("\u{feff}{}", csv(300));
        let r = Recording::from_csv_str(&text).unwrap();
        assert_eq!(r.states.len(), 300);
    }

    #[test]
    fn channels_are_chosen_by_name_and_left_out_as_unmeasured() {
        assert_eq!(parse_channels("all"), Ok([true; 6]));
        assert_eq!(
            parse_channels(" pose + speed "),
            Ok([true, true, true, true, false, false])
        );
        assert_eq!(
            parse_channels("pose+vx+yaw_rate"),
            Ok([true, true, true, true, false, true])
        );
        assert_eq!(
            parse_channels("pose"),
            Ok([true, true, true, false, false, false])
        );
        let e = parse_channels("pose+speeed").unwrap_err();
        assert!(e.contains("\"speeed\" is not a channel"), "{e}");
        assert!(
            parse_channels("speed")
                .unwrap_err()
                .contains("leaves out the pose")
        );
        assert!(parse_channels("").is_err());

        let mut r = Recording::from_csv_str(&csv(300)).unwrap();
        r.keep_channels(parse_channels("pose+speed").unwrap(), "pose+speed");
        assert_eq!(
            r.missing_channels(),
            [false, false, false, false, true, true]
        );
        assert_eq!(r.states[1].vx, 1.0);
        assert!(r.states[1].vy.is_nan());
        assert_eq!(
            r.warnings.last().unwrap(),
            "measured but left out (--channels pose+speed): vy, yaw_rate"
        );
        // nothing measured is left out: no warning
        let n = r.warnings.len();
        r.keep_channels(parse_channels("pose+speed").unwrap(), "pose+speed");
        assert_eq!(r.warnings.len(), n);
    }

    /// A log with a long gap or a restart of time holds several runs; pose-and-speed
    /// logs have no `vy` or `yaw_rate` column.
    #[test]
    fn gaps_make_runs_and_velocity_channels_are_optional() {
        let mut s = String::from("\"t\",steer_cmd,speed_cmd,x,y,yaw,vx\n");
        for i in 0..120 {
            s.push_str(&format!("{},0.1,2,0,0,0,1.0\n", i as f64 * 0.025));
        }
        for i in 0..120 {
            s.push_str(&format!("{},0.1,2,0,0,0,\n", 10.0 + i as f64 * 0.025));
        }
        let r = Recording::from_csv_str(&s).unwrap();
        r.check().unwrap();
        let runs = r.runs();
        assert_eq!(runs.len(), 2, "{:?}", r.warnings);
        assert!(runs[1].start > runs[0].end && runs[1].start < runs[0].end + 0.3);
        assert_eq!(
            r.missing_channels(),
            [false, false, false, false, true, true]
        );
        assert!(r.states[130].vx.is_nan());
        assert!(
            r.warnings.iter().any(|w| w.contains("vy, yaw_rate")),
            "{:?}",
            r.warnings
        );
        // a command before the second run's start does not leak into it
        let g = r.commands_on_grid(crate::replay::DT, (r.duration() / 0.01) as usize);
        assert!(g.iter().all(|c| c.1 == 2.0 || c.1 == 0.0));
    }

    #[test]
    fn commands_hold_until_the_next_row() {
        let r = Recording {
            commands: vec![
                Command {
                    t: 0.0,
                    steer: 0.1,
                    speed: 1.0,
                },
                Command {
                    t: 0.025,
                    steer: 0.2,
                    speed: 2.0,
                },
                Command {
                    t: 0.05,
                    steer: 0.3,
                    speed: 3.0,
                },
            ],
            ..Recording::default()
        };
        let g = r.commands_on_grid(0.01, 7);
        let speeds: Vec<f64> = g.iter().map(|c| c.1).collect();
        assert_eq!(speeds, vec![1.0, 1.0, 1.0, 2.0, 2.0, 3.0, 3.0]);
    }

    #[test]
    fn wrap_pi_range() {
        for a in [-10.0, -3.2, 0.0, 3.1, 3.2, 7.0] {
            let w = wrap_pi(a);
            assert!((-std::f64::consts::PI..std::f64::consts::PI).contains(&w));
            assert!((libm::sin(w) - libm::sin(a)).abs() < 1e-12);
        }
    }
}
