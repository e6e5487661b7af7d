//! Behaviour of the ask/tell API: bounds, determinism, resumption, errors, restarts.

mod common;

use common::{rosenbrock, sphere};
use paddock_tune::{
    Optimizer, Options, RestartFrom, RunStop, Sigma0, StopReason, Tolerances, TuneError, minimize,
};

fn bits(generation: &[Vec<f64>]) -> Vec<u64> {
    generation.iter().flatten().map(|v| v.to_bits()).collect()
}

/// Drives `opt` to the end, recording every generation's candidates as bits.
fn drive(opt: &mut Optimizer, f: impl Fn(&[f64]) -> f64) -> Vec<Vec<u64>> {
    let mut log = Vec::new();
    while opt.is_done().is_none() {
        let candidates = opt.ask().unwrap();
        let fitness: Vec<f64> = candidates.iter().map(|x| f(x)).collect();
        opt.tell(&candidates, &fitness).unwrap();
        log.push(bits(&candidates));
    }
    log
}

/// Rosenbrock that "fails" (+inf) in part of the space, to exercise +inf handling.
fn rosenbrock_with_failures(x: &[f64]) -> f64 {
    if x[0] > 1.5 {
        f64::INFINITY
    } else {
        rosenbrock(x)
    }
}

fn resumable_options() -> Options {
    // Small per-run iteration cap so that restarts happen within the test.
    let tolerances = Tolerances {
        max_iter: Some(60),
        ..Tolerances::default()
    };
    Options::new(vec![0.5; 6], Sigma0::FractionOfWidth(0.3))
        .with_bounds(vec![(-2.0, 2.0); 6])
        .with_seed(42)
        .with_tolerances(tolerances)
        .with_max_restarts(3)
        .with_max_evals(6_000)
}

#[test]
fn every_candidate_lies_inside_the_bounds() {
    // The optimum (3, -3, 0.2, ...) is partly outside the box, restarts included.
    let bounds = vec![
        (-1.0, 1.0),
        (-0.5, 2.0),
        (0.0, 0.1),
        (-1e-3, 1e-3),
        (5.0, 6.0),
    ];
    let target = [3.0, -3.0, 0.2, 0.0, 5.5];
    let f = |x: &[f64]| {
        x.iter()
            .zip(&target)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
    };
    let mut opt = Optimizer::new(
        Options::new(vec![0.0, 0.0, 0.05, 0.0, 5.9], Sigma0::FractionOfWidth(0.5))
            .with_bounds(bounds.clone())
            .with_seed(3)
            .with_max_restarts(2),
    )
    .unwrap();
    let mut count = 0;
    while opt.is_done().is_none() {
        let candidates = opt.ask().unwrap();
        for x in &candidates {
            for (v, (lo, hi)) in x.iter().zip(&bounds) {
                assert!(*lo <= *v && *v <= *hi, "{v} outside [{lo}, {hi}]");
            }
            count += 1;
        }
        let fitness: Vec<f64> = candidates.iter().map(|x| f(x)).collect();
        opt.tell(&candidates, &fitness).unwrap();
    }
    assert!(opt.status().restarts == 2 && count > 1000);
}

#[test]
fn optimum_outside_the_box_converges_to_the_boundary_point() {
    // Interior optimum in some coordinates, on the lower or upper bound in others.
    let centre = [-3.0, 0.25, 4.0, -0.5, 1.0];
    let expected = [-1.0, 0.25, 1.0, -0.5, 1.0];
    let f = |x: &[f64]| {
        x.iter()
            .zip(&centre)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
    };
    let f_star = f(&expected);
    let outcome = minimize(
        f,
        Options::new(vec![0.0; 5], Sigma0::FractionOfWidth(0.3))
            .with_bounds(vec![(-1.0, 1.0); 5])
            .with_seed(11)
            .with_max_restarts(0),
    )
    .unwrap();
    for (x, e) in outcome.x.iter().zip(&expected) {
        assert!((x - e).abs() < 1e-6, "{:?} vs {expected:?}", outcome.x);
    }
    assert!(
        outcome.fitness - f_star < 1e-10,
        "{} vs {f_star}",
        outcome.fitness
    );
    assert!(matches!(outcome.stop, StopReason::RestartsExhausted(_)));
}

#[test]
fn same_seed_gives_the_same_candidates_bit_for_bit() {
    let run = |seed| {
        let mut opt = Optimizer::new(resumable_options().with_seed(seed)).unwrap();
        drive(&mut opt, rosenbrock_with_failures)
    };
    let a = run(42);
    let b = run(42);
    let c = run(43);
    assert!(a.len() > 50);
    assert_eq!(a, b);
    assert_ne!(a[0], c[0]);
}

