//! Calibration and play of the command path: the hand-set gains of the VESC driver
//! (`steering_angle_to_servo_gain`, `speed_to_erpm_gain`) make the wheel angle a scaled
//! command and the speed target a scaled one, and the servo linkage of a 1/10 car has
//! play. All off by default; with them off the step is the reference's, bit for bit.

use serde::{Deserialize, Serialize};

use super::{ParamsError, check};

/// Wheel angle target = `gain` x steering command (before `steering_offset`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SteeringGain {
    pub gain: f64,
}

/// Speed target = `gain` x speed command (before `drive_lag`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedGain {
    pub gain: f64,
}

/// Play in the steering linkage: a dead band `width_rad` wide between the steering
/// target and the wheel's target. The wheel's target moves only when the steering target
/// pushes one side of the band, so after a reversal the wheel waits `width_rad` before it
/// follows (it rests `width_rad / 2` short of a target approached from either side).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SteeringBacklash {
    pub width_rad: f64,
}

impl SteeringBacklash {
    /// Move the play's output `state` for the input `target` and return it.
    #[inline]
    pub fn update(&self, state: &mut f64, target: f64) -> f64 {
        let half = 0.5 * self.width_rad;
        if target > *state + half {
            *state = target - half;
        } else if target < *state - half {
            *state = target + half;
        }
        *state
    }
}

/// Check the calibration effects (dotted field names under `effects`).
pub(super) fn validate(
    steering_gain: Option<&SteeringGain>,
    speed_gain: Option<&SpeedGain>,
    backlash: Option<&SteeringBacklash>,
) -> Result<(), ParamsError> {
    if let Some(g) = steering_gain {
        check(
            "effects.steering_gain.gain",
            g.gain,
            g.gain > 0.0 && g.gain <= 10.0,
            "in (0, 10]",
        )?;
    }
    if let Some(g) = speed_gain {
        check(
            "effects.speed_gain.gain",
            g.gain,
            g.gain > 0.0 && g.gain <= 10.0,
            "in (0, 10]",
        )?;
    }
    if let Some(b) = backlash {
        check(
            "effects.steering_backlash.width_rad",
            b.width_rad,
            (0.0..=1.0).contains(&b.width_rad),
            "in [0, 1] rad",
        )?;
    }
    Ok(())
}
