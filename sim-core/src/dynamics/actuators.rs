//! Command-path memories: the reference's 2-step steering buffer, an extra pure delay
//! line and a first-order lag. Plain data, so a world snapshot is a clone.

use serde::{Deserialize, Serialize};

/// Longest extra delay line in steps (guards against a tiny `dt` with a long delay).
pub const MAX_DELAY_STEPS: usize = 100_000;

/// The reference's steering buffer of length 2: the command given at step k is used at
/// step k+2; the first two steps use 0.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SteerBuffer {
    /// `[newest, oldest]`.
    cmds: [f64; 2],
    len: u8,
}

impl SteerBuffer {
    /// Push this step's command, return the one to use now.
    #[inline]
    pub fn push(&mut self, cmd: f64) -> f64 {
        let out = if self.len < 2 {
            self.len += 1;
            0.0
        } else {
            self.cmds[1]
        };
        self.cmds = [cmd, self.cmds[0]];
        out
    }

    /// Full of `cmd`, as after holding it for two steps or more.
    pub fn filled(cmd: f64) -> Self {
        Self {
            cmds: [cmd, cmd],
            len: 2,
        }
    }

    /// Commands waiting, newest first.
    pub fn pending(&self) -> &[f64] {
        &self.cmds[..self.len as usize]
    }
}

/// A pure delay of `n` steps, a ring filled with zeros (rest) when created or when `n`
/// changes; allocates only then, never per step.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct DelayLine {
    ring: Vec<f64>,
    head: usize,
}

impl DelayLine {
    /// Push this step's value into an `n`-step line and return the value from `n` steps ago.
    #[inline]
    pub fn push(&mut self, value: f64, n: usize) -> f64 {
        let n = n.min(MAX_DELAY_STEPS);
        if n == 0 {
            if !self.ring.is_empty() {
                self.clear();
            }
            return value;
        }
        if self.ring.len() != n {
            self.ring.clear();
            self.ring.resize(n, 0.0);
            self.head = 0;
        }
        let out = std::mem::replace(&mut self.ring[self.head], value);
        self.head += 1;
        if self.head == n {
            self.head = 0;
        }
        out
    }

    /// An `n`-step line full of `value`, as after holding it for `n` steps or more.
    pub fn fill(&mut self, value: f64, n: usize) {
        let n = n.min(MAX_DELAY_STEPS);
        self.ring.clear();
        self.ring.resize(n, value);
        self.head = 0;
    }

    /// Empty the line (keeps its allocation).
    pub fn clear(&mut self) {
        self.ring.clear();
        self.head = 0;
    }

    /// Number of steps currently held.
    pub fn len(&self) -> usize {
        self.ring.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ring.is_empty()
    }
}

/// Exact discretisation of a first-order lag with time constant `tau` over `dt`:
/// the fraction of the remaining gap closed in one step, `1 - exp(-dt / tau)`
/// (1 for `tau = 0`).
#[inline]
pub fn lag_gain(dt: f64, tau: f64) -> f64 {
    1.0 - libm::exp(-dt / tau)
}

/// Advance a lag state towards `input` and return the new output.
#[inline]
pub fn lag_update(state: &mut f64, input: f64, gain: f64) -> f64 {
    *state += gain * (input - *state);
    *state
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steer_buffer_delays_two_steps() {
        let mut b = SteerBuffer::default();
        let out: Vec<f64> = [1.0, 2.0, 3.0, 4.0].iter().map(|&c| b.push(c)).collect();
        assert_eq!(out, [0.0, 0.0, 1.0, 2.0]);
        assert_eq!(b.pending(), &[4.0, 3.0]);
    }

    #[test]
    fn delay_line_delays_n_steps_and_resizes() {
        let mut d = DelayLine::default();
        let out: Vec<f64> = (1..=5).map(|c| d.push(c as f64, 3)).collect();
        assert_eq!(out, [0.0, 0.0, 0.0, 1.0, 2.0]);
        assert_eq!(d.len(), 3);
        assert_eq!(d.push(9.0, 0), 9.0);
        assert!(d.is_empty());
    }

    #[test]
    fn lag_gain_limits() {
        assert_eq!(lag_gain(0.01, 0.0), 1.0);
        let g = lag_gain(0.01, 0.1);
        assert!((g - (1.0 - (-0.1f64).exp())).abs() < 1e-15);
        let mut s = 0.0;
        for _ in 0..10 {
            lag_update(&mut s, 1.0, g);
        }
        // After one time constant: 1 - 1/e.
        assert!((s - (1.0 - (-1.0f64).exp())).abs() < 1e-12, "{s}");
    }
}
