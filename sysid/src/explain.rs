//! Words for people: what a fitted parameter means on the car, which effects the data
//! cannot identify (and what to drive so they can), and the VESC driver's parameters
//! that undo a fitted calibration error.

use serde_json::{Value, json};

use crate::effects::EffectKind;
use crate::recording::Recording;
use crate::replay::smoothed_state;

/// A parameter's physical reading ("the steering answers 56 ms late").
pub fn reading(kind: EffectKind, v: &[f64], nominal_mu: f64) -> String {
    let deg = |r: f64| r.to_degrees();
    match kind {
        EffectKind::SteeringDelay => format!(
            "the steering answers {:.0} ms later than the simulator assumes",
            1e3 * v[0]
        ),
        EffectKind::SteeringLag => format!(
            "the wheels follow a steering command with a lag of {:.0} ms (time constant)",
            1e3 * v[0]
        ),
        EffectKind::SteeringOffset => format!(
            "with a straight command the wheels point {:.3} rad ({:.2} deg) to the {}",
            v[0].abs(),
            deg(v[0].abs()),
            if v[0] > 0.0 { "left" } else { "right" }
        ),
        EffectKind::SteeringGain => format!(
            "the wheels turn {:.0} % of the commanded angle",
            100.0 * v[0]
        ),
        EffectKind::SteeringBacklash => format!(
            "the steering linkage has {:.3} rad ({:.1} deg) of play: after a reversal the wheels wait that much command before they move",
            v[0],
            deg(v[0])
        ),
        EffectKind::DriveLag => format!(
            "the speed follows its command with a lag of {:.0} ms (time constant)",
            1e3 * v[0]
        ),
        EffectKind::SpeedGain => format!(
            "the car drives at {:.0} % of the commanded speed",
            100.0 * v[0]
        ),
        EffectKind::Drag => format!(
            "resistance takes {:.2} m/s^2 off at 3 m/s and {:.2} m/s^2 at 6 m/s",
            3.0 * v[0] + 9.0 * v[1],
            6.0 * v[0] + 36.0 * v[1]
        ),
        EffectKind::Friction => format!(
            "the tyres grip {:.0} % as well as the nominal model's (mu {:.2} for {:.2})",
            100.0 * v[0] / nominal_mu,
            v[0],
            nominal_mu
        ),
        EffectKind::FrictionPatch => format!(
            "the floor in x [{:.1}, {:.1}] m, y [{:.1}, {:.1}] m grips with mu {:.2}",
            v[1], v[3], v[2], v[4], v[0]
        ),
        EffectKind::TireSaturation => format!(
            "the tyres' lateral force levels off at {:.2} times the load (D), shape C {:.2}",
            v[0], v[1]
        ),
        EffectKind::MeasurementDelay => format!(
            "the pose source reports states {:.0} ms old (a sensor property: set it in the localiser or the policy, not in vehicle.yaml)",
            1e3 * v[0]
        ),
    }
}

/// How much the recording exercises each kind of effect.
#[derive(Debug, Clone, Default)]
pub struct Excitation {
    pub steer_cmd_range: f64,
    pub steer_reversals: usize,
    pub speed_cmd_changes: usize,
    pub max_speed: f64,
    pub max_lateral_accel: f64,
    pub missing: [bool; 6],
}

/// Measure the excitation of `rec`.
pub fn excitation(rec: &Recording) -> Excitation {
    let mut e = Excitation {
        missing: rec.missing_channels(),
        ..Default::default()
    };
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    let mut last_dir = 0.0f64;
    let mut anchor = f64::NAN;
    let mut prev_speed = f64::NAN;
    for c in &rec.commands {
        lo = lo.min(c.steer);
        hi = hi.max(c.steer);
        if anchor.is_nan() {
            anchor = c.steer;
        }
        // a reversal: the command turns back by more than 0.05 rad
        let d = c.steer - anchor;
        if d.abs() > 0.05 {
            let dir = d.signum();
            if last_dir != 0.0 && dir != last_dir {
                e.steer_reversals += 1;
            }
            last_dir = dir;
            anchor = c.steer;
        }
        if prev_speed.is_finite() && (c.speed - prev_speed).abs() > 0.3 {
            e.speed_cmd_changes += 1;
        }
        prev_speed = c.speed;
    }
    e.steer_cmd_range = if hi >= lo { hi - lo } else { 0.0 };
    for run in rec.runs() {
        let st = &rec.states[run.first_state..run.first_state + run.n_states];
        let mut t = run.start;
        while t <= run.end {
            let s = smoothed_state(st, t);
            let v = libm::hypot(s.vx, s.vy);
            e.max_speed = e.max_speed.max(v);
            e.max_lateral_accel = e.max_lateral_accel.max((v * s.yaw_rate).abs());
            t += 0.1;
        }
    }
    e
}

