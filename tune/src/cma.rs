//! One CMA-ES run (no restarts, no bounds): the equations of Hansen, "The CMA Evolution
//! Strategy: A Tutorial" (arXiv:1604.00772), Table 1 defaults with positive weights
//! only, and the termination criteria of its appendix B.3.
//!
//! Everything here works in the optimiser's internal (unbounded, normalised) space; the
//! [`Optimizer`](crate::Optimizer) maps candidates into the user's box.

use serde::{Deserialize, Serialize};

use crate::eigen::symmetric_eigen;
use crate::fit::Fit;
use crate::rng::Rng;
use crate::{RunStop, Tolerances};

/// Longest fitness history the stagnation test looks at (appendix B.3).
const STAGNATION_MAX_WINDOW: usize = 20_000;

/// Strategy parameters of one run; fixed for its lifetime.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Params {
    n: usize,
    lambda: usize,
    mu: usize,
    /// Recombination weights w_1..w_mu, positive, summing to 1.
    weights: Vec<f64>,
    mu_eff: f64,
    c_sigma: f64,
    d_sigma: f64,
    c_c: f64,
    c_1: f64,
    c_mu: f64,
    /// E||N(0, I)||.
    chi_n: f64,
    /// Generations between eigendecompositions (lazy update, tutorial B.2).
    eigen_interval: f64,
    max_iter: u64,
}

impl Params {
    fn new(n: usize, lambda: usize, max_iter: Option<u64>) -> Self {
        let nf = n as f64;
        let mu = lambda / 2;
        let raw: Vec<f64> = (1..=mu)
            .map(|i| libm::log((lambda as f64 + 1.0) / 2.0) - libm::log(i as f64))
            .collect();
        let sum: f64 = raw.iter().sum();
        let weights: Vec<f64> = raw.iter().map(|w| w / sum).collect();
        let mu_eff = 1.0 / weights.iter().map(|w| w * w).sum::<f64>();

        let c_sigma = (mu_eff + 2.0) / (nf + mu_eff + 5.0);
        let d_sigma =
            1.0 + 2.0 * f64::max(0.0, libm::sqrt((mu_eff - 1.0) / (nf + 1.0)) - 1.0) + c_sigma;
        let c_c = (4.0 + mu_eff / nf) / (nf + 4.0 + 2.0 * mu_eff / nf);
        let alpha_cov = 2.0;
        let c_1 = alpha_cov / ((nf + 1.3) * (nf + 1.3) + mu_eff);
        let c_mu = f64::min(
            1.0 - c_1,
            alpha_cov * (mu_eff - 2.0 + 1.0 / mu_eff)
                / ((nf + 2.0) * (nf + 2.0) + alpha_cov * mu_eff / 2.0),
        );
        let chi_n = libm::sqrt(nf) * (1.0 - 1.0 / (4.0 * nf) + 1.0 / (21.0 * nf * nf));
        let eigen_interval = lambda as f64 / ((c_1 + c_mu) * nf * 10.0);
        // pycma's default maxiter: 100 + 150 (n + 3)^2 / sqrt(popsize).
        let max_iter = max_iter.unwrap_or_else(|| {
            (100.0 + 150.0 * (nf + 3.0) * (nf + 3.0) / libm::sqrt(lambda as f64)) as u64
        });
        Params {
            n,
            lambda,
            mu,
            weights,
            mu_eff,
            c_sigma,
            d_sigma,
            c_c,
            c_1,
            c_mu,
            chi_n,
            eigen_interval,
            max_iter,
        }
    }
}

/// One generation's samples: z ~ N(0, I), y = B D z, x = m + sigma y.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Samples {
    pub(crate) z: Vec<Vec<f64>>,
    pub(crate) y: Vec<Vec<f64>>,
    pub(crate) x: Vec<Vec<f64>>,
}

