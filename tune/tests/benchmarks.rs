//! Statistical comparison with published pycma behaviour on 10-D test functions.
//!
//! Reference figures (pycma, default popsize 10, target 1e-8): sphere about
//! 1,000-1,600 evaluations; Rosenbrock about 5,000-7,000 (pycma median 5.1k on this
//! machine kind, the `cmaes` crate 4.6k-5.7k); Rastrigin needs IPOP's large
//! populations. Each test runs 20 seeds, prints its figures (`--nocapture`) and
//! asserts a band around them.

mod common;

use common::{median, rastrigin, rosenbrock, sphere, test_uniform};
use paddock_tune::{Options, Sigma0, StopReason, minimize};

const SEEDS: u64 = 20;
const DIM: usize = 10;

fn x0(seed: u64, lo: f64, hi: f64) -> Vec<f64> {
    (0..DIM)
        .map(|i| lo + (hi - lo) * test_uniform(seed, i))
        .collect()
}

/// Runs each seed; returns (evaluations of the successful runs, number of successes).
fn run_seeds(f: fn(&[f64]) -> f64, options: impl Fn(u64) -> Options) -> (Vec<u64>, usize) {
    let mut evals = Vec::new();
    for seed in 0..SEEDS {
        let outcome = minimize(f, options(seed)).expect("valid options");
        if outcome.stop == StopReason::TargetReached {
            assert!(outcome.fitness <= 1e-8);
            evals.push(outcome.evaluations);
        }
    }
    let successes = evals.len();
    (evals, successes)
}

#[test]
fn sphere_10d_median_evaluations_match_pycma() {
    let (mut evals, successes) = run_seeds(sphere, |seed| {
        Options::new(x0(seed, -1.0, 1.0), Sigma0::Absolute(0.5))
            .with_seed(seed)
            .with_target(1e-8)
            .with_max_restarts(0)
    });
    let med = median(&mut evals);
    println!(
        "sphere 10-D: {successes}/{SEEDS} reached 1e-8, median {med} evaluations, range {}..{}",
        evals[0],
        evals[evals.len() - 1]
    );
    assert_eq!(successes, SEEDS as usize);
    assert!((800..=2_000).contains(&med), "median {med}");
}

#[test]
fn rosenbrock_10d_median_evaluations_match_pycma() {
    let (mut evals, successes) = run_seeds(rosenbrock, |seed| {
        Options::new(x0(seed, -1.0, 1.0), Sigma0::Absolute(0.5))
            .with_seed(seed)
            .with_target(1e-8)
            .with_max_evals(100_000)
    });
    let med = median(&mut evals);
    println!(
        "rosenbrock 10-D: {successes}/{SEEDS} reached 1e-8, median {med} evaluations, range {}..{}",
        evals[0],
        evals[evals.len() - 1]
    );
    assert!(
        successes * 10 >= SEEDS as usize * 9,
        "success {successes}/{SEEDS}"
    );
    assert!((3_500..=8_000).contains(&med), "median {med}");
}

#[test]
fn rastrigin_10d_ipop_success_rate() {
    let (mut evals, successes) = run_seeds(rastrigin, |seed| {
        Options::new(x0(seed, -5.0, 5.0), Sigma0::Absolute(2.0))
            .with_seed(seed)
            .with_target(1e-8)
            .with_max_evals(200_000)
    });
    let med = if evals.is_empty() {
        0
    } else {
        median(&mut evals)
    };
    println!(
        "rastrigin 10-D IPOP: {successes}/{SEEDS} reached 1e-8 within 2e5 evaluations, median of successes {med}"
    );
    assert!(
        successes * 2 >= SEEDS as usize,
        "success {successes}/{SEEDS}"
    );
}
