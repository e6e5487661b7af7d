//! The sweep's per-beam set-up: each beam's direction in the grid frame, its inverses and
//! its first range, with the scan's noise drawn alongside where asked.

use std::ops::Range;

#[cfg(target_arch = "x86_64")]
use super::avx;
use crate::rng::Rng;

/// The per-beam arrays [`super::Sweep::prepare`] fills.
pub(super) struct Beams<'a> {
    pub(super) beam_cos: &'a [f64],
    pub(super) beam_sin: &'a [f64],
    pub(super) dx: &'a mut [f64],
    pub(super) dy: &'a mut [f64],
    pub(super) inv_dx: &'a mut [f64],
    pub(super) inv_dy: &'a mut [f64],
    pub(super) best: &'a mut [f64],
}

impl Beams<'_> {
    /// Fills beam j's direction, its inverses and its first `best` (`start(j)`), for `j`
    /// in `range`.
    #[inline(always)]
    fn prepare(&mut self, gc: f64, gs: f64, start: &impl Fn(usize) -> f64, range: Range<usize>) {
        let (beam_cos, beam_sin) = (&self.beam_cos[range.clone()], &self.beam_sin[range.clone()]);
        let (dxs, dys) = (&mut self.dx[range.clone()], &mut self.dy[range.clone()]);
        let (inv_dx, inv_dy) = (
            &mut self.inv_dx[range.clone()],
            &mut self.inv_dy[range.clone()],
        );
        let best = &mut self.best[range.clone()];
        for j in 0..best.len() {
            let (bc, bs) = (beam_cos[j], beam_sin[j]);
            // As the march prepares them: -0.0 would give an inverse of -infinity.
            let dx = gc * bc - gs * bs;
            let dy = gs * bc + gc * bs;
            let dx = if dx == 0.0 { 0.0 } else { dx };
            let dy = if dy == 0.0 { 0.0 } else { dy };
            dxs[j] = dx;
            dys[j] = dy;
            inv_dx[j] = 1.0 / dx;
            inv_dy[j] = 1.0 / dy;
            best[j] = start(range.start + j);
        }
    }

    /// [`Beams::prepare`] for every beam, with the scan's noise drawn alongside if asked
    /// (`noise`: the generator, the standard deviation and where the values go).
    /// `start(j)` is `limits`' `limit[j] * inv_res + 1.0` where given, else the same for
    /// every beam.
    #[inline(always)]
    pub(super) fn fill(
        mut self,
        gc: f64,
        gs: f64,
        start: impl Fn(usize) -> f64,
        limits: Option<(&[f64], f64)>,
        noise: Option<Noise<'_>>,
    ) {
        let n = self.best.len();
        #[cfg(target_arch = "x86_64")]
        if let Some((rng, std, values)) = noise {
            // The draws wait on their generator's chain of integer operations, the set-up
            // on its two divisions a beam: taken together, each runs in the other's
            // shadow. `ALONGSIDE` beams per batch of draws, by `avx::prepare8`
            // (the same bits).
            let blocks = n / ALONGSIDE;
            let beams = avx::BeamPtrs {
                bc: self.beam_cos.as_ptr(),
                bs: self.beam_sin.as_ptr(),
                dx: self.dx.as_mut_ptr(),
                dy: self.dy.as_mut_ptr(),
                inv_dx: self.inv_dx.as_mut_ptr(),
                inv_dy: self.inv_dy.as_mut_ptr(),
                best: self.best.as_mut_ptr(),
                limit: limits.map_or(std::ptr::null(), |(l, _)| l.as_ptr()),
                inv_res: limits.map_or(0.0, |(_, r)| r),
                start: start(0),
            };
            let mut blocks_done = 0;
            let block = &mut blocks_done;
            // (Inlined into the draws' loop, which is compiled for AVX2: a closure of its
            // own would be compiled without the features of its caller.)
            rng.normals_alongside(
                values,
                0.0,
                std,
                #[inline(always)]
                move || {
                    if *block < blocks {
                        let j = *block * ALONGSIDE;
                        // SAFETY: only called with AVX (see `Sweep::prepare`'s callers); beams
                        // j..j + ALONGSIDE (eight) lie within the n beams every array holds.
                        unsafe {
                            avx::prepare8(gc, gs, &beams, j);
                        }
                        *block += 1;
                    }
                },
            );
            let done = blocks_done * ALONGSIDE;
            self.prepare(gc, gs, &start, done..n);
            return;
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = limits;
            assert!(
                noise.is_none(),
                "the noise is drawn alongside with AVX only"
            );
        }
        self.prepare(gc, gs, &start, 0..n);
    }
}

/// Beams set up per batch of the noise's draws (see [`Beams::fill`]): one `avx::prepare8`,
/// which sets up eight (checked here: its memory safety rests on it).
const ALONGSIDE: usize = 8;
const _: () = assert!(ALONGSIDE == 8, "one avx::prepare8 sets up eight beams");

/// The scan's noise as [`super::Sweep::prepare`] draws it: the generator, the standard deviation
/// and the values, one per beam.
pub(crate) type Noise<'a> = (&'a mut Rng, f64, &'a mut [f64]);
