//! # paddock-tune: CMA-ES with box bounds, IPOP restarts and ask/tell
//!
//! Paddock tunes controller and model parameters (pure-pursuit lookahead, speed
//! profiles, tyre coefficients ...) by black-box optimisation: a candidate is scored by
//! simulated rollouts, which are noisy-free but expensive, non-smooth and come from a
//! broker that farms them out to remote workers. This crate is the optimiser; it knows
//! nothing about the simulator, the broker or threads.
//!
//! ## Algorithm
//!
//! The covariance matrix adaptation evolution strategy as specified in N. Hansen, "The
//! CMA Evolution Strategy: A Tutorial" (arXiv:1604.00772), with its default strategy
//! parameters (Table 1):
//!
//! * population `lambda = 4 + floor(3 ln n)`, `mu = floor(lambda / 2)` parents,
//!   positive recombination weights `w_i ∝ ln((lambda + 1) / 2) - ln i`;
//! * rank-one update (evolution path `p_c`) and rank-mu update of the covariance
//!   matrix `C`, with the `h_sigma` stall of `p_c` while `||p_sigma||` is large;
//! * cumulative step-size adaptation (CSA) of `sigma` through the conjugate path
//!   `p_sigma`;
//! * the eigendecomposition `C = B D^2 B^T` is recomputed lazily, every
//!   `lambda / (10 n (c_1 + c_mu))` generations, by a small cyclic Jacobi solver;
//! * flat fitness (the best and the 0.7-lambda-th value equal) widens `sigma`.
//!
//! Each run stops on the tutorial's criteria (appendix B.3): TolFun, TolX,
//! NoEffectAxis, NoEffectCoord, ConditionCov (> 1e14), Stagnation, a per-run MaxIter
//! (pycma's default `100 + 150 (n+3)^2 / sqrt(lambda)`) and TolUpSigma.
//!
//! ## Restarts (IPOP)
//!
//! When a run stops, a new one starts with the population size doubled (Auger & Hansen,
//! "A restart CMA evolution strategy with increasing population size", CEC 2005), the
//! initial `sigma` and `C`, and a mean drawn uniformly in the box
//! ([`RestartFrom::RandomInBounds`], the default; unbounded coordinates restart from
//! `x0`) or `x0` itself ([`RestartFrom::InitialMean`]). Larger populations smooth out
//! multi-modal landscapes such as Rastrigin's. The best candidate over all runs is
//! kept. The optimiser stops when the target fitness is reached, the evaluation budget
//! is spent, or the last allowed run ends.
//!
//! ## Box bounds
//!
//! CMA-ES samples in an unbounded internal space; each bounded coordinate is normalised
//! to its box and mapped into it by a smooth, periodic, reflecting transformation:
//! identity in the interior, quadratic within 5% of the box width of each bound, and
//! mirrored beyond (the construction pycma documents for its `BoundTransform`). The
//! objective is thus always evaluated on a feasible point and is never penalised. So:
//!
//! * every candidate handed out by `ask` is inside `[lo, hi]`, with no rejection and no
//!   repair;
//! * an optimum on a bound is a smooth optimum of the transformed problem, and the
//!   search converges to the boundary point at the usual linear rate;
//! * the step size of a bounded coordinate is naturally relative to its box width
//!   ([`Sigma0::FractionOfWidth`]).
//!
//! ## Why ask/tell
//!
//! A tuning job's candidates are evaluated remotely, concurrently, in whatever order
//! workers finish, and the broker that holds the job may restart in the middle. So the
//! optimiser never calls the objective itself: [`Optimizer::ask`] hands out one
//! generation, [`Optimizer::tell`] takes its fitness values in the order asked (the
//! broker reduces in task-index order), and between the two the whole state is plain
//! data. It derives serde `Serialize`/`Deserialize`, including the random generator and
//! the pending generation, so a stored job resumes bit for bit. [`minimize`] wraps the
//! loop for in-process use.
//!
//! ## Determinism
//!
//! Randomness comes only from the crate's seeded xoshiro256++ generator (Box-Muller
//! normals); transcendental functions come from `libm`; ties in the ranking are broken
//! by candidate index. The same options give the same candidates, bit for bit, on every
//! host.
//!
//! ```
//! use paddock_tune::{minimize, Options, Sigma0};
//!
//! let sphere = |x: &[f64]| x.iter().map(|v| (v - 0.3) * (v - 0.3)).sum::<f64>();
//! let options = Options::new(vec![0.0; 4], Sigma0::FractionOfWidth(0.3))
//!     .with_bounds(vec![(-1.0, 1.0); 4])
//!     .with_target(1e-10)
//!     .with_seed(1);
//! let outcome = minimize(sphere, options).unwrap();
//! assert!(outcome.fitness <= 1e-10);
//! ```

mod bounds;
mod cma;
mod eigen;
mod error;
mod fit;
mod optimizer;
mod rng;

pub use error::TuneError;
pub use optimizer::{
    Optimizer, Options, RestartFrom, RunStop, Sigma0, Status, StopReason, Tolerances,
};

/// Result of [`minimize`].
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// Best candidate found (inside the bounds).
    pub x: Vec<f64>,
    pub fitness: f64,
    pub evaluations: u64,
    pub generations: u64,
    pub restarts: usize,
    pub stop: StopReason,
}

/// Minimise `f` by driving an [`Optimizer`] through ask/tell until it stops.
///
/// `f` may return `+inf` for a failed evaluation; a NaN is reported as
/// [`TuneError::InvalidFitness`].
pub fn minimize<F>(mut f: F, options: Options) -> Result<Outcome, TuneError>
where
    F: FnMut(&[f64]) -> f64,
{
    let mut opt = Optimizer::new(options)?;
    let stop = loop {
        if let Some(stop) = opt.is_done() {
            break stop;
        }
        let candidates = opt.ask()?;
        let fitness: Vec<f64> = candidates.iter().map(|x| f(x)).collect();
        opt.tell(&candidates, &fitness)?;
    };
    let status = opt.status();
    let (x, fitness) = opt
        .best()
        .map(|(x, f)| (x.to_vec(), f))
        .expect("at least one generation was told before stopping");
    Ok(Outcome {
        x,
        fitness,
        evaluations: status.evaluations,
        generations: status.generation,
        restarts: status.restarts,
        stop,
    })
}
