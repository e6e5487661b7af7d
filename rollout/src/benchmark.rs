//! The three benchmark tasks of the F1TENTH paper.
//!
//! - **B1, time trial**: one car from seeded random starts; lap time (mean ± std over
//!   every collision-free lap) and completion rate.
//! - **B2, obstacles**: as B1 with seeded random static boxes on the track that the
//!   driver is not told about (only a LIDAR driver can see them); success rate (all laps
//!   without a collision) and the lap time of successful runs.
//! - **B3, head to head**: the driver under test (car 0) against an opponent; episodes come in
//!   pairs with the same seed and the grid positions swapped; average lap time, crash
//!   rate and win rate of the driver (it finishes, and before the opponent if both do).

use std::sync::Arc;

use paddock_sim::collision::CollisionMode;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::world::ObstacleConfig;
use serde::{Deserialize, Serialize};

use crate::{
    AgentSpec, EpisodeResult, EpisodeTask, RolloutError, Scenario, StartSpec, Termination,
    task_seed,
};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Task {
    B1,
    B2,
    B3,
}

impl std::str::FromStr for Task {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "b1" => Ok(Task::B1),
            "b2" => Ok(Task::B2),
            "b3" => Ok(Task::B3),
            other => Err(format!(
                "unknown benchmark task {other:?} (expected b1, b2 or b3)"
            )),
        }
    }
}

impl std::fmt::Display for Task {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Task::B1 => "B1",
            Task::B2 => "B2",
            Task::B3 => "B3",
        })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchmarkSpec {
    pub task: Task,
    pub map: String,
    /// The driver under test (car 0); `policy` in specs stored before the rename.
    #[serde(alias = "policy")]
    pub driver: AgentSpec,
    /// B3's opponent.
    pub opponent: Option<AgentSpec>,
    pub episodes: usize,
    pub seed: u64,
    pub laps: u32,
    /// B2's obstacle count.
    pub obstacles: usize,
    pub time_limit: f64,
}

impl BenchmarkSpec {
    /// The tasks to run, in episode order.
    pub fn tasks(&self) -> Result<Vec<EpisodeTask>, RolloutError> {
        if self.episodes == 0 || self.episodes > 100_000 {
            return Err(RolloutError::Invalid {
                field: "episodes".into(),
                value: self.episodes.to_string(),
                reason: "must be 1..=100000".into(),
            });
        }
        let mut agents = vec![self.driver.clone()];
        if self.task == Task::B3 {
            let Some(opp) = &self.opponent else {
                return Err(RolloutError::Invalid {
                    field: "opponent".into(),
                    value: "none".into(),
                    reason: "benchmark B3 needs an opponent".into(),
                });
            };
            agents.push(opp.clone());
        }
        let base = Scenario {
            map: self.map.clone(),
            agents,
            starts: StartSpec::Random,
            obstacles: ObstacleConfig {
                count: if self.task == Task::B2 {
                    self.obstacles
                } else {
                    0
                },
                ..ObstacleConfig::default()
            },
            laps: self.laps,
            time_limit: self.time_limit,
            collision_mode: CollisionMode::Terminate,
            lidar: LidarConfig::default(),
            crash_penalty: 100.0,
        };
        base.validate()?;
        let forward = Arc::new(base.clone());
        let swapped = Arc::new(Scenario {
            starts: StartSpec::RandomReversed,
            ..base
        });
        Ok((0..self.episodes)
            .map(|k| {
                if self.task == Task::B3 {
                    // pairs share a seed; the second of each pair swaps the grid
                    EpisodeTask {
                        scenario: if k % 2 == 0 {
                            forward.clone()
                        } else {
                            swapped.clone()
                        },
                        seed: task_seed(self.seed, (k / 2) as u64),
                        record: None,
                    }
                } else {
                    EpisodeTask {
                        scenario: forward.clone(),
                        seed: task_seed(self.seed, k as u64),
                        record: None,
                    }
                }
            })
            .collect())
    }
}

