//! Where the nominal model's residual concentrates: time segments, operating regimes
//! (speed, lateral acceleration, steering rate, braking) and places on the track.
//!
//! Each sample's score is its noise-normalised squared residual averaged over the six
//! channels; a group's `ratio` is its mean score over the recording's mean score (1 =
//! typical, 3 = three times the typical residual) and `share` its part of the total.

use serde_json::{Value, json};

use crate::recording::{CHANNELS, Recording};
use crate::replay::{DT, Replay, Residuals};

/// Groups below this many samples are not reported.
const MIN_GROUP: usize = 20;
/// A group is reported when its ratio reaches this.
const CONCENTRATED: f64 = 1.5;
/// Side of an x-y cell [m].
pub const CELL_M: f64 = 2.0;

/// One group's statistics.
#[derive(Debug, Clone)]
pub struct Group {
    pub kind: &'static str,
    /// For regimes: the quantity binned.
    pub label: String,
    /// Time segment [t0, t1], regime range [lo, hi], or cell [xmin, ymin, xmax, ymax].
    pub range: Vec<f64>,
    pub samples: usize,
    /// Mean noise-normalised squared residual of the group's samples.
    pub score: f64,
    pub ratio: f64,
    pub share: f64,
    pub rmse: [f64; 6],
}

impl Group {
    pub fn to_json(&self) -> Value {
        let rmse: serde_json::Map<String, Value> = CHANNELS
            .iter()
            .zip(self.rmse)
            .map(|(c, v)| ((*c).to_string(), json!(round(v))))
            .collect();
        let mut m = json!({
            "kind": self.kind,
            "ratio": round(self.ratio),
            "share": round(self.share),
            "samples": self.samples,
            "rmse": rmse,
        });
        match self.kind {
            "time" => {
                m["t0"] = json!(round(self.range[0]));
                m["t1"] = json!(round(self.range[1]));
            }
            "regime" => {
                m["regime"] = json!(self.label);
                m["range"] = json!([round(self.range[0]), round(self.range[1])]);
            }
            _ => {
                m["cell"] = json!(self.range.iter().map(|v| round(*v)).collect::<Vec<_>>());
            }
        }
        m
    }
}

fn round(v: f64) -> f64 {
    if v.is_finite() {
        (v * 1e4).round() / 1e4
    } else {
        f64::NAN
    }
}

/// Everything the locate step found.
#[derive(Debug, Clone)]
pub struct Located {
    pub time: Vec<Group>,
    pub regimes: Vec<Group>,
    pub cells: Vec<Group>,
    /// Concentrations worth reporting, most concentrated first within each kind.
    pub mismatch: Vec<Group>,
    /// Candidate friction-patch boxes, best first.
    pub patch_seeds: Vec<[f64; 4]>,
}

struct Accum {
    n: usize,
    score: f64,
    sq: [f64; 6],
    /// Samples where each channel was measured.
    nc: [usize; 6],
}

impl Accum {
    fn new() -> Self {
        Self {
            n: 0,
            score: 0.0,
            sq: [0.0; 6],
            nc: [0; 6],
        }
    }
    fn add(&mut self, s: f64, r: &[f64; 6]) {
        self.n += 1;
        self.score += s;
        for (c, v) in r.iter().enumerate() {
            if v.is_finite() {
                self.sq[c] += v * v;
                self.nc[c] += 1;
            }
        }
    }
    fn group(
        &self,
        kind: &'static str,
        label: &str,
        range: Vec<f64>,
        mean: f64,
        total: f64,
    ) -> Group {
        let n = self.n.max(1) as f64;
        Group {
            kind,
            label: label.to_string(),
            range,
            samples: self.n,
            score: self.score / n,
            ratio: self.score / n / mean.max(1e-12),
            share: self.score / total.max(1e-12),
            rmse: std::array::from_fn(|c| {
                if self.nc[c] == 0 {
                    f64::NAN
                } else {
                    (self.sq[c] / self.nc[c] as f64).sqrt()
                }
            }),
        }
    }
}

/// Regime bins: (quantity, bin edges).
const REGIMES: [(&str, &[f64]); 4] = [
    (
        "speed_mps",
        &[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, f64::INFINITY],
    ),
    (
        "lateral_accel_mps2",
        &[0.0, 1.0, 2.0, 3.0, 4.0, 6.0, f64::INFINITY],
    ),
    (
        "steering_rate_radps",
        &[0.0, 0.25, 0.5, 1.0, 2.0, f64::INFINITY],
    ),
    ("braking", &[0.0, 0.5, 1.5]),
];