#[test]
fn candidates_are_pinned_across_hosts() {
    // A golden value: the first generations of a fixed problem must not change between
    // hosts or builds. Update deliberately (and say why) if the algorithm changes.
    let mut opt = Optimizer::new(resumable_options()).unwrap();
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for _ in 0..20 {
        let candidates = opt.ask().unwrap();
        for b in bits(&candidates) {
            hash = (hash ^ b).wrapping_mul(0x0100_0000_01b3);
        }
        let fitness: Vec<f64> = candidates.iter().map(|x| rosenbrock(x)).collect();
        opt.tell(&candidates, &fitness).unwrap();
    }
    assert_eq!(hash, GOLDEN_HASH, "got {hash:#018x}");
}
const GOLDEN_HASH: u64 = 0xa743_f9b1_39b6_7eac;

#[test]
fn resumes_bit_identically_after_serialisation() {
    let mut reference = Optimizer::new(resumable_options()).unwrap();
    let full = drive(&mut reference, rosenbrock_with_failures);
    assert!(
        reference.status().restarts >= 1,
        "test should cover a restart"
    );

    for stop_after in [1, 37, 75, 130] {
        for mid_generation in [false, true] {
            let mut opt = Optimizer::new(resumable_options()).unwrap();
            let mut log = Vec::new();
            for _ in 0..stop_after {
                let candidates = opt.ask().unwrap();
                let fitness: Vec<f64> = candidates
                    .iter()
                    .map(|x| rosenbrock_with_failures(x))
                    .collect();
                opt.tell(&candidates, &fitness).unwrap();
                log.push(bits(&candidates));
            }
            let mut pending = None;
            if mid_generation {
                pending = Some(opt.ask().unwrap());
            }
            let json = serde_json::to_string(&opt).unwrap();
            drop(opt);
            let mut resumed: Optimizer = serde_json::from_str(&json).unwrap();
            if let Some(candidates) = pending {
                let fitness: Vec<f64> = candidates
                    .iter()
                    .map(|x| rosenbrock_with_failures(x))
                    .collect();
                resumed.tell(&candidates, &fitness).unwrap();
                log.push(bits(&candidates));
            }
            log.extend(drive(&mut resumed, rosenbrock_with_failures));
            assert_eq!(log, full, "resumed after {stop_after} generations");
            assert_eq!(resumed, reference);
        }
    }
}

#[test]
fn failed_evaluations_are_tolerated() {
    // +inf everywhere outside a small feasible region: the search still converges.
    let f = |x: &[f64]| {
        if x[0] < 0.5 {
            f64::INFINITY
        } else {
            sphere(&[x[0] - 1.0, x[1]])
        }
    };
    let outcome = minimize(
        f,
        Options::new(vec![0.6, 0.0], Sigma0::Absolute(0.2))
            .with_seed(5)
            .with_target(1e-10),
    )
    .unwrap();
    assert_eq!(outcome.stop, StopReason::TargetReached);
}