/// The full state of one run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Run {
    p: Params,
    tol: Tolerances,
    mean: Vec<f64>,
    sigma: f64,
    sigma0: f64,
    /// Covariance matrix, row-major n x n, kept exactly symmetric.
    c: Vec<f64>,
    /// Eigenvectors of `c` (columns of a row-major matrix).
    b: Vec<f64>,
    /// Square roots of the eigenvalues of `c`.
    d: Vec<f64>,
    p_c: Vec<f64>,
    p_sigma: Vec<f64>,
    generation: u64,
    eigen_generation: u64,
    /// Best and median fitness per generation (for TolFun and stagnation).
    best_history: Vec<Fit>,
    median_history: Vec<Fit>,
}

impl Run {
    /// A run with mean `mean`, step size `sigma` and C = diag(scales^2).
    pub(crate) fn new(
        mean: Vec<f64>,
        sigma: f64,
        scales: &[f64],
        lambda: usize,
        tol: Tolerances,
    ) -> Self {
        let n = mean.len();
        let p = Params::new(n, lambda, tol.max_iter);
        let mut c = vec![0.0; n * n];
        let mut b = vec![0.0; n * n];
        for i in 0..n {
            c[i * n + i] = scales[i] * scales[i];
            b[i * n + i] = 1.0;
        }
        Run {
            p,
            tol,
            mean,
            sigma,
            sigma0: sigma,
            c,
            b,
            d: scales.to_vec(),
            p_c: vec![0.0; n],
            p_sigma: vec![0.0; n],
            generation: 0,
            eigen_generation: 0,
            best_history: Vec::new(),
            median_history: Vec::new(),
        }
    }

    pub(crate) fn lambda(&self) -> usize {
        self.p.lambda
    }
    pub(crate) fn sigma(&self) -> f64 {
        self.sigma
    }
    pub(crate) fn mean(&self) -> &[f64] {
        &self.mean
    }
    pub(crate) fn generation(&self) -> u64 {
        self.generation
    }
    /// Axis ratio squared: largest over smallest eigenvalue of C.
    pub(crate) fn condition(&self) -> f64 {
        let max = self.d.iter().cloned().fold(0.0, f64::max);
        let min = self.d.iter().cloned().fold(f64::INFINITY, f64::min);
        (max / min) * (max / min)
    }

    pub(crate) fn sample(&self, rng: &mut Rng) -> Samples {
        let n = self.p.n;
        let mut s = Samples {
            z: Vec::with_capacity(self.p.lambda),
            y: Vec::with_capacity(self.p.lambda),
            x: Vec::with_capacity(self.p.lambda),
        };
        for _ in 0..self.p.lambda {
            let z: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
            let y: Vec<f64> = (0..n)
                .map(|i| (0..n).map(|k| self.b[i * n + k] * (self.d[k] * z[k])).sum())
                .collect();
            let x: Vec<f64> = (0..n).map(|i| self.mean[i] + self.sigma * y[i]).collect();
            s.z.push(z);
            s.y.push(y);
            s.x.push(x);
        }
        s
    }

