//! The user-facing optimiser: options, bounds, ask/tell, IPOP restarts, status.

use std::fmt;

use serde::{Deserialize, Serialize};

use crate::TuneError;
use crate::bounds::Dim;
use crate::cma::{Run, Samples};
use crate::fit::Fit;
use crate::rng::Rng;

/// Initial step size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Sigma0 {
    /// Standard deviation in the user's units, the same for every coordinate. For a
    /// bounded coordinate it is divided by that coordinate's box width internally.
    Absolute(f64),
    /// Standard deviation as a fraction of each coordinate's box width (all coordinates
    /// must be bounded). 0.3 is a good default for a box that brackets the optimum.
    FractionOfWidth(f64),
}

/// Where a restart puts the new mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum RestartFrom {
    /// The initial mean `x0` every time (pycma's default with a fixed x0).
    InitialMean,
    /// A uniform random point in the box (drawn from the optimiser's seeded generator);
    /// unbounded coordinates restart from `x0`.
    RandomInBounds,
}

/// Termination tolerances of one run (Hansen's tutorial, appendix B.3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Tolerances {
    /// TolFun: stop when the recent best values and the current generation span less.
    pub fun: f64,
    /// TolX, relative to the initial sigma: stop when every coordinate's standard
    /// deviation (and sigma * p_c) is below `x * sigma0`.
    pub x: f64,
    /// Stop when the condition number of C exceeds this.
    pub condition: f64,
    /// Stop when sigma * max(D) grows beyond this factor times the initial sigma.
    pub up_sigma: f64,
    /// Enable the stagnation criterion.
    pub stagnation: bool,
    /// Generations per run; `None` means pycma's default 100 + 150 (n+3)^2 / sqrt(lambda).
    pub max_iter: Option<u64>,
}

impl Default for Tolerances {
    fn default() -> Self {
        Tolerances {
            fun: 1e-12,
            x: 1e-12,
            condition: 1e14,
            up_sigma: 1e20,
            stagnation: true,
            max_iter: None,
        }
    }
}

/// Why one CMA-ES run ended (and a restart began or the optimiser stopped).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum RunStop {
    TolFun,
    TolX,
    NoEffectAxis,
    NoEffectCoord,
    ConditionCov,
    Stagnation,
    MaxIter,
    TolUpSigma,
}

/// Why the optimiser as a whole stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum StopReason {
    /// The best fitness reached the target.
    TargetReached,
    /// The evaluation budget is spent.
    MaxEvaluations,
    /// The last allowed run ended for this reason.
    RestartsExhausted(RunStop),
}

impl fmt::Display for RunStop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self {
            RunStop::TolFun => "tolfun",
            RunStop::TolX => "tolx",
            RunStop::NoEffectAxis => "noeffectaxis",
            RunStop::NoEffectCoord => "noeffectcoord",
            RunStop::ConditionCov => "conditioncov",
            RunStop::Stagnation => "stagnation",
            RunStop::MaxIter => "maxiter",
            RunStop::TolUpSigma => "tolupsigma",
        };
        f.write_str(s)
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StopReason::TargetReached => f.write_str("target fitness reached"),
            StopReason::MaxEvaluations => f.write_str("evaluation budget spent"),
            StopReason::RestartsExhausted(r) => {
                write!(f, "restarts exhausted, last run stopped by {r}")
            }
        }
    }
}

/// Settings of an [`Optimizer`]. Build with [`Options::new`] and the `with_*` methods,
/// or set the public fields.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Options {
    /// Initial mean; its length is the problem dimension.
    pub x0: Vec<f64>,
    pub sigma0: Sigma0,
    /// Per-coordinate `(lo, hi)`, `lo < hi`, both finite, or `(-inf, inf)` for an
    /// unbounded coordinate. `None`: unbounded everywhere. JSON has no infinity, so
    /// serialise options of unbounded coordinates with `None`, or keep them in code.
    pub bounds: Option<Vec<(f64, f64)>>,
    /// Population size of the first run; `None`: 4 + floor(3 ln n).
    pub popsize: Option<usize>,
    pub seed: u64,
    /// Stop once this many evaluations have been told (checked after each generation,
    /// so the last generation may overshoot by up to one population).
    pub max_evals: Option<u64>,
    /// IPOP restarts after the first run, each doubling the population size.
    pub max_restarts: usize,
    /// Stop when a fitness at or below this is told.
    pub target: Option<f64>,
    pub tolerances: Tolerances,
    pub restart_from: RestartFrom,
}

