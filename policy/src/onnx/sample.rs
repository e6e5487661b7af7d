//! Seeded sample inputs for a model: plausible values for every observation key, to
//! compare runtimes on (`paddock onnx-check`, `paddock.onnx.check` in Python).

use super::{Feed, OnnxPolicy};

/// splitmix64: a small seeded generator, the same sequence everywhere.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    fn uniform(&mut self, lo: f64, hi: f64) -> f32 {
        let u = (self.next() >> 11) as f64 / (1u64 << 53) as f64;
        (lo + (hi - lo) * u) as f32
    }
}

/// The range sampled for each scalar key.
fn scalar_range(key: &str) -> (f64, f64) {
    match key {
        "poses_x" | "poses_y" => (-20.0, 20.0),
        "poses_theta" => (-std::f64::consts::PI, std::f64::consts::PI),
        "linear_vels_x" => (0.0, 8.0),
        "linear_vels_y" => (-1.0, 1.0),
        "ang_vels_z" => (-2.0, 2.0),
        "steering_angles" => (-0.4, 0.4),
        "slip_angles" => (-0.2, 0.2),
        "progress" => (0.0, 100.0),
        "lap_times" => (0.0, 60.0),
        _ => (0.0, 0.0),
    }
}

impl OnnxPolicy {
    /// Sample input values for the model, one flat vector per input in
    /// [`Self::inputs`] order (what [`Self::run`] takes): scans uniform in [0.1, 10) m,
    /// scalars in plausible ranges, lap counts and collisions whole numbers, the previous
    /// action in (steering [-0.4, 0.4), speed [0, 8)). The same `seed` gives the same
    /// values everywhere.
    pub fn sample_inputs(&self, seed: u64) -> Vec<Vec<f32>> {
        let mut rng = SplitMix(seed);
        self.inputs
            .iter()
            .map(|slot| match slot.feed {
                Feed::Scans { beams } => (0..beams).map(|_| rng.uniform(0.1, 10.0)).collect(),
                Feed::Scalar("lap_counts") => vec![(rng.next() % 3) as f32],
                Feed::Scalar("collisions") => vec![(rng.next() % 2) as f32],
                Feed::Scalar(key) => {
                    let (lo, hi) = scalar_range(key);
                    vec![rng.uniform(lo, hi)]
                }
                Feed::PrevAction => vec![rng.uniform(-0.4, 0.4), rng.uniform(0.0, 8.0)],
            })
            .collect()
    }
}