    /// Update from one evaluated generation. `order` sorts the samples best first.
    /// Returns why the run should stop, if it should.
    pub(crate) fn update(
        &mut self,
        s: &Samples,
        fitness: &[f64],
        order: &[usize],
    ) -> Option<RunStop> {
        let p = &self.p;
        let n = p.n;

        // Weighted recombination of the mu best steps.
        let mut y_w = vec![0.0; n];
        let mut z_w = vec![0.0; n];
        for (w, &k) in p.weights.iter().zip(order) {
            for i in 0..n {
                y_w[i] += w * s.y[k][i];
                z_w[i] += w * s.z[k][i];
            }
        }
        for (m, y) in self.mean.iter_mut().zip(&y_w) {
            *m += self.sigma * y;
        }

        // Cumulation for sigma: p_sigma += sqrt(cs (2 - cs) mu_eff) C^{-1/2} y_w, where
        // C^{-1/2} y_w = B z_w because B and D have not changed since sampling.
        let cs = p.c_sigma;
        let ks = libm::sqrt(cs * (2.0 - cs) * p.mu_eff);
        for i in 0..n {
            let bz: f64 = (0..n).map(|k| self.b[i * n + k] * z_w[k]).sum();
            self.p_sigma[i] = (1.0 - cs) * self.p_sigma[i] + ks * bz;
        }
        let ps_norm = libm::sqrt(self.p_sigma.iter().map(|v| v * v).sum());

        // h_sigma stalls the update of p_c when ||p_sigma|| is large, e.g. right after
        // a fast increase of sigma.
        let g1 = (self.generation + 1) as f64;
        let h_sigma = ps_norm / libm::sqrt(1.0 - libm::pow(1.0 - cs, 2.0 * g1))
            < (1.4 + 2.0 / (n as f64 + 1.0)) * p.chi_n;
        let cc = p.c_c;
        let kc = if h_sigma {
            libm::sqrt(cc * (2.0 - cc) * p.mu_eff)
        } else {
            0.0
        };
        for (pc, y) in self.p_c.iter_mut().zip(&y_w) {
            *pc = (1.0 - cc) * *pc + kc * y;
        }

        // Rank-one and rank-mu update; delta(h_sigma) compensates the stalled p_c.
        let delta_h = if h_sigma { 0.0 } else { cc * (2.0 - cc) };
        let old_weight = 1.0 + p.c_1 * delta_h - p.c_1 - p.c_mu;
        for i in 0..n {
            for j in i..n {
                let mut rank_mu = 0.0;
                for (w, &k) in p.weights.iter().zip(order) {
                    rank_mu += w * (s.y[k][i] * s.y[k][j]);
                }
                let v = old_weight * self.c[i * n + j]
                    + p.c_1 * (self.p_c[i] * self.p_c[j])
                    + p.c_mu * rank_mu;
                self.c[i * n + j] = v;
                self.c[j * n + i] = v;
            }
        }

        // Cumulative step-size adaptation.
        self.sigma *= libm::exp((cs / p.d_sigma) * (ps_norm / p.chi_n - 1.0));

        // Flat fitness: the distribution cannot tell candidates apart, so widen it.
        let best = fitness[order[0]];
        let k70 = (0.7 * p.lambda as f64).ceil() as usize;
        if best == fitness[order[k70.clamp(1, p.lambda) - 1]] {
            self.sigma *= libm::exp(0.2 + cs / p.d_sigma);
        }

        self.generation += 1;
        self.best_history.push(Fit(best));
        self.median_history.push(Fit(fitness[order[p.lambda / 2]]));
        if self.best_history.len() > STAGNATION_MAX_WINDOW {
            self.best_history.remove(0);
            self.median_history.remove(0);
        }

        if (self.generation - self.eigen_generation) as f64 > p.eigen_interval && !self.decompose()
        {
            return Some(RunStop::ConditionCov);
        }
        self.termination(fitness)
    }

    /// Eigendecomposition of C; false when C is no longer positive definite.
    fn decompose(&mut self) -> bool {
        let n = self.p.n;
        self.eigen_generation = self.generation;
        let (values, vectors) = symmetric_eigen(&self.c, n);
        if !values.iter().all(|v| v.is_finite() && *v > 0.0) {
            return false;
        }
        self.d = values.iter().map(|v| libm::sqrt(*v)).collect();
        self.b = vectors;
        true
    }

