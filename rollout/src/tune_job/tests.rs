use super::*;
use crate::{Executor, LocalExecutor};

fn eval(finished: usize, mean: Option<f64>) -> Evaluation {
    Evaluation {
        episodes: 20,
        finished,
        lap_time_mean: mean,
        lap_time_std: mean.map(|_| 0.1),
    }
}

#[test]
fn no_improvement_is_claimed_for_a_driver_that_finishes_fewer_starts() {
    // faster on the laps it finished, but 12/20 against 20/20: no claim
    assert_eq!(
        improvement_pct(&eval(20, Some(10.0)), &eval(12, Some(8.0))),
        None
    );
    assert_eq!(improvement_pct(&eval(20, Some(10.0)), &eval(0, None)), None);
    assert_eq!(improvement_pct(&eval(0, None), &eval(5, Some(9.0))), None);
    // as many (or more) finished: the lap-time gain counts, a loss shows negative
    assert_eq!(
        improvement_pct(&eval(20, Some(10.0)), &eval(20, Some(9.0))),
        Some(10.0)
    );
    assert_eq!(
        improvement_pct(&eval(18, Some(10.0)), &eval(19, Some(11.0))),
        Some(-10.0)
    );
}

fn small_job() -> TuneJob {
    let mut spec = TuneSpec::new("pure-pursuit");
    spec.generations = 2;
    spec.popsize = 4;
    spec.seeds = 2;
    spec.holdout = 2;
    spec.seed = 3;
    let mut base = Scenario::single("pure-pursuit").unwrap();
    base.time_limit = 8.0;
    TuneJob::new(spec, base, 60.0).unwrap()
}

fn run_to_end(job: &mut TuneJob, exec: &LocalExecutor, stop_after: Option<u32>) {
    let mut rounds = 0;
    while let Some(tasks) = job.next_round().unwrap() {
        if stop_after == Some(rounds) {
            return;
        }
        let results: Vec<EpisodeResult> = exec
            .run_batch(&tasks, &|_| {})
            .into_iter()
            .map(|r| r.unwrap())
            .collect();
        job.tell(&results).unwrap();
        rounds += 1;
    }
}

#[test]
fn a_job_resumed_from_its_serialised_state_ends_the_same() {
    let exec = LocalExecutor::new(0, paddock_sim::circuit::Circuits::new()).unwrap();
    let mut whole = small_job();
    run_to_end(&mut whole, &exec, None);
    assert!(whole.is_done());
    assert_eq!(whole.rounds_done(), 4);
    assert_eq!(whole.rounds_total(), 4);

    let mut first = small_job();
    run_to_end(&mut first, &exec, Some(1));
    // a handed-out round survives the round trip too
    first.next_round().unwrap();
    let stored = serde_json::to_string(&first).unwrap();
    let mut resumed: TuneJob = serde_json::from_str(&stored).unwrap();
    run_to_end(&mut resumed, &exec, None);
    assert_eq!(resumed.result(), whole.result());
    let r = whole.result().unwrap();
    assert_eq!(r.history.len(), 2);
    assert_eq!(r.episodes_run, 2 * 4 * 2 + 2 * 2 * 2 + 2 * 2);
    assert!(r.tuned_example.as_ref().unwrap().trajectory.is_some());
}

#[test]
fn bad_specs_and_wrong_result_counts_are_refused() {
    let base = Scenario::single("pure-pursuit").unwrap();
    let mut spec = TuneSpec::new("pure-pursuit");
    spec.crash_penalty = f64::NAN;
    let e = TuneJob::new(spec, base.clone(), 50.0).unwrap_err();
    assert!(e.to_string().contains("crash_penalty"), "{e}");
    let e = TuneJob::new(TuneSpec::new("no-such-driver"), base, 50.0).unwrap_err();
    assert!(e.to_string().contains("no-such-driver"), "{e}");
    let mut job = small_job();
    let e = job.tell(&[]).unwrap_err();
    assert!(e.to_string().contains("results"), "{e}");
}