/// Effects these data cannot identify, each with the reason and what to drive.
pub fn not_identifiable(e: &Excitation, nominal_mu: f64) -> Vec<(EffectKind, String)> {
    let mut out = Vec::new();
    let steer = e.steer_cmd_range > 0.05;
    if !steer {
        for k in [
            EffectKind::SteeringDelay,
            EffectKind::SteeringLag,
            EffectKind::SteeringGain,
        ] {
            out.push((
                k,
                "the steering command hardly changes: drive steering steps (0.2 rad at 2 m/s)"
                    .to_string(),
            ));
        }
    }
    if e.steer_reversals == 0 {
        out.push((
            EffectKind::SteeringBacklash,
            "the steering never reverses: drive a step one way and then the other".into(),
        ));
    }
    if e.speed_cmd_changes == 0 {
        out.push((
            EffectKind::DriveLag,
            "the speed command never steps: drive speed steps (2 -> 4 m/s)".into(),
        ));
        out.push((
            EffectKind::MeasurementDelay,
            "without speed steps a pose latency looks like a steering delay: drive speed steps"
                .into(),
        ));
    }
    if e.max_speed < 3.0 {
        out.push((
            EffectKind::Drag,
            format!(
                "the car never drove faster than {:.1} m/s: drive straights at 4-6 m/s",
                e.max_speed
            ),
        ));
    }
    let grip = 0.5 * nominal_mu * paddock_sim::params::GRAVITY;
    if e.max_lateral_accel < grip {
        for k in [EffectKind::Friction, EffectKind::TireSaturation] {
            out.push((
                k,
                format!(
                    "the lateral acceleration never passed {:.1} m/s^2 (half the nominal grip): drive arcs at rising speed",
                    e.max_lateral_accel
                ),
            ));
        }
    }
    if e.missing[4] && e.missing[5] {
        out.push((
            EffectKind::TireSaturation,
            "no vy or yaw_rate: the tyres show only through the pose; a gyro's yaw rate would help"
                .into(),
        ));
    }
    out
}

/// The VESC driver's parameters (f1tenth_system `vesc.yaml` keys) found in `text`.
pub fn vesc_params(text: &str) -> Result<Vec<(String, f64)>, crate::SysidError> {
    let v: Value = serde_norway::from_str(text).map_err(|e| crate::SysidError::Format {
        message: format!("the VESC config is not YAML: {e}"),
    })?;
    let mut found = Vec::new();
    fn walk(v: &Value, found: &mut Vec<(String, f64)>) {
        match v {
            Value::Object(m) => {
                for (k, x) in m {
                    if VESC_KEYS.contains(&k.as_str()) {
                        if let Some(f) = x.as_f64() {
                            found.push((k.clone(), f));
                        }
                    } else {
                        walk(x, found);
                    }
                }
            }
            Value::Array(a) => a.iter().for_each(|x| walk(x, found)),
            _ => {}
        }
    }
    walk(&v, &mut found);
    if found.is_empty() {
        return Err(crate::SysidError::Format {
            message: format!("the VESC config has none of {}", VESC_KEYS.join(", ")),
        });
    }
    Ok(found)
}

const VESC_KEYS: [&str; 4] = [
    "speed_to_erpm_gain",
    "speed_to_erpm_offset",
    "steering_angle_to_servo_gain",
    "steering_angle_to_servo_offset",
];

/// The VESC parameters that undo a fitted `steering_gain` g, `steering_offset` o and
/// `speed_gain` k: the servo map becomes `gain / g` and `offset - gain o / g`, the erpm
/// gain `gain / k`. Only the keys that change are returned, with old and new values.
pub fn vesc_corrections(
    params: &[(String, f64)],
    steering_gain: Option<f64>,
    steering_offset: Option<f64>,
    speed_gain: Option<f64>,
) -> Value {
    let get = |k: &str| params.iter().find(|(n, _)| n == k).map(|(_, v)| *v);
    let mut out = serde_json::Map::new();
    let r = |x: f64| (x * 1e5).round() / 1e5;
    if steering_gain.is_some() || steering_offset.is_some() {
        let g = steering_gain.unwrap_or(1.0);
        let o = steering_offset.unwrap_or(0.0);
        if let (Some(gs), Some(os)) = (
            get("steering_angle_to_servo_gain"),
            get("steering_angle_to_servo_offset"),
        ) {
            out.insert(
                "steering_angle_to_servo_gain".into(),
                json!({"old": gs, "new": r(gs / g)}),
            );
            out.insert(
                "steering_angle_to_servo_offset".into(),
                json!({"old": os, "new": r(os - gs * o / g)}),
            );
        }
    }
    if let (Some(k), Some(ge)) = (speed_gain, get("speed_to_erpm_gain")) {
        out.insert(
            "speed_to_erpm_gain".into(),
            json!({"old": ge, "new": r(ge / k)}),
        );
    }
    Value::Object(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vesc_keys_are_found_and_corrected() {
        let text = "/**:\n  ros__parameters:\n    speed_to_erpm_gain: 4614.0\n    speed_to_erpm_offset: 0.0\n    steering_angle_to_servo_gain: -1.2135\n    steering_angle_to_servo_offset: 0.5304\n    port: /dev/sensors/vesc\n";
        let p = vesc_params(text).unwrap();
        assert_eq!(p.len(), 4);
        let c = vesc_corrections(&p, Some(0.8), Some(0.02), Some(1.1));
        let gs = c["steering_angle_to_servo_gain"]["new"].as_f64().unwrap();
        assert!((gs - (-1.2135 / 0.8)).abs() < 1e-4, "{c}");
        // with the new map a command c gives servo gs' c + os'; the old map gave the
        // wheel angle 0.8 c + 0.02 at servo -1.2135 c + 0.5304: the wheel now sits at c
        let os = c["steering_angle_to_servo_offset"]["new"].as_f64().unwrap();
        for cmd in [-0.3, 0.0, 0.25] {
            let servo = gs * cmd + os;
            let old_cmd = (servo - 0.5304) / -1.2135;
            assert!((0.8 * old_cmd + 0.02 - cmd).abs() < 1e-4);
        }
        let ge = c["speed_to_erpm_gain"]["new"].as_f64().unwrap();
        assert!((ge - 4614.0 / 1.1).abs() < 1e-2);
        assert!(vesc_params("a: 1\n").is_err());
        assert!(vesc_params(": : :").is_err());
    }
}