/// Mean and sample standard deviation.
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = if v.len() > 1 {
        v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    (mean, var.sqrt())
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchmarkReport {
    pub task: Task,
    pub map: String,
    /// The driver under test (`policy` in reports written before the rename).
    #[serde(alias = "policy")]
    pub driver: String,
    pub opponent: Option<String>,
    pub episodes: usize,
    /// Laps counted in the lap time.
    pub laps_counted: usize,
    pub lap_time_mean: Option<f64>,
    pub lap_time_std: Option<f64>,
    /// Episodes in which the driver completed every lap without a collision.
    pub success_rate: f64,
    pub crash_rate: f64,
    /// B3 only.
    pub win_rate: Option<f64>,
    pub errors: usize,
}

fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// Reduce the episodes (in task order) to the task's figures.
pub fn report(
    spec: &BenchmarkSpec,
    results: &[Result<EpisodeResult, RolloutError>],
) -> BenchmarkReport {
    let ok: Vec<&EpisodeResult> = results.iter().filter_map(|r| r.as_ref().ok()).collect();
    let n = ok.len().max(1) as f64;
    let mut laps = Vec::new();
    let mut successes = 0usize;
    let mut crashes = 0usize;
    let mut wins = 0usize;
    for e in &ok {
        let me = &e.agents[0];
        let success = me.termination == Termination::Finished && !me.collided;
        if me.termination == Termination::Crashed {
            crashes += 1;
        }
        match spec.task {
            // laps before a crash are collision-free
            Task::B1 | Task::B3 => laps.extend_from_slice(&me.lap_times),
            Task::B2 => {
                if success {
                    laps.extend_from_slice(&me.lap_times)
                }
            }
        }
        if success {
            successes += 1;
        }
        if spec.task == Task::B3 {
            let other = &e.agents[1];
            let won = me.termination == Termination::Finished
                && match (other.termination, me.end_time, other.end_time) {
                    (Termination::Finished, Some(a), Some(b)) => a < b,
                    _ => true,
                };
            if won {
                wins += 1;
            }
        }
    }
    let (m, s) = mean_std(&laps);
    BenchmarkReport {
        task: spec.task,
        map: ok
            .first()
            .map(|e| e.map.clone())
            .unwrap_or_else(|| spec.map.clone()),
        driver: spec.driver.driver.clone(),
        opponent: spec.opponent.as_ref().map(|o| o.driver.clone()),
        episodes: results.len(),
        laps_counted: laps.len(),
        lap_time_mean: finite(m),
        lap_time_std: finite(s),
        success_rate: successes as f64 / n,
        crash_rate: crashes as f64 / n,
        win_rate: (spec.task == Task::B3).then(|| wins as f64 / n),
        errors: results.len() - ok.len(),
    }
}

impl BenchmarkReport {
    fn cells(&self) -> Vec<String> {
        let lap = match (self.lap_time_mean, self.lap_time_std) {
            (Some(m), Some(s)) => format!("{m:.2} ± {s:.2}"),
            _ => "-".into(),
        };
        let pct = |x: f64| format!("{:.0}%", 100.0 * x);
        vec![
            self.task.to_string(),
            self.map.clone(),
            self.driver.clone(),
            self.opponent.clone().unwrap_or_else(|| "-".into()),
            self.episodes.to_string(),
            lap,
            pct(self.success_rate),
            pct(self.crash_rate),
            self.win_rate.map(pct).unwrap_or_else(|| "-".into()),
        ]
    }

    pub const HEADER: [&'static str; 9] = [
        "task",
        "map",
        "driver",
        "opponent",
        "episodes",
        "lap time [s]",
        "success",
        "crash",
        "win",
    ];

    /// Markdown table rows for several reports.
    pub fn markdown(reports: &[BenchmarkReport]) -> String {
        let mut s = format!("| {} |\n", Self::HEADER.join(" | "));
        s += &format!("|{}\n", " --- |".repeat(Self::HEADER.len()));
        for r in reports {
            s += &format!("| {} |\n", r.cells().join(" | "));
        }
        s
    }

    /// A plain aligned table for a terminal.
    pub fn table(reports: &[BenchmarkReport]) -> String {
        let rows: Vec<Vec<String>> =
            std::iter::once(Self::HEADER.iter().map(|s| s.to_string()).collect())
                .chain(reports.iter().map(|r| r.cells()))
                .collect();
        let widths: Vec<usize> = (0..Self::HEADER.len())
            .map(|c| rows.iter().map(|r| r[c].chars().count()).max().unwrap_or(0))
            .collect();
        let mut s = String::new();
        for r in rows {
            let line: Vec<String> = r
                .iter()
                .zip(&widths)
                .map(|(cell, w)| format!("{cell:<w$}"))
                .collect();
            s += line.join("  ").trim_end();
            s += "\n";
        }
        s
    }
}
