//! The choice between the angular sweep and the march when a LIDAR is left to choose
//! ([`ScanAlgorithm::Auto`]): both give the same bits, and which is faster depends on the
//! map and the CPU (on AVX-512 CPUs the march is the faster on some real tracks, the sweep
//! on others and on every map measured with AVX2 alone; `docs/performance-scan.md`).
//!
//! Each thread keeps, per map, code path and beam count it scans, a trial of both: each
//! of its first `TRIAL` scans is computed by both algorithms in turn (which one first
//! alternates), each timed, so that both are timed on the same scans whatever the
//! scenes (a vector env's consecutive scans are of different cars); the one with the
//! lower total time, leaving out the `DROP` scans that took longest in all (a thread
//! interrupted mid-scan), takes the scans after, until the next trial `PERIOD` scans
//! later (so that a change of scene, more cars in view say, is seen). A trial costs its
//! scans' time by the slower algorithm, about 2 % of a thread's scan time where that is
//! the march at three to four times the sweep's (AVX2 alone); so after a trial that the
//! same algorithm won again by at least `DECISIVE` times the other's time, the next comes
//! twice as many scans later, up to `LONGEST` (a trial that is closer, or won by the
//! other algorithm, brings the period back to `PERIOD`). The timing only picks which of
//! two bit-identical computations runs: results never depend on it.

use super::ScanAlgorithm;

/// Scans in a trial, each computed by both algorithms.
pub(super) const TRIAL: usize = 16;
/// The trial's scans left out of the comparison: those that took longest in all.
const DROP: usize = 2;
/// Scans from the start of one trial to the start of the next, per map, after the
/// first trial and after a close one.
pub(super) const PERIOD: u64 = 2048;
/// The longest such period, after decisive trials won by the same algorithm.
const LONGEST: u64 = 16 * PERIOD;
/// How many times the winner's time the loser must take for a trial to be decisive.
const DECISIVE: u64 = 2;
/// Maps (with path and beam count) remembered per thread; the least recently scanned is
/// forgotten first.
const KEYS: usize = 8;

/// What a choice is kept for: the map (by address), the code path and the beam count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Key {
    pub map: usize,
    pub path: u8,
    pub beams: usize,
}

/// One map's trials.
struct Entry {
    key: Key,
    /// Scans of this key since the start of its current trial.
    scans: u64,
    /// Scans from the start of this key's current trial to the start of the next.
    period: u64,
    /// The last trial's winner (true: the sweep), which takes the scans outside trials;
    /// `None` until the first trial ends (the sweep takes them).
    winner: Option<bool>,
    /// When this key was last scanned (the chooser's own tick).
    used: u64,
    /// The current trial's times in nanoseconds, `[march, sweep]` per scan.
    times: [[u64; 2]; TRIAL],
}

/// The next scan's algorithm (the first of the two in a trial), and its trial slot, if
/// it is one (the entry and the scan's index in the trial).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Pick {
    pub sweep: bool,
    pub trial: Option<(usize, usize)>,
}

/// A thread's choices (see the module doc) and its scans.
pub(super) struct Choice {
    entries: Vec<Entry>,
    tick: u64,
    /// This thread's scans so far, whatever the mode (a trial's scan twice: it is
    /// computed by both algorithms).
    pub scans: u64,
}

impl Choice {
    pub(super) const fn new() -> Choice {
        Choice {
            entries: Vec::new(),
            tick: 0,
            scans: 0,
        }
    }

    /// The algorithm of the next scan of `key` by a LIDAR set to `algorithm`.
    pub(super) fn pick(&mut self, algorithm: ScanAlgorithm, key: Key) -> Pick {
        self.scans += 1;
        match algorithm {
            ScanAlgorithm::Sweep => {
                return Pick {
                    sweep: true,
                    trial: None,
                };
            }
            ScanAlgorithm::March => {
                return Pick {
                    sweep: false,
                    trial: None,
                };
            }
            ScanAlgorithm::Auto => {}
        }
        self.tick += 1;
        let e = match self.entries.iter().position(|e| e.key == key) {
            Some(e) => e,
            None if self.entries.len() < KEYS => {
                self.entries.push(Entry::new(key));
                self.entries.len() - 1
            }
            None => {
                let (oldest, _) = self
                    .entries
                    .iter()
                    .enumerate()
                    .min_by_key(|(_, e)| e.used)
                    .expect("KEYS > 0 entries");
                self.entries[oldest] = Entry::new(key);
                oldest
            }
        };
        let entry = &mut self.entries[e];
        entry.used = self.tick;
        let phase = entry.scans as usize;
        entry.scans += 1;
        if entry.scans >= entry.period {
            entry.scans = 0;
        }
        if phase < TRIAL {
            self.scans += 1;
            Pick {
                sweep: phase.is_multiple_of(2),
                trial: Some((e, phase)),
            }
        } else {
            Pick {
                sweep: entry.winner.unwrap_or(true),
                trial: None,
            }
        }
    }

