//! The replay reproduces a noise-free recording made by the simulator itself, and the
//! analysis finds an effect hidden in one (library level, no CLI).

use paddock_sim::dynamics::Vehicle;
use paddock_sim::geometry::Pose;
use paddock_sim::params::{SteeringOffset, VehicleParams};
use paddock_sysid::effects::EffectKind;
use paddock_sysid::recording::{Command, Recording, StateSample, wrap_pi};
use paddock_sysid::replay::Replay;
use paddock_sysid::{AnalysisOptions, analyze};

/// Drive `p` with smooth open-loop commands, logging every 3rd step (30 ms), no noise.
fn record(p: &VehicleParams, seconds: f64) -> Recording {
    let mut car = Vehicle::new(Pose::new(0.0, 0.0, 0.0));
    let mut rec = Recording::default();
    let steps = (seconds / 0.01) as usize;
    let mut cmd = (0.0, 0.0);
    for k in 0..=steps {
        let t = k as f64 * 0.01;
        if k % 3 == 0 {
            cmd = (
                0.25 * libm::sin(0.9 * t) + 0.1 * libm::sin(2.3 * t),
                3.0 + 1.5 * libm::sin(0.4 * t),
            );
            let (vx, vy) = car.body_velocity();
            let s = car.state;
            rec.commands.push(Command {
                t,
                steer: cmd.0,
                speed: cmd.1,
            });
            rec.states.push(StateSample {
                t,
                x: s.x,
                y: s.y,
                yaw: wrap_pi(s.yaw),
                vx,
                vy,
                yaw_rate: s.yaw_rate,
            });
        }
        car.step(p, cmd.0, cmd.1, 0.01);
    }
    rec
}

#[test]
fn replay_of_the_models_own_recording_is_near_exact() {
    let p = VehicleParams::default();
    let rec = record(&p, 30.0);
    rec.check().unwrap();
    let replay = Replay::new(&rec, 1.0);
    assert_eq!(replay.n_windows(), 31);
    let rmse = replay.residuals(&p).rmse(|_| true);
    // only the anchor smoothing of curved signals is left
    assert!(rmse[0] < 0.01 && rmse[1] < 0.01, "{rmse:?}");
    assert!(rmse[2] < 0.01 && rmse[5] < 0.05, "{rmse:?}");
    // a wrong model is far off
    let mut wrong = p.clone();
    wrong.effects.steering_offset = Some(SteeringOffset { offset_rad: 0.03 });
    let bad = replay.residuals(&wrong).rmse(|_| true);
    assert!(
        bad[5] > 3.0 * rmse[5] && bad[2] > 3.0 * rmse[2],
        "{bad:?} vs {rmse:?}"
    );
}

#[test]
fn analysis_finds_a_hidden_offset_and_nothing_else() {
    let mut truth = VehicleParams::default();
    truth.effects.steering_offset = Some(SteeringOffset { offset_rad: -0.02 });
    let rec = record(&truth, 30.0);
    let opts = AnalysisOptions {
        candidates: vec![
            EffectKind::SteeringOffset,
            EffectKind::SteeringLag,
            EffectKind::Drag,
        ],
        ..AnalysisOptions::default()
    };
    let calls = std::sync::atomic::AtomicUsize::new(0);
    let a = analyze(&rec, &VehicleParams::default(), &opts, &|_| {
        calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    assert!(calls.into_inner() >= 3, "progress was reported");
    assert_eq!(a.effects.len(), 1, "{:?}", a.effects);
    assert_eq!(a.effects[0].kind, EffectKind::SteeringOffset);
    assert!(
        (a.effects[0].values[0] + 0.02).abs() < 0.002,
        "{:?}",
        a.effects
    );
    for c in 0..6 {
        assert!(a.rmse_after[c] <= a.rmse_before[c] * 1.01);
    }
    assert!(a.rmse_after[5] < 0.3 * a.rmse_before[5]);
    let off = a.fitted.effects.steering_offset.unwrap().offset_rad;
    assert!((off + 0.02).abs() < 0.002);
}

#[test]
fn bad_options_are_named() {
    let rec = record(&VehicleParams::default(), 10.0);
    for (opts, field) in [
        (
            AnalysisOptions {
                window_s: 0.0,
                ..Default::default()
            },
            "window_s",
        ),
        (
            AnalysisOptions {
                folds: 1,
                ..Default::default()
            },
            "folds",
        ),
        (
            AnalysisOptions {
                margin_per_param: f64::NAN,
                ..Default::default()
            },
            "margin_per_param",
        ),
    ] {
        let e = analyze(&rec, &VehicleParams::default(), &opts, &|_| {}).unwrap_err();
        assert!(e.to_string().contains(field), "{e}");
    }
    // too short for the folds: 10 s with 5 s windows is 2 windows for 3 folds
    let opts = AnalysisOptions {
        window_s: 5.0,
        ..Default::default()
    };
    let e = analyze(&rec, &VehicleParams::default(), &opts, &|_| {}).unwrap_err();
    assert!(e.to_string().contains("too short"), "{e}");
}
