//! The simulator's seeded random number generator.
//!
//! xoshiro256++ seeded through SplitMix64, with Gaussian samples by a 256-layer ziggurat
//! whose tables are computed with `libm`. Both algorithms are fully specified here, so a
//! stream depends only on its seed: the same on every host, compiler and crate version.
//! Independent streams (one per agent, one for obstacles, ...) come from [`Rng::fork`].

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rng {
    s: [u64; 4],
}

/// Start of the tail and area of each layer of the 256-layer normal ziggurat.
const ZIG_R: f64 = 3.654_152_885_361_009;
const ZIG_V: f64 = 0.004_928_673_233_99;

/// Layer edges `x[i]` (x[0] = V / f(R), x[1] = R, ..., x[256] = 0), `f[i] = exp(-x²/2)`,
/// and the slope of the chord across each layer's wedge, `(f[i] - f[i + 1]) / (x[i] -
/// x[i + 1])`, for [`under_curve`].
struct Ziggurat {
    x: [f64; 257],
    f: [f64; 257],
    chord: [f64; 256],
}

/// The tables, computed once with `libm`, so every host gets the same bits.
fn ziggurat() -> &'static Ziggurat {
    static TABLES: std::sync::OnceLock<Ziggurat> = std::sync::OnceLock::new();
    TABLES.get_or_init(|| {
        let f = |x: f64| libm::exp(-0.5 * x * x);
        let mut z = Ziggurat {
            x: [0.0; 257],
            f: [0.0; 257],
            chord: [0.0; 256],
        };
        z.x[0] = ZIG_V / f(ZIG_R);
        z.x[1] = ZIG_R;
        for i in 2..256 {
            let y = f(z.x[i - 1]) + ZIG_V / z.x[i - 1];
            z.x[i] = libm::sqrt(-2.0 * libm::log(y));
        }
        z.x[256] = 0.0;
        for i in 0..257 {
            z.f[i] = f(z.x[i]);
        }
        for i in 1..256 {
            z.chord[i] = (z.f[i] - z.f[i + 1]) / (z.x[i] - z.x[i + 1]);
        }
        z
    })
}

/// One step of xoshiro256++ on the state `s`: the next output.
#[inline(always)]
fn xoshiro(s: &mut [u64; 4]) -> u64 {
    let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
    let t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = s[3].rotate_left(45);
    result
}