    /// Records that trial scan `slot` (from [`Choice::pick`]) took `march` nanoseconds by
    /// the march and `sweep` by the sweep; the trial's last scan settles the choice.
    pub(super) fn timed(&mut self, (e, phase): (usize, usize), march: u64, sweep: u64) {
        let entry = &mut self.entries[e];
        entry.times[phase] = [march, sweep];
        if phase == TRIAL - 1 {
            let [march, sweep] = totals(&mut entry.times);
            let won = sweep <= march;
            let (winner, loser) = if won { (sweep, march) } else { (march, sweep) };
            let decisive = loser >= winner.saturating_mul(DECISIVE);
            // A first trial has no earlier winner to agree with: the period grows from
            // the second.
            entry.period = if decisive && entry.winner == Some(won) {
                (entry.period * 2).min(LONGEST)
            } else {
                PERIOD
            };
            entry.winner = Some(won);
        }
    }
}

impl Entry {
    fn new(key: Key) -> Entry {
        Entry {
            key,
            scans: 0,
            period: PERIOD,
            winner: None,
            used: 0,
            times: [[0; 2]; TRIAL],
        }
    }
}

/// The march's and the sweep's total times over a trial's scans `[march, sweep]`,
/// leaving out the [`DROP`] scans that took longest by both together (sorting them).
fn totals(times: &mut [[u64; 2]; TRIAL]) -> [u64; 2] {
    times.sort_unstable_by_key(|&[m, s]| m.saturating_add(s));
    let kept = &times[..TRIAL - DROP];
    let total = |k: usize| kept.iter().fold(0u64, |a, t| a.saturating_add(t[k]));
    [total(0), total(1)]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(map: usize) -> Key {
        Key {
            map,
            path: 1,
            beams: 1080,
        }
    }

    /// Runs `scans` scans of `k`, each trial scan taking `sweep_ns` by the sweep and
    /// `march_ns` by the march; returns how many took the sweep outside trials.
    fn run(c: &mut Choice, k: Key, scans: u64, sweep_ns: u64, march_ns: u64) -> u64 {
        let mut swept = 0;
        for _ in 0..scans {
            let p = c.pick(ScanAlgorithm::Auto, k);
            match p.trial {
                Some(t) => c.timed(t, march_ns, sweep_ns),
                None => swept += u64::from(p.sweep),
            }
        }
        swept
    }

    #[test]
    fn the_faster_algorithm_takes_the_scans_after_a_trial() {
        let mut c = Choice::new();
        // the trial: each scan by both, which one first alternating
        for i in 0..TRIAL {
            let p = c.pick(ScanAlgorithm::Auto, key(1));
            assert_eq!(p.trial.map(|t| t.1), Some(i));
            assert_eq!(p.sweep, i % 2 == 0);
            c.timed(p.trial.unwrap(), 20, 10);
        }
        assert_eq!(run(&mut c, key(1), 1000, 10, 20), 1000);
        let mut c = Choice::new();
        assert_eq!(run(&mut c, key(1), 1000 + TRIAL as u64, 20, 10), 0);
        // a tie goes to the sweep
        let mut c = Choice::new();
        assert_eq!(run(&mut c, key(1), 10 + TRIAL as u64, 10, 10), 10);
    }

    #[test]
    fn the_totals_leave_out_the_slowest_scans_and_weigh_the_rest() {
        let k = key(1);
        // The sweep is faster, but two scans were interrupted while it ran: left out.
        let mut c = Choice::new();
        for i in 0..TRIAL {
            let t = c.pick(ScanAlgorithm::Auto, k).trial.unwrap();
            let sweep = if i < DROP { 1_000_000 } else { 10 };
            c.timed(t, 20, sweep);
        }
        assert!(c.pick(ScanAlgorithm::Auto, k).sweep);
        // The march is faster on most scans by a little, the sweep on a few by much: the
        // totals decide (the sweep), not the count of scans each won.
        let mut c = Choice::new();
        for i in 0..TRIAL {
            let t = c.pick(ScanAlgorithm::Auto, k).trial.unwrap();
            let (march, sweep) = if i < 4 { (100, 40) } else { (50, 52) };
            c.timed(t, march, sweep);
        }
        assert!(c.pick(ScanAlgorithm::Auto, k).sweep);
    }

    #[test]
    fn trials_come_again_and_follow_a_change() {
        let mut c = Choice::new();
        let k = key(7);
        assert_eq!(run(&mut c, k, PERIOD, 10, 20), PERIOD - TRIAL as u64);
        // the scene changes: the march is now the faster; the next trial sees it
        assert_eq!(run(&mut c, k, PERIOD - 100, 20, 10), 0);
        assert_eq!(run(&mut c, k, 100, 20, 10), 0);
        // and the one after it
        assert_eq!(run(&mut c, k, PERIOD, 10, 20), PERIOD - TRIAL as u64);
    }

    /// The scans (counted from 0) at which the trials of `scans` scans of `k` start, each
    /// trial scan taking `sweep_ns` by the sweep and `march_ns` by the march.
    fn trial_starts(c: &mut Choice, k: Key, scans: u64, sweep_ns: u64, march_ns: u64) -> Vec<u64> {
        let mut starts = Vec::new();
        for i in 0..scans {
            let p = c.pick(ScanAlgorithm::Auto, k);
            if let Some(t) = p.trial {
                if t.1 == 0 {
                    starts.push(i);
                }
                c.timed(t, march_ns, sweep_ns);
            }
        }
        starts
    }

    #[test]
    fn trials_come_less_often_while_the_same_algorithm_wins_by_far() {
        let (mut c, k) = (Choice::new(), key(3));
        let p = PERIOD;
        // the sweep four times as fast: after the first two trials the period doubles up
        // to the longest
        let starts = trial_starts(&mut c, k, 63 * p, 10, 40);
        assert_eq!(starts, [0, p, 3 * p, 7 * p, 15 * p, 31 * p, 47 * p]);
        assert_eq!(LONGEST, 16 * p);
        // from 63 p (the trial due there) on: a close trial brings the period back
        let starts = trial_starts(&mut c, k, 3 * p, 10, 15);
        assert_eq!(starts, [0, p, 2 * p]);
        // decisive trials again, from a period of p (the next due at 14 p)
        let starts = trial_starts(&mut c, k, 7 * p, 10, 40);
        assert_eq!(starts, [0, 2 * p, 6 * p]);
        // the march as far ahead from here: the trial due then sees the change of winner,
        // and the period starts again from p
        let starts = trial_starts(&mut c, k, 11 * p, 40, 10);
        assert_eq!(starts, [7 * p, 8 * p, 10 * p]);
        assert!(!c.pick(ScanAlgorithm::Auto, k).sweep);
    }

    #[test]
    fn choices_are_kept_per_map_path_and_beams_and_the_oldest_forgotten() {
        let mut c = Choice::new();
        run(&mut c, key(1), TRIAL as u64, 20, 10);
        let other_path = Key { path: 2, ..key(1) };
        let other_beams = Key {
            beams: 100,
            ..key(1)
        };
        run(&mut c, other_path, TRIAL as u64, 10, 20);
        run(&mut c, other_beams, TRIAL as u64, 10, 20);
        assert!(!c.pick(ScanAlgorithm::Auto, key(1)).sweep);
        assert!(c.pick(ScanAlgorithm::Auto, other_path).sweep);
        assert!(c.pick(ScanAlgorithm::Auto, other_beams).sweep);
        // KEYS more maps: key(1) was scanned before them all and is forgotten, so it
        // starts a new trial
        for m in 100..100 + KEYS {
            run(&mut c, key(m), 1, 10, 20);
        }
        let p = c.pick(ScanAlgorithm::Auto, key(1));
        assert_eq!(p.trial.map(|t| t.1), Some(0));
        assert_eq!(c.entries.len(), KEYS);
    }

    #[test]
    fn forced_algorithms_are_not_timed() {
        let mut c = Choice::new();
        for _ in 0..3 {
            let p = c.pick(ScanAlgorithm::Sweep, key(1));
            assert_eq!(
                p,
                Pick {
                    sweep: true,
                    trial: None
                }
            );
            let p = c.pick(ScanAlgorithm::March, key(1));
            assert_eq!(
                p,
                Pick {
                    sweep: false,
                    trial: None
                }
            );
        }
        assert!(c.entries.is_empty());
    }
}