impl Options {
    /// Defaults: no bounds, default popsize, seed 0, no evaluation limit, 9 restarts
    /// (IPOP as benchmarked by Auger & Hansen 2005), no target, default tolerances,
    /// restarts from a random point in the box.
    pub fn new(x0: Vec<f64>, sigma0: Sigma0) -> Self {
        Options {
            x0,
            sigma0,
            bounds: None,
            popsize: None,
            seed: 0,
            max_evals: None,
            max_restarts: 9,
            target: None,
            tolerances: Tolerances::default(),
            restart_from: RestartFrom::RandomInBounds,
        }
    }
    pub fn with_bounds(mut self, bounds: Vec<(f64, f64)>) -> Self {
        self.bounds = Some(bounds);
        self
    }
    pub fn with_popsize(mut self, popsize: usize) -> Self {
        self.popsize = Some(popsize);
        self
    }
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }
    pub fn with_max_evals(mut self, max_evals: u64) -> Self {
        self.max_evals = Some(max_evals);
        self
    }
    pub fn with_max_restarts(mut self, max_restarts: usize) -> Self {
        self.max_restarts = max_restarts;
        self
    }
    pub fn with_target(mut self, target: f64) -> Self {
        self.target = Some(target);
        self
    }
    pub fn with_tolerances(mut self, tolerances: Tolerances) -> Self {
        self.tolerances = tolerances;
        self
    }
    pub fn with_restart_from(mut self, restart_from: RestartFrom) -> Self {
        self.restart_from = restart_from;
        self
    }
}

/// A snapshot for progress display.
#[derive(Debug, Clone, PartialEq)]
pub struct Status {
    /// Generations told, over all runs.
    pub generation: u64,
    /// Generations told in the current run.
    pub run_generation: u64,
    pub evaluations: u64,
    /// Best fitness told so far (+inf before the first tell or if all failed).
    pub best_fitness: f64,
    pub best_x: Option<Vec<f64>>,
    /// Step size in the internal space: for bounded coordinates, a fraction of the box
    /// width (times the coordinate's scale in C).
    pub sigma: f64,
    /// Population size of the current run.
    pub popsize: usize,
    pub restarts: usize,
    /// Condition number of the current covariance matrix.
    pub condition: f64,
    /// A generation has been asked and awaits its tell.
    pub awaiting_tell: bool,
    pub stop: Option<StopReason>,
    /// Why the most recent finished run stopped.
    pub last_run_stop: Option<RunStop>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Pending {
    samples: Samples,
    /// The candidates handed out, in the user's space.
    candidates: Vec<Vec<f64>>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Best {
    x: Vec<f64>,
    fitness: Fit,
}

/// CMA-ES with box bounds and IPOP restarts, driven by [`ask`](Optimizer::ask) and
/// [`tell`](Optimizer::tell). The whole state serialises with serde; a deserialised
/// optimiser continues bit for bit as the original would have.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Optimizer {
    dims: Vec<Dim>,
    x0_internal: Vec<f64>,
    sigma0_internal: f64,
    /// Initial C = diag(scales^2).
    scales: Vec<f64>,
    base_popsize: usize,
    max_evals: Option<u64>,
    max_restarts: usize,
    target: Option<f64>,
    tolerances: Tolerances,
    restart_from: RestartFrom,

    rng: Rng,
    run: Run,
    restarts: usize,
    evaluations: u64,
    generations: u64,
    best: Option<Best>,
    pending: Option<Pending>,
    stop: Option<StopReason>,
    last_run_stop: Option<RunStop>,
}

fn invalid(field: &'static str, value: impl fmt::Debug, reason: &'static str) -> TuneError {
    TuneError::InvalidOption {
        field,
        value: format!("{value:?}"),
        reason,
    }
}

impl Optimizer {
    /// Validate `options` and set up the first run.
    pub fn new(options: Options) -> Result<Self, TuneError> {
        let n = options.x0.len();
        if n == 0 {
            return Err(invalid("x0", &options.x0, "needs at least one coordinate"));
        }
        if let Some(i) = options.x0.iter().position(|v| !v.is_finite()) {
            return Err(invalid(
                "x0",
                options.x0[i],
                "every coordinate must be finite",
            ));
        }
        let dims: Vec<Dim> = match &options.bounds {
            None => vec![Dim::Free; n],
            Some(b) if b.len() != n => {
                return Err(invalid(
                    "bounds",
                    b.len(),
                    "needs one (lo, hi) pair per coordinate of x0",
                ));
            }
            Some(b) => {
                let mut dims = Vec::with_capacity(n);
                for (i, &(lo, hi)) in b.iter().enumerate() {
                    let dim = if lo == f64::NEG_INFINITY && hi == f64::INFINITY {
                        Dim::Free
                    } else if lo.is_finite() && hi.is_finite() && lo < hi {
                        Dim::Box { lo, hi }
                    } else {
                        return Err(invalid(
                            "bounds",
                            (i, lo, hi),
                            "each pair must be finite with lo < hi, or (-inf, inf); one-sided bounds are not supported",
                        ));
                    };
                    let x = options.x0[i];
                    if x < lo || x > hi {
                        return Err(invalid("x0", (i, x), "lies outside its bounds"));
                    }
                    dims.push(dim);
                }
                dims
            }
        };
        let scales_user: Vec<f64> = match options.sigma0 {
            Sigma0::Absolute(s) if s.is_finite() && s > 0.0 => dims
                .iter()
                .map(|d| s * d.internal_per_user_unit())
                .collect(),
            Sigma0::FractionOfWidth(f) if f.is_finite() && f > 0.0 => {
                if dims.contains(&Dim::Free) {
                    return Err(invalid(
                        "sigma0",
                        options.sigma0,
                        "FractionOfWidth needs every coordinate bounded",
                    ));
                }
                vec![f; n]
            }
            s => return Err(invalid("sigma0", s, "must be finite and positive")),
        };
        let sigma0_internal = scales_user.iter().cloned().fold(0.0, f64::max);
        let scales: Vec<f64> = scales_user.iter().map(|s| s / sigma0_internal).collect();

        let base_popsize = match options.popsize {
            None => 4 + libm::floor(3.0 * libm::log(n as f64)) as usize,
            Some(p) if p >= 2 => p,
            Some(p) => return Err(invalid("popsize", p, "must be at least 2")),
        };
        if let Some(t) = options.target
            && !t.is_finite()
        {
            return Err(invalid(
                "target",
                t,
                "must be finite (use None for no target)",
            ));
        }
        if options.max_evals == Some(0) {
            return Err(invalid("max_evals", 0, "must be positive"));
        }
        let t = options.tolerances;
        for (field, v) in [
            ("tolerances.fun", t.fun),
            ("tolerances.x", t.x),
            ("tolerances.condition", t.condition),
            ("tolerances.up_sigma", t.up_sigma),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid(field, v, "must be finite and positive"));
            }
        }