#[test]
fn tell_errors_name_the_problem_and_change_nothing() {
    let mut opt = Optimizer::new(Options::new(vec![0.0; 3], Sigma0::Absolute(1.0))).unwrap();
    assert_eq!(opt.tell(&[], &[]), Err(TuneError::NoPendingAsk));

    let candidates = opt.ask().unwrap();
    let lambda = candidates.len();
    assert_eq!(lambda, 7);
    assert!(matches!(
        opt.ask(),
        Err(TuneError::TellPending { generation: 0 })
    ));
    let before = opt.clone();

    let mut fitness = vec![1.0; lambda];
    fitness[3] = f64::NAN;
    let err = opt.tell(&candidates, &fitness).unwrap_err();
    assert!(matches!(err, TuneError::InvalidFitness { index: 3, .. }));
    assert_eq!(
        err.to_string(),
        "fitness[3] = NaN: must be a number or +inf (failed evaluation)"
    );
    fitness[3] = f64::NEG_INFINITY;
    assert!(
        opt.tell(&candidates, &fitness)
            .unwrap_err()
            .to_string()
            .contains("fitness[3] = -inf")
    );

    let err = opt.tell(&candidates, &[1.0; 6]).unwrap_err();
    assert_eq!(err.to_string(), "tell got 6 fitness values, expected 7");
    let err = opt.tell(&candidates[..5], &[1.0; 7]).unwrap_err();
    assert_eq!(err.to_string(), "tell got 5 candidates, expected 7");

    let mut wrong = candidates.clone();
    wrong[2].push(0.0);
    let err = opt.tell(&wrong, &[1.0; 7]).unwrap_err();
    assert_eq!(
        err.to_string(),
        "candidates[2] has 4 coordinates, expected 3"
    );

    let mut wrong = candidates.clone();
    wrong.swap(0, 4);
    let err = opt.tell(&wrong, &[1.0; 7]).unwrap_err();
    assert!(
        matches!(
            err,
            TuneError::CandidateMismatch {
                index: 0,
                coordinate: 0,
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().starts_with("candidates[0][0] = "));

    assert_eq!(opt, before, "failed tells leave the state unchanged");
    let mut fitness = vec![2.0; lambda];
    fitness[1] = f64::INFINITY;
    opt.tell(&candidates, &fitness).unwrap();
    assert_eq!(opt.status().evaluations, 7);
    assert_eq!(opt.best().unwrap().1, 2.0);
}

#[test]
fn ask_after_stop_is_an_error() {
    let mut opt =
        Optimizer::new(Options::new(vec![1.0; 2], Sigma0::Absolute(0.5)).with_max_evals(5))
            .unwrap();
    let candidates = opt.ask().unwrap();
    let fitness: Vec<f64> = candidates.iter().map(|x| sphere(x)).collect();
    opt.tell(&candidates, &fitness).unwrap();
    assert_eq!(opt.is_done(), Some(StopReason::MaxEvaluations));
    let err = opt.ask().unwrap_err();
    assert_eq!(err, TuneError::Finished(StopReason::MaxEvaluations));
}

#[test]
fn invalid_options_are_rejected_with_the_field_named() {
    let base = || Options::new(vec![0.0; 2], Sigma0::Absolute(1.0));
    let message = |o: Options| Optimizer::new(o).unwrap_err().to_string();
    assert!(message(Options::new(vec![], Sigma0::Absolute(1.0))).contains("`x0`"));
    assert!(
        message(Options::new(vec![0.0, f64::NAN], Sigma0::Absolute(1.0))).contains("`x0` = NaN")
    );
    assert!(message(base().with_bounds(vec![(0.0, 1.0)])).contains("`bounds`"));
    assert!(
        message(base().with_bounds(vec![(-1.0, 1.0), (1.0, -1.0)]))
            .contains("`bounds` = (1, 1.0, -1.0)")
    );
    assert!(
        message(base().with_bounds(vec![(-1.0, 1.0), (0.0, f64::INFINITY)])).contains("one-sided")
    );
    assert!(message(base().with_bounds(vec![(-1.0, 1.0), (0.5, 1.0)])).contains("`x0` = (1, 0.0)"));
    assert!(message(Options::new(vec![0.0; 2], Sigma0::Absolute(-1.0))).contains("`sigma0`"));
    assert!(
        message(Options::new(vec![0.0; 2], Sigma0::FractionOfWidth(0.3)))
            .contains("needs every coordinate bounded")
    );
    assert!(message(base().with_popsize(1)).contains("`popsize` = 1"));
    assert!(message(base().with_target(f64::NAN)).contains("`target`"));
    // Mixed bounded and unbounded coordinates are fine.
    let ok = base().with_bounds(vec![(-1.0, 1.0), (f64::NEG_INFINITY, f64::INFINITY)]);
    assert!(Optimizer::new(ok).is_ok());
}

#[test]
fn ipop_doubles_the_population_on_each_restart() {
    let tolerances = Tolerances {
        max_iter: Some(20),
        ..Tolerances::default()
    };
    let mut opt = Optimizer::new(
        Options::new(vec![0.0; 4], Sigma0::Absolute(1.0))
            .with_popsize(6)
            .with_tolerances(tolerances)
            .with_max_restarts(3)
            .with_restart_from(RestartFrom::InitialMean),
    )
    .unwrap();
    let mut popsizes = Vec::new();
    while opt.is_done().is_none() {
        let candidates = opt.ask().unwrap();
        if popsizes.last() != Some(&candidates.len()) {
            popsizes.push(candidates.len());
        }
        let fitness: Vec<f64> = candidates.iter().map(|x| rosenbrock(x)).collect();
        opt.tell(&candidates, &fitness).unwrap();
    }
    assert_eq!(popsizes, vec![6, 12, 24, 48]);
    let status = opt.status();
    assert_eq!(status.restarts, 3);
    assert_eq!(status.generation, 80);
    assert_eq!(status.evaluations, 20 * (6 + 12 + 24 + 48));
    assert_eq!(
        status.stop,
        Some(StopReason::RestartsExhausted(RunStop::MaxIter))
    );
}

#[test]
fn a_converged_run_stops_on_a_tolerance() {
    let outcome = minimize(
        sphere,
        Options::new(vec![1.0; 3], Sigma0::Absolute(0.5)).with_max_restarts(0),
    )
    .unwrap();
    assert!(outcome.fitness < 1e-12, "{}", outcome.fitness);
    assert!(
        matches!(
            outcome.stop,
            StopReason::RestartsExhausted(RunStop::TolFun | RunStop::TolX)
        ),
        "{:?}",
        outcome.stop
    );
}

#[test]
fn minimize_reports_a_nan_objective() {
    let err = minimize(|_| f64::NAN, Options::new(vec![0.0], Sigma0::Absolute(1.0))).unwrap_err();
    assert!(matches!(err, TuneError::InvalidFitness { index: 0, .. }));
}