/// Group the nominal residuals.
pub fn locate(rec: &Recording, replay: &Replay, res: &Residuals) -> Located {
    let sig = replay.sigma;
    // mean over the channels measured at the sample
    let score: Vec<f64> = res
        .values
        .iter()
        .map(|r| {
            let measured = (0..6).filter(|&c| r[c].is_finite());
            let n = measured.clone().count().max(1) as f64;
            measured.map(|c| (r[c] / sig[c]).powi(2)).sum::<f64>() / n
        })
        .collect();
    let total: f64 = score.iter().sum();
    let mean = total / score.len().max(1) as f64;

    // steering rate from the commands on the grid, over 0.1 s
    let cmds = replay.commands();
    let steer_rate = |t: f64| {
        let k = ((t / DT) as usize).min(cmds.len() - 1);
        let k0 = k.saturating_sub(5);
        let k1 = (k + 5).min(cmds.len() - 1);
        if k1 > k0 {
            (cmds[k1].0 - cmds[k0].0).abs() / ((k1 - k0) as f64 * DT)
        } else {
            0.0
        }
    };

    // time segments
    let seg = (rec.duration() / 20.0).max(5.0);
    let n_seg = (rec.duration() / seg).ceil().max(1.0) as usize;
    let mut time_acc: Vec<Accum> = (0..n_seg).map(|_| Accum::new()).collect();
    let mut regime_acc: Vec<Vec<Accum>> = REGIMES
        .iter()
        .map(|(_, e)| (0..e.len() - 1).map(|_| Accum::new()).collect())
        .collect();
    let mut cells: std::collections::BTreeMap<(i64, i64), Accum> = Default::default();

    for (i, r) in res.values.iter().enumerate() {
        let s = &rec.states[res.state[i]];
        // velocities not measured: the simulated ones
        let sim = &res.simulated[i];
        let pick = |m: f64, c: usize| if m.is_finite() { m } else { sim[c] };
        let (vx, vy, yaw_rate) = (pick(s.vx, 3), pick(s.vy, 4), pick(s.yaw_rate, 5));
        let sc = score[i];
        let ti = ((s.t / seg) as usize).min(n_seg - 1);
        time_acc[ti].add(sc, r);
        let speed = libm::hypot(vx, vy);
        let t_cmd = s.t;
        let k = ((t_cmd / DT) as usize).min(cmds.len() - 1);
        let braking = if cmds[k].1 < vx - 0.3 { 1.0 } else { 0.0 };
        let vals = [speed, (speed * yaw_rate).abs(), steer_rate(t_cmd), braking];
        for (q, (_, edges)) in REGIMES.iter().enumerate() {
            if let Some(b) = edges
                .windows(2)
                .position(|e| vals[q] >= e[0] && vals[q] < e[1])
            {
                regime_acc[q][b].add(sc, r);
            }
        }
        let key = ((s.x / CELL_M).floor() as i64, (s.y / CELL_M).floor() as i64);
        cells.entry(key).or_insert_with(Accum::new).add(sc, r);
    }

    let time: Vec<Group> = time_acc
        .iter()
        .enumerate()
        .map(|(i, a)| {
            let t1 = ((i + 1) as f64 * seg).min(rec.duration());
            a.group("time", "", vec![i as f64 * seg, t1], mean, total)
        })
        .collect();
    let mut regimes = Vec::new();
    for (q, (name, edges)) in REGIMES.iter().enumerate() {
        for (b, a) in regime_acc[q].iter().enumerate() {
            if a.n > 0 {
                regimes.push(a.group("regime", name, vec![edges[b], edges[b + 1]], mean, total));
            }
        }
    }
    let cell_groups: Vec<Group> = cells
        .iter()
        .map(|((cx, cy), a)| {
            let (x0, y0) = (*cx as f64 * CELL_M, *cy as f64 * CELL_M);
            a.group(
                "region",
                "",
                vec![x0, y0, x0 + CELL_M, y0 + CELL_M],
                mean,
                total,
            )
        })
        .collect();

    let pick = |v: &[Group], limit: usize| -> Vec<Group> {
        let mut g: Vec<Group> = v
            .iter()
            .filter(|g| g.samples >= MIN_GROUP && g.ratio >= CONCENTRATED)
            .cloned()
            .collect();
        g.sort_by(|a, b| b.ratio.total_cmp(&a.ratio));
        g.truncate(limit);
        g
    };
    let mut mismatch = pick(&time, 5);
    mismatch.extend(pick(&regimes, 8));
    mismatch.extend(pick(&cell_groups, 8));

    // friction-patch seeds: the worst cells alone and with their neighbours
    let mut ranked: Vec<&Group> = cell_groups.iter().filter(|g| g.samples >= 10).collect();
    ranked.sort_by(|a, b| b.ratio.total_cmp(&a.ratio));
    let mut patch_seeds = Vec::new();
    for g in ranked.iter().take(3) {
        let r = &g.range;
        patch_seeds.push([r[0] - CELL_M, r[1] - CELL_M, r[2] + CELL_M, r[3] + CELL_M]);
        patch_seeds.push([r[0], r[1], r[2], r[3]]);
    }
    Located {
        time,
        regimes,
        cells: cell_groups,
        mismatch,
        patch_seeds,
    }
}
