//! The start pose of a run, fitted. Where a run starts, the replay has only the samples
//! after the start to place the car (none before it belong to the run), and a pose
//! smoothed from those is extrapolated, noisy and, at a start from rest or on an arc,
//! biased: an error every window of the run then carries. Because the dynamics do not
//! depend on where the car is or which way it points, moving the start pose moves the
//! whole simulated window rigidly; so the window's simulated poses are moved by the
//! translation and rotation that best fit its first instants, weighted as the start
//! state was ([`super::smooth::start_weight`]): the start pose is fitted per run, the
//! rest of the start state and every model parameter are not.

use crate::recording::wrap_pi;

use super::smooth::start_weight;

/// One replayed sample held back: index, window, residual, simulated channels, time
/// after the run's start [s].
type Held = (usize, usize, [f64; 6], [f64; 6], f64);

/// The first window of a run, held until its start pose is fitted.
#[derive(Debug, Default)]
pub(super) struct StartWindow {
    /// Simulated position at the start, the centre of the rotation.
    origin: (f64, f64),
    /// Span of the fit [s].
    span: f64,
    held: Vec<Held>,
    open: bool,
}

impl StartWindow {
    /// Begin a run's first window at the simulated position `origin`.
    pub fn begin(&mut self, origin: (f64, f64), span: f64) {
        self.origin = origin;
        self.span = span;
        self.held.clear();
        self.open = true;
    }

    pub fn is_open(&self) -> bool {
        self.open
    }

    pub fn hold(&mut self, sample: Held) {
        self.held.push(sample);
    }

    /// Fit the start pose, move every held sample's simulated pose with it, and hand
    /// them on in order.
    pub fn flush(
        &mut self,
        sigma: &[f64; 6],
        visit: &mut impl FnMut(usize, usize, [f64; 6], [f64; 6]),
    ) {
        if !self.open {
            return;
        }
        self.open = false;
        let [dx, dy, eps] = self.fit(sigma);
        let (x0, y0) = self.origin;
        let (sn, cs) = (libm::sin(eps), libm::cos(eps));
        for (si, w, mut r, mut sim, _) in self.held.drain(..) {
            if sim.iter().all(|v| v.is_finite()) && r.iter().all(|v| v.is_nan() || v.abs() < 1e3) {
                let (ex, ey) = (sim[0] - x0, sim[1] - y0);
                let x = x0 + dx + cs * ex - sn * ey;
                let y = y0 + dy + sn * ex + cs * ey;
                r[0] -= x - sim[0];
                r[1] -= y - sim[1];
                r[2] = wrap_pi(r[2] - eps);
                sim[0] = x;
                sim[1] = y;
                sim[2] += eps;
            }
            visit(si, w, r, sim);
        }
    }

    /// The translation `(dx, dy)` and rotation `eps` about the origin (linearised) that
    /// minimise the weighted, noise-normalised pose residuals of the samples inside the
    /// span. A small ridge keeps it defined (zero) where the samples say nothing.
    fn fit(&self, sigma: &[f64; 6]) -> [f64; 3] {
        let mut a = [[0.0; 3]; 3];
        let mut b = [0.0; 3];
        let (x0, y0) = self.origin;
        for (_, _, r, sim, u) in &self.held {
            let w = start_weight(*u, self.span);
            if w <= 0.0 || !sim.iter().all(|v| v.is_finite()) {
                continue;
            }
            let rows: [([f64; 3], usize); 3] = [
                ([1.0, 0.0, -(sim[1] - y0)], 0),
                ([0.0, 1.0, sim[0] - x0], 1),
                ([0.0, 0.0, 1.0], 2),
            ];
            for (j, c) in rows {
                if !r[c].is_finite() || r[c].abs() >= 1e3 {
                    continue;
                }
                let wc = w / (sigma[c] * sigma[c]);
                for p in 0..3 {
                    b[p] += wc * j[p] * r[c];
                    for q in 0..3 {
                        a[p][q] += wc * j[p] * j[q];
                    }
                }
            }
        }
        let trace = a[0][0] + a[1][1] + a[2][2];
        for (p, row) in a.iter_mut().enumerate() {
            row[p] += 1e-9 * trace + 1e-12;
        }
        solve3(a, b)
    }
}

/// `a x = b` for a symmetric positive definite 3x3 `a` (Cramer's rule).
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> [f64; 3] {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if d == 0.0 || !d.is_finite() {
        return [0.0; 3];
    }
    std::array::from_fn(|k| {
        let mut m = a;
        for (row, bi) in m.iter_mut().zip(b) {
            row[k] = bi;
        }
        det(m) / d
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A window whose simulated poses are the recorded ones moved rigidly: the fit undoes
    /// the move, and the residuals vanish.
    #[test]
    fn a_rigidly_moved_start_is_fitted_back() {
        let sigma = [0.01, 0.01, 0.005, 0.05, 0.05, 0.05];
        let (dx, dy, eps) = (0.03, -0.02, 0.01);
        let mut w = StartWindow::default();
        w.begin((1.0, 2.0), 0.2);
        for i in 0..30 {
            let u = i as f64 * 0.02 - 0.05;
            // recorded: along x at 2 m/s from (1, 2), heading 0
            let m = [1.0 + 2.0 * u, 2.0, 0.0];
            // simulated: that path rotated by -eps about the origin, shifted by -d
            let (ex, ey) = (m[0] - 1.0, m[1] - 2.0);
            let (sn, cs) = (libm::sin(-eps), libm::cos(-eps));
            let sim = [
                1.0 - dx + cs * ex - sn * ey,
                2.0 - dy + sn * ex + cs * ey,
                -eps,
                2.0,
                0.0,
                0.0,
            ];
            let r = [
                m[0] - sim[0],
                m[1] - sim[1],
                m[2] - sim[2],
                0.0,
                f64::NAN,
                f64::NAN,
            ];
            w.hold((i, 0, r, sim, u));
        }
        let mut out = Vec::new();
        w.flush(&sigma, &mut |si, _, r, _| out.push((si, r)));
        assert_eq!(out.len(), 30);
        assert!(out.windows(2).all(|p| p[0].0 < p[1].0));
        for (_, r) in out {
            // the rotation is linearised about the origin: small remainders far out
            assert!(
                r[0].abs() < 2e-3 && r[1].abs() < 2e-3 && r[2].abs() < 1e-6,
                "{r:?}"
            );
            assert!(r[4].is_nan());
        }
    }
}