    /// Termination criteria of the tutorial's appendix B.3 (and pycma's TolUpSigma).
    fn termination(&self, fitness: &[f64]) -> Option<RunStop> {
        let p = &self.p;
        let n = p.n;
        let tol = &self.tol;

        if self.generation >= p.max_iter {
            return Some(RunStop::MaxIter);
        }
        if self.condition() > tol.condition {
            return Some(RunStop::ConditionCov);
        }
        let d_max = self.d.iter().cloned().fold(0.0, f64::max);
        if self.sigma * d_max > tol.up_sigma * self.sigma0 {
            return Some(RunStop::TolUpSigma);
        }

        // TolFun: recent best values and this generation's values all within tol.fun.
        let window = 10 + (30.0 * n as f64 / p.lambda as f64).ceil() as usize;
        if self.best_history.len() >= window {
            let recent = self.best_history[self.best_history.len() - window..]
                .iter()
                .map(|f| f.0)
                .chain(fitness.iter().cloned());
            let (lo, hi) = recent.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
            if hi - lo < tol.fun {
                return Some(RunStop::TolFun);
            }
        }

        // TolX: every coordinate's standard deviation and sigma * p_c tiny.
        let tol_x = tol.x * self.sigma0;
        if (0..n).all(|i| {
            self.sigma * libm::sqrt(self.c[i * n + i]) < tol_x
                && (self.sigma * self.p_c[i]).abs() < tol_x
        }) {
            return Some(RunStop::TolX);
        }

        // NoEffectAxis: a 0.1-sigma step along principal axis (g mod n) changes nothing.
        let axis = (self.generation % n as u64) as usize;
        let step = 0.1 * self.sigma * self.d[axis];
        if (0..n).all(|i| self.mean[i] + step * self.b[i * n + axis] == self.mean[i]) {
            return Some(RunStop::NoEffectAxis);
        }
        // NoEffectCoord: a 0.2-sigma step in some coordinate changes nothing.
        if (0..n).any(|i| {
            self.mean[i] + 0.2 * self.sigma * libm::sqrt(self.c[i * n + i]) == self.mean[i]
        }) {
            return Some(RunStop::NoEffectCoord);
        }

        if tol.stagnation && self.stagnated() {
            return Some(RunStop::Stagnation);
        }
        None
    }

    /// Stagnation (appendix B.3): over the last 20% of generations, but at least
    /// 120 + 30 n / lambda and at most 20,000, the median of the most recent 30% of both
    /// the best and the median fitness is not better than that of the first 30%.
    fn stagnated(&self) -> bool {
        let p = &self.p;
        let min_window = 120 + (30.0 * p.n as f64 / p.lambda as f64).ceil() as usize;
        let window = usize::max(min_window, (0.2 * self.generation as f64) as usize)
            .min(STAGNATION_MAX_WINDOW);
        let len = self.best_history.len();
        if len < window {
            return false;
        }
        let part = ((0.3 * window as f64) as usize).max(1);
        let not_better = |h: &[Fit]| {
            let h = &h[len - window..];
            median(&h[..part]) <= median(&h[window - part..])
        };
        not_better(&self.best_history) && not_better(&self.median_history)
    }
}

fn median(v: &[Fit]) -> f64 {
    let mut s: Vec<f64> = v.iter().map(|f| f.0).collect();
    s.sort_by(f64::total_cmp);
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        0.5 * (s[m - 1] + s[m])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_parameters_match_the_tutorial_for_n_10() {
        let p = Params::new(10, 10, None);
        assert_eq!(p.mu, 5);
        let sum: f64 = p.weights.iter().sum();
        assert!((sum - 1.0).abs() < 1e-15);
        assert!(p.weights.windows(2).all(|w| w[0] > w[1]));
        // Reference values computed from the Table 1 formulas by hand.
        assert!((p.mu_eff - 3.167_299_28).abs() < 1e-8, "{}", p.mu_eff);
        assert!((p.c_1 - 2.0 / (11.3 * 11.3 + p.mu_eff)).abs() < 1e-15);
        assert!(p.c_mu > 0.0 && p.c_1 + p.c_mu < 1.0);
        assert!((p.chi_n - 3.0841).abs() < 1e-3);
    }
}