        let x0_internal: Vec<f64> = dims
            .iter()
            .zip(&options.x0)
            .map(|(d, &x)| d.to_internal(x))
            .collect();
        let run = Run::new(
            x0_internal.clone(),
            sigma0_internal,
            &scales,
            base_popsize,
            t,
        );
        Ok(Optimizer {
            dims,
            x0_internal,
            sigma0_internal,
            scales,
            base_popsize,
            max_evals: options.max_evals,
            max_restarts: options.max_restarts,
            target: options.target,
            tolerances: t,
            restart_from: options.restart_from,
            rng: Rng::seed_from_u64(options.seed),
            run,
            restarts: 0,
            evaluations: 0,
            generations: 0,
            best: None,
            pending: None,
            stop: None,
            last_run_stop: None,
        })
    }

    /// Problem dimension.
    pub fn dimension(&self) -> usize {
        self.dims.len()
    }

    /// Population size of the current run (the number of candidates `ask` returns).
    pub fn popsize(&self) -> usize {
        self.run.lambda()
    }

    /// Sample one generation. Every candidate lies inside the bounds. Candidates may be
    /// evaluated in any order, anywhere; tell them back in the order returned here.
    pub fn ask(&mut self) -> Result<Vec<Vec<f64>>, TuneError> {
        if let Some(reason) = self.stop {
            return Err(TuneError::Finished(reason));
        }
        if self.pending.is_some() {
            return Err(TuneError::TellPending {
                generation: self.generations,
            });
        }
        let samples = self.run.sample(&mut self.rng);
        let candidates: Vec<Vec<f64>> = samples.x.iter().map(|x| self.to_user(x)).collect();
        self.pending = Some(Pending {
            samples,
            candidates: candidates.clone(),
        });
        Ok(candidates)
    }

    /// Report the fitness (to be minimised) of the candidates of the last `ask`, in the
    /// same order. `+inf` marks a failed evaluation; NaN and `-inf` are errors. On error
    /// nothing changes and the generation stays pending.
    pub fn tell(&mut self, candidates: &[Vec<f64>], fitness: &[f64]) -> Result<(), TuneError> {
        let pending = self.pending.as_ref().ok_or(TuneError::NoPendingAsk)?;
        let lambda = pending.candidates.len();
        if candidates.len() != lambda {
            return Err(TuneError::WrongCount {
                what: "candidates",
                expected: lambda,
                got: candidates.len(),
            });
        }
        if fitness.len() != lambda {
            return Err(TuneError::WrongCount {
                what: "fitness values",
                expected: lambda,
                got: fitness.len(),
            });
        }
        let n = self.dimension();
        for (index, (got, asked)) in candidates.iter().zip(&pending.candidates).enumerate() {
            if got.len() != n {
                return Err(TuneError::WrongDimension {
                    index,
                    expected: n,
                    got: got.len(),
                });
            }
            if let Some(coordinate) = (0..n).find(|&i| got[i] != asked[i]) {
                return Err(TuneError::CandidateMismatch {
                    index,
                    coordinate,
                    expected: asked[coordinate],
                    got: got[coordinate],
                });
            }
        }
        if let Some(index) = fitness
            .iter()
            .position(|f| f.is_nan() || *f == f64::NEG_INFINITY)
        {
            return Err(TuneError::InvalidFitness {
                index,
                value: fitness[index],
            });
        }

        let pending = self.pending.take().expect("checked above");
        self.evaluations += lambda as u64;
        self.generations += 1;
        for (x, &f) in pending.candidates.iter().zip(fitness) {
            if self.best.as_ref().is_none_or(|b| f < b.fitness.0) {
                self.best = Some(Best {
                    x: x.clone(),
                    fitness: Fit(f),
                });
            }
        }
        // Rank by fitness, ties by index, so the ranking is a pure function of input.
        let mut order: Vec<usize> = (0..lambda).collect();
        order.sort_by(|&a, &b| fitness[a].total_cmp(&fitness[b]).then(a.cmp(&b)));
        let run_stop = self.run.update(&pending.samples, fitness, &order);

        let best = self.best.as_ref().map_or(f64::INFINITY, |b| b.fitness.0);
        if self.target.is_some_and(|t| best <= t) {
            self.stop = Some(StopReason::TargetReached);
        } else if self.max_evals.is_some_and(|m| self.evaluations >= m) {
            self.stop = Some(StopReason::MaxEvaluations);
        } else if let Some(reason) = run_stop {
            self.last_run_stop = Some(reason);
            if self.restarts < self.max_restarts {
                self.restart();
            } else {
                self.stop = Some(StopReason::RestartsExhausted(reason));
            }
        }
        Ok(())
    }

    /// IPOP: a new run with twice the population size.
    fn restart(&mut self) {
        self.restarts += 1;
        let lambda = self.run.lambda() * 2;
        let mean: Vec<f64> = match self.restart_from {
            RestartFrom::InitialMean => self.x0_internal.clone(),
            RestartFrom::RandomInBounds => {
                let mut m = self.x0_internal.clone();
                for (mi, dim) in m.iter_mut().zip(&self.dims) {
                    if let Dim::Box { lo, hi } = *dim {
                        let x = lo + (hi - lo) * self.rng.uniform();
                        *mi = dim.to_internal(x);
                    }
                }
                m
            }
        };
        self.run = Run::new(
            mean,
            self.sigma0_internal,
            &self.scales,
            lambda,
            self.tolerances,
        );
    }

    fn to_user(&self, internal: &[f64]) -> Vec<f64> {
        self.dims
            .iter()
            .zip(internal)
            .map(|(d, &y)| d.to_user(y))
            .collect()
    }

    /// `Some(reason)` once the optimiser has stopped; `ask` then returns an error.
    pub fn is_done(&self) -> Option<StopReason> {
        self.stop
    }

    /// Best candidate and fitness told so far.
    pub fn best(&self) -> Option<(&[f64], f64)> {
        self.best.as_ref().map(|b| (b.x.as_slice(), b.fitness.0))
    }

    /// Current distribution mean, in the user's space (inside the bounds).
    pub fn mean(&self) -> Vec<f64> {
        self.to_user(self.run.mean())
    }

    /// Progress snapshot.
    pub fn status(&self) -> Status {
        Status {
            generation: self.generations,
            run_generation: self.run.generation(),
            evaluations: self.evaluations,
            best_fitness: self.best.as_ref().map_or(f64::INFINITY, |b| b.fitness.0),
            best_x: self.best.as_ref().map(|b| b.x.clone()),
            sigma: self.run.sigma(),
            popsize: self.run.lambda(),
            restarts: self.restarts,
            condition: self.run.condition(),
            awaiting_tell: self.pending.is_some(),
            stop: self.stop,
            last_run_stop: self.last_run_stop,
        }
    }
}