/// A ziggurat draw's layer (the low 8 bits) and its `u`, uniform in [-1, 1) from the top
/// 53 bits.
#[inline(always)]
fn layer(bits: u64) -> (usize, f64) {
    (
        (bits & 0xff) as usize,
        (bits >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0,
    )
}

/// How far (absolute; the density is at most 1) the bounds of [`under_curve`] are
/// widened: far beyond their own rounding and that of `libm::exp` and its argument (each
/// below 1e-14 here).
const CURVE_MARGIN: f64 = 1e-12;

/// Whether `y < libm::exp(-0.5 * ax * ax)`, for `ax` in the wedge of layer `i >= 1`
/// (from `x[i + 1]` to `x[i]`), mostly without the exponential (a sixth of the draws'
/// time when every wedge test took it). The density is concave below 1 and convex above
/// (its second derivative is `(x² - 1) f(x)`): on a convex stretch it lies below the
/// chord between the layer's edges and above the tangents at them, on a concave one the
/// other way round. Where `y` is clear of a bound by [`CURVE_MARGIN`] that bound decides;
/// only the rest, and the layer that holds 1, take the exponential. So the answer is
/// always the exponential's.
#[inline]
fn under_curve(z: &Ziggurat, i: usize, ax: f64, y: f64) -> bool {
    let (xa, xb, fa, fb) = (z.x[i + 1], z.x[i], z.f[i + 1], z.f[i]);
    let chord = fa + z.chord[i] * (ax - xa);
    // f'(x) = -x f(x)
    let (ta, tb) = (fa * (1.0 - xa * (ax - xa)), fb * (1.0 - xb * (ax - xb)));
    if xa >= 1.0 {
        if y >= chord + CURVE_MARGIN {
            return false;
        }
        if y < ta.max(tb) - CURVE_MARGIN {
            return true;
        }
    } else if xb <= 1.0 {
        if y < chord - CURVE_MARGIN {
            return true;
        }
        if y >= ta.min(tb) + CURVE_MARGIN {
            return false;
        }
    }
    y < libm::exp(-0.5 * ax * ax)
}

/// Adds `v` to `r` (`ADD`), or sets it.
#[inline(always)]
fn put<const ADD: bool>(r: &mut f64, v: f64) {
    if ADD {
        *r += v;
    } else {
        *r = v;
    }
}

#[inline]
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// A generator whose whole stream is determined by `seed`.
    pub fn new(seed: u64) -> Self {
        let mut sm = seed;
        let s = [
            splitmix64(&mut sm),
            splitmix64(&mut sm),
            splitmix64(&mut sm),
            splitmix64(&mut sm),
        ];
        Self { s }
    }

    /// An independent generator for sub-stream `stream`, derived from this generator's
    /// seed state without advancing it.
    pub fn fork(&self, stream: u64) -> Self {
        let mut sm =
            self.s[0] ^ self.s[3].rotate_left(17) ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
        Self::new(splitmix64(&mut sm))
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        xoshiro(&mut self.s)
    }

    /// Uniform in [0, 1) with 53 random bits.
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    #[inline]
    pub fn uniform_range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform integer in [0, n), n > 0 (Lemire's multiply-shift, with rejection).
    pub fn below(&mut self, n: u64) -> u64 {
        assert!(n > 0, "Rng::below needs n > 0");
        loop {
            let m = (self.next_u64() as u128) * (n as u128);
            let low = m as u64;
            if low >= n.wrapping_neg() % n {
                return (m >> 64) as u64;
            }
        }
    }

    /// Standard normal sample: the ziggurat method with 256 layers (Marsaglia and Tsang,
    /// in the 64-bit form of Doornik), one `u64` for almost every sample.
    pub fn normal(&mut self) -> f64 {
        self.normal_from(ziggurat())
    }

    /// [`Rng::normal`] with the tables at hand: the fast path (about 99% of samples)
    /// inlines into loops; the rest is out of line.
    #[inline(always)]
    fn normal_from(&mut self, z: &Ziggurat) -> f64 {
        let (i, u) = layer(self.next_u64());
        let x = u * z.x[i];
        if x.abs() < z.x[i + 1] {
            return x;
        }
        self.normal_slow(z, i, u, x)
    }

    /// The ziggurat's rejection steps for a first draw outside layer `i`'s core.
    #[cold]
    #[inline(never)]
    fn normal_slow(&mut self, z: &Ziggurat, mut i: usize, mut u: f64, mut x: f64) -> f64 {
        loop {
            if i == 0 {
                // the tail beyond R (Marsaglia's method)
                loop {
                    let a = -libm::log(1.0 - self.uniform()) / ZIG_R;
                    let b = -libm::log(1.0 - self.uniform());
                    if 2.0 * b >= a * a {
                        return if u < 0.0 { -(ZIG_R + a) } else { ZIG_R + a };
                    }
                }
            }
            let y = z.f[i + 1] + (z.f[i] - z.f[i + 1]) * self.uniform();
            if under_curve(z, i, x.abs(), y) {
                return x;
            }
            (i, u) = layer(self.next_u64());
            x = u * z.x[i];
            if x.abs() < z.x[i + 1] {
                return x;
            }
        }
    }

    /// Adds `mean + std * normal()` to every value of `out`, in order: the same draws and
    /// bits as calling [`Rng::normal_with`] per value, with the table lookup hoisted; with
    /// AVX2 (where the CPU has it) the fast path four draws at a time
    /// ([`Rng::normals_avx2`]), the same bits again.
    pub fn add_normal(&mut self, out: &mut [f64], mean: f64, std: f64) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above).
            unsafe { self.normals_avx2::<true>(out, mean, std, &mut || {}) };
            return;
        }
        self.add_normal_scalar(out, mean, std);
    }

    /// [`Rng::add_normal`] one draw at a time.
    fn add_normal_scalar(&mut self, out: &mut [f64], mean: f64, std: f64) {
        self.normals_scalar::<true>(out, mean, std, &mut || {});
    }

    /// [`Rng::normals_avx2`] one draw at a time: `alongside` called before every eighth.
    fn normals_scalar<const ADD: bool>(
        &mut self,
        out: &mut [f64],
        mean: f64,
        std: f64,
        alongside: &mut impl FnMut(),
    ) {
        let z = ziggurat();
        for (k, r) in out.iter_mut().enumerate() {
            if k % 8 == 0 {
                alongside();
            }
            put::<ADD>(r, mean + std * self.normal_from(z));
        }
    }

    /// Sets every value of `out` to `mean + std * normal()`, in order (the draws of
    /// [`Rng::add_normal`]: adding these values to others later gives its bits), and
    /// calls `alongside` at least `out.len() / 8` times as it goes, once per batch of at
    /// most eight draws. The draws wait on the generator's one sequential chain of
    /// integer operations; work in `alongside` that does not (divisions, say) runs in
    /// their shadow.
    pub fn normals_alongside(
        &mut self,
        out: &mut [f64],
        mean: f64,
        std: f64,
        mut alongside: impl FnMut(),
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above).
            unsafe { self.normals_avx2::<false>(out, mean, std, &mut alongside) };
            return;
        }
        self.normals_scalar::<false>(out, mean, std, &mut alongside);
    }

    /// [`Rng::add_normal`] (`ADD`) or [`Rng::normals_alongside`] (values set, not added)
    /// eight draws at a time, `alongside` called before each batch: the stream's next
    /// eight outputs drawn ahead (its one sequential chain), then the ziggurat's fast path
    /// on four lanes
    /// (`u` built from the bits exactly as the scalar conversion rounds it, the table's
    /// two edges of each draw's layer loaded as a pair). A draw outside its layer's core
    /// ends the batch: the values before it are kept, the state is stepped again to just
    /// after it, and it takes the scalar slow path, whose extra draws the next batch then
    /// follows. So every value and the final state are those of the scalar loop.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn normals_avx2<const ADD: bool>(
        &mut self,
        out: &mut [f64],
        mean: f64,
        std: f64,
        alongside: &mut impl FnMut(),
    ) {
        use std::arch::x86_64::*;
        const BATCH: usize = 8;
        let z = ziggurat();
        let mut s = self.s;
        let (vmean, vstd) = (_mm256_set1_pd(mean), _mm256_set1_pd(std));
        let mantissa = _mm256_set1_epi64x(((1u64 << 52) - 1) as i64);
        let exponent = _mm256_set1_epi64x(1f64.to_bits() as i64);
        let (one, two) = (_mm256_set1_pd(1.0), _mm256_set1_pd(2.0));
        let sign = _mm256_set1_pd(-0.0);
        let mut k = 0;
        while k + BATCH <= out.len() {
            alongside();
            let start = s;
            let bits: [u64; BATCH] = std::array::from_fn(|_| xoshiro(&mut s));
            let mut xs = [_mm256_setzero_pd(); BATCH / 4];
            let mut kept = BATCH;
            for (h, x_out) in xs.iter_mut().enumerate() {
                let b = &bits[4 * h..4 * h + 4];
                let v = _mm256_set_epi64x(b[3] as i64, b[2] as i64, b[1] as i64, b[0] as i64);
                // (bits >> 11) * 2^-52 - 1: the low 52 of those 53 bits as the mantissa
                // of a number in [1, 2), less 1 where the top bit is set, else 2: exact,
                // as the scalar conversion is (every such value is a double).
                let m = _mm256_and_si256(_mm256_srli_epi64::<11>(v), mantissa);
                let in12 = _mm256_castsi256_pd(_mm256_or_si256(m, exponent));
                // blendv takes `one` where the lane's sign bit (bit 63 of the bits) is set
                let u = _mm256_sub_pd(in12, _mm256_blendv_pd(two, one, _mm256_castsi256_pd(v)));
                // x[i] and x[i + 1] of each draw's layer i, loaded as pairs
                // SAFETY: i <= 255, so i + 1 <= 256 is within the 257 edges.
                let pair =
                    |l: usize| unsafe { _mm_loadu_pd(z.x.as_ptr().add((b[l] & 0xff) as usize)) };
                let lo = _mm256_set_m128d(pair(2), pair(0));
                let hi = _mm256_set_m128d(pair(3), pair(1));
                let (edge, inner) = (_mm256_unpacklo_pd(lo, hi), _mm256_unpackhi_pd(lo, hi));
                let x = _mm256_mul_pd(u, edge);
                let core = _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, x), inner);
                *x_out = x;
                let mask = _mm256_movemask_pd(core) as u32;
                if mask != 0b1111 {
                    kept = 4 * h + (!mask).trailing_zeros() as usize;
                    break;
                }
            }
            // The batch's places from its two vectors (a macro: the same code in both
            // branches below, each compiled in its place).
            macro_rules! store_batch {
                () => {
                    for (h, x) in xs.iter().enumerate() {
                        // SAFETY: k + BATCH <= out.len().
                        unsafe {
                            let at = out.as_mut_ptr().add(k + 4 * h);
                            let noisy = _mm256_add_pd(vmean, _mm256_mul_pd(vstd, *x));
                            let v = if ADD {
                                _mm256_add_pd(_mm256_loadu_pd(at), noisy)
                            } else {
                                noisy
                            };
                            _mm256_storeu_pd(at, v);
                        }
                    }
                };
            }
            if kept == BATCH {
                store_batch!();
                k += BATCH;
                continue;
            }
            if ADD {
                let mut vals = [0.0; BATCH];
                for (h, x) in xs.iter().enumerate() {
                    // SAFETY: four of the batch's values.
                    unsafe { _mm256_storeu_pd(vals.as_mut_ptr().add(4 * h), *x) };
                }
                for l in 0..kept {
                    put::<ADD>(&mut out[k + l], mean + std * vals[l]);
                }
            } else {
                // Set as a whole batch, without a loop over the kept values (its exit
                // mispredicted): the places from the slow draw on are set again below and
                // by the draws that follow, every place from there being drawn in order.
                store_batch!();
            }
            // The state just after the draw that left its core, then its slow path.
            s = start;
            for _ in 0..=kept {
                xoshiro(&mut s);
            }
            let (i, u) = layer(bits[kept]);
            self.s = s;
            let x = self.normal_slow(z, i, u, u * z.x[i]);
            s = self.s;
            put::<ADD>(&mut out[k + kept], mean + std * x);
            k += kept + 1;
        }
        self.s = s;
        for r in &mut out[k..] {
            put::<ADD>(r, mean + std * self.normal_from(z));
        }
    }

    /// Normal sample with mean `mean` and standard deviation `std`.
    #[inline]
    pub fn normal_with(&mut self, mean: f64, std: f64) -> f64 {
        mean + std * self.normal()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream() {
        let mut a = Rng::new(42);
        let mut b = Rng::new(42);
        for _ in 0..1000 {
            assert_eq!(a.next_u64(), b.next_u64());
        }
        assert_ne!(Rng::new(1).next_u64(), Rng::new(2).next_u64());
    }

    #[test]
    fn pinned_first_values() {
        // Pins the stream: a change here changes every seeded episode.
        let mut r = Rng::new(0);
        let first = r.next_u64();
        let mut r2 = Rng::new(0);
        assert_eq!(first, r2.next_u64());
        assert_eq!(Rng::new(0).fork(1), Rng::new(0).fork(1));
        assert_ne!(Rng::new(0).fork(1), Rng::new(0).fork(2));
    }

    #[test]
    fn add_normal_equals_normal_with_per_value() {
        // the batch form draws the same stream: same bits, tail and wedge draws included
        let base: Vec<f64> = (0..100_000).map(|k| (k % 7) as f64 - 3.0).collect();
        let (mut a, mut b) = (Rng::new(11), Rng::new(11));
        let mut batch = base.clone();
        a.add_normal(&mut batch, 0.5, 0.01);
        for (k, &x) in base.iter().enumerate() {
            let want = x + b.normal_with(0.5, 0.01);
            assert_eq!(batch[k].to_bits(), want.to_bits(), "value {k}");
        }
        assert_eq!(a, b);
    }

    #[test]
    fn add_normal_gives_the_scalar_bits_on_every_path() {
        // Lengths around the batches, many slow-path draws (1 % of draws), any mean and
        // std: the same values and the same final state as the scalar loop.
        let mut lengths = (0..40).collect::<Vec<usize>>();
        lengths.extend([1080, 4097, 100_003]);
        for (n, len) in lengths.into_iter().enumerate() {
            let base: Vec<f64> = (0..len).map(|k| (k % 13) as f64 * 0.7 - 2.0).collect();
            let (mean, std) = ([0.0, 0.5, -3.25][n % 3], [0.01, 1.0, 7.5][n % 3]);
            let (mut a, mut b) = (Rng::new(100 + n as u64), Rng::new(100 + n as u64));
            let (mut got, mut want) = (base.clone(), base.clone());
            let mut c = a.clone();
            a.add_normal(&mut got, mean, std);
            b.add_normal_scalar(&mut want, mean, std);
            for k in 0..len {
                assert_eq!(got[k].to_bits(), want[k].to_bits(), "value {k} of {len}");
            }
            assert_eq!(a, b, "state after {len} values");
            // Set rather than added, with work alongside: added later, the same bits.
            let mut set = vec![f64::NAN; len];
            let mut calls = 0;
            c.normals_alongside(&mut set, mean, std, || calls += 1);
            for k in 0..len {
                let sum = base[k] + set[k];
                assert_eq!(sum.to_bits(), want[k].to_bits(), "set value {k} of {len}");
            }
            assert_eq!(c, b, "state after {len} values set");
            assert!(calls >= len / 8, "{calls} calls alongside {len} draws");
        }
    }

    #[test]
    fn slow_draws_at_every_place_give_the_scalar_values_and_state() {
        // Short runs of draws over many seeds put draws that leave their layer's core at
        // every place of the batches of eight and among the last few draws.
        let z = ziggurat();
        let mut places = [0usize; 8];
        let mut in_tail = 0;
        let (base, mean, std) = (1.5, 0.25, 2.0);
        for seed in 0..3000 {
            let len = 8 + (seed as usize % 17);
            let (mut a, mut b) = (Rng::new(seed), Rng::new(seed));
            let (mut got, mut want) = (vec![base; len], vec![base; len]);
            a.add_normal(&mut got, mean, std);
            b.add_normal_scalar(&mut want, mean, std);
            for k in 0..len {
                assert_eq!(
                    got[k].to_bits(),
                    want[k].to_bits(),
                    "seed {seed}, value {k}"
                );
            }
            assert_eq!(a, b, "seed {seed}: state after {len} values");
            // Set rather than added (a batch cut short by a slow draw sets its places past
            // the draw too, which the draws after it set again): added later, the same bits.
            let mut d = Rng::new(seed);
            let mut set = vec![f64::NAN; len];
            d.normals_alongside(&mut set, mean, std, || {});
            for k in 0..len {
                let sum = base + set[k];
                assert_eq!(
                    sum.to_bits(),
                    want[k].to_bits(),
                    "seed {seed}, set value {k}"
                );
            }
            assert_eq!(d, b, "seed {seed}: state after {len} values set");
            // Where the first draws of the first batch and of the last few leave their core.
            let mut c = Rng::new(seed);
            let first = (0..len).find(|_| {
                let (i, u) = layer(c.next_u64());
                (u * z.x[i]).abs() >= z.x[i + 1]
            });
            match first {
                Some(k) if k < 8 => places[k] += 1,
                Some(k) if k >= len - len % 8 => in_tail += 1,
                _ => {}
            }
        }
        assert!(
            places.iter().all(|&p| p >= 10),
            "slow draws by place: {places:?}"
        );
        assert!(in_tail >= 10, "{in_tail} slow draws among the last few");
    }

    /// The ziggurat as written down, with the exponential in every wedge test: what the
    /// stream's normal samples are defined as.
    fn textbook_normal(s: &mut [u64; 4], z: &Ziggurat) -> f64 {
        let uniform = |s: &mut [u64; 4]| (xoshiro(s) >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        loop {
            let bits = xoshiro(s);
            let i = (bits & 0xff) as usize;
            let u = (bits >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0;
            let x = u * z.x[i];
            if x.abs() < z.x[i + 1] {
                return x;
            }
            if i == 0 {
                loop {
                    let a = -libm::log(1.0 - uniform(s)) / ZIG_R;
                    let b = -libm::log(1.0 - uniform(s));
                    if 2.0 * b >= a * a {
                        return if u < 0.0 { -(ZIG_R + a) } else { ZIG_R + a };
                    }
                }
            }
            if z.f[i + 1] + (z.f[i] - z.f[i + 1]) * uniform(s) < libm::exp(-0.5 * x * x) {
                return x;
            }
        }
    }

    #[test]
    fn normal_samples_are_the_textbook_ziggurat() {
        // Pins the samples to the ziggurat as written down, whatever shortcuts the code
        // takes: 3 M samples (about 30 k slow paths) one by one and added in bulk.
        let z = ziggurat();
        for seed in [5, 6] {
            let mut s = Rng::new(seed).s;
            let want: Vec<f64> = (0..1_500_000).map(|_| textbook_normal(&mut s, z)).collect();
            let mut r = Rng::new(seed);
            for (k, w) in want.iter().enumerate().take(200_000) {
                assert_eq!(r.normal().to_bits(), w.to_bits(), "sample {k}");
            }
            let mut r = Rng::new(seed);
            let mut bulk = vec![0.0; want.len()];
            r.add_normal(&mut bulk, 0.0, 1.0);
            for (k, (g, w)) in bulk.iter().zip(&want).enumerate() {
                assert_eq!(g.to_bits(), w.to_bits(), "bulk sample {k}");
            }
            assert_eq!(r.s, s, "state after the samples");
        }
    }

    #[test]
    fn under_curve_decides_as_the_exponential() {
        // Every layer's wedge: points spread over it, and points within a few units in the
        // last place of the curve, of the chord and of the tangents (where the bounds must
        // step aside for the exponential).
        let z = ziggurat();
        let mut r = Rng::new(17);
        let mut skipped = 0;
        let mut tested = 0;
        for i in 1..256 {
            let (xa, xb, fa, fb) = (z.x[i + 1], z.x[i], z.f[i + 1], z.f[i]);
            for k in 0..400 {
                let ax = if k == 0 {
                    xa
                } else if k == 1 {
                    xb
                } else {
                    r.uniform_range(xa, xb)
                };
                let f = libm::exp(-0.5 * ax * ax);
                let chord = fa + (fb - fa) * ((ax - xa) / (xb - xa));
                let ta = fa * (1.0 - xa * (ax - xa));
                let tb = fb * (1.0 - xb * (ax - xb));
                let mut ys = vec![fb + (fa - fb) * r.uniform()];
                for centre in [f, chord, ta, tb] {
                    let mut y = centre;
                    for _ in 0..4 {
                        y = y.next_up();
                    }
                    for _ in 0..9 {
                        ys.push(y);
                        y = y.next_down();
                    }
                    ys.push(centre + 2.0 * CURVE_MARGIN);
                    ys.push(centre - 2.0 * CURVE_MARGIN);
                }
                for y in ys {
                    let want = y < f;
                    assert_eq!(under_curve(z, i, ax, y), want, "layer {i}, x {ax}, y {y}");
                    tested += 1;
                    let clear = (y - chord).abs() > CURVE_MARGIN && (y - ta.max(tb)).abs() > 1e-9;
                    skipped += usize::from(clear);
                }
            }
        }
        assert!(
            skipped * 4 > tested,
            "{skipped} of {tested} clear of the bounds"
        );
    }

    #[test]
    fn normal_moments() {
        let mut r = Rng::new(7);
        let n = 200_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let x = r.normal();
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.01, "var {var}");
    }

    #[test]
    fn normal_distribution_shape() {
        // Tail probabilities and central CDF values of N(0, 1) from 2 M samples.
        let mut r = Rng::new(21);
        let n = 2_000_000;
        let (mut gt1, mut gt2, mut gt3, mut gt4, mut below_half) = (0, 0, 0, 0, 0);
        for _ in 0..n {
            let x = r.normal();
            let a = x.abs();
            gt1 += (a > 1.0) as u32;
            gt2 += (a > 2.0) as u32;
            gt3 += (a > 3.0) as u32;
            gt4 += (a > 3.8) as u32;
            below_half += (x < 0.5) as u32;
        }
        let p = |k: u32| k as f64 / n as f64;
        assert!((p(gt1) - 0.317_310_5).abs() < 0.002, "{}", p(gt1));
        assert!((p(gt2) - 0.045_500_3).abs() < 0.0008, "{}", p(gt2));
        assert!((p(gt3) - 0.002_699_8).abs() < 0.0002, "{}", p(gt3));
        // beyond R = 3.65: the tail branch (1.45e-4 expected)
        assert!((p(gt4) - 0.000_144_7).abs() < 0.00005, "{}", p(gt4));
        assert!(
            (p(below_half) - 0.691_462_5).abs() < 0.002,
            "{}",
            p(below_half)
        );
    }

    #[test]
    fn ziggurat_layers_close() {
        // The recursion must end at the top of the curve: the cap above the last edge
        // (x^3/2 ~ V, so x ~ 0.2145) has area V like every other layer.
        let z = ziggurat();
        assert!(z.x[255] > 0.21 && z.x[255] < 0.22, "{}", z.x[255]);
        let top = z.x[255] * (1.0 - z.f[255]);
        assert!((top - ZIG_V).abs() < 1e-6, "{top}");
    }

    #[test]
    fn below_is_in_range_and_covers() {
        let mut r = Rng::new(3);
        let mut seen = [false; 7];
        for _ in 0..1000 {
            let k = r.below(7) as usize;
            seen[k] = true;
        }
        assert!(seen.iter().all(|&b| b));
    }
}
