//! The sweep's per-beam arrays, aligned to cache lines.

/// Doubles laid out from the start of a 64-byte cache line: the AVX code's lanes of four
/// beams (32 bytes, at multiples of four) then never straddle two lines, as half of them
/// may in an allocation that is only 16-byte aligned.
#[derive(Default)]
pub(crate) struct Lines {
    lines: Vec<Line>,
    len: usize,
}

/// One cache line of doubles.
#[derive(Clone, Copy, Default)]
#[repr(C, align(64))]
struct Line([f64; 8]);

impl Lines {
    /// `len` zeros.
    pub(super) fn zeroed(&mut self, len: usize) {
        self.lines.clear();
        self.lines.resize(len.div_ceil(8), Line::default());
        self.len = len;
    }
}

impl std::ops::Deref for Lines {
    type Target = [f64];
    fn deref(&self) -> &[f64] {
        // SAFETY: the lines hold at least `len` doubles back to back (`Line` is eight
        // doubles with no padding), initialised, and borrowed with `self`.
        unsafe { std::slice::from_raw_parts(self.lines.as_ptr().cast::<f64>(), self.len) }
    }
}

impl std::ops::DerefMut for Lines {
    fn deref_mut(&mut self) -> &mut [f64] {
        // SAFETY: as in `deref`, borrowed mutably with `self`.
        unsafe { std::slice::from_raw_parts_mut(self.lines.as_mut_ptr().cast::<f64>(), self.len) }
    }
}

#[cfg(test)]
mod tests {
    use super::Lines;

    #[test]
    fn zeroed_lines_start_a_cache_line_and_hold_len_zeros() {
        let mut l = Lines::default();
        assert!(l.is_empty());
        for len in [1, 7, 8, 9, 1088, 3] {
            l[..].fill(1.0);
            l.zeroed(len);
            assert_eq!(l.len(), len);
            assert!(l.iter().all(|&v| v == 0.0));
            assert_eq!(l.as_ptr() as usize % 64, 0, "{len} doubles");
            l[len - 1] = 2.0;
            assert_eq!(l[len - 1], 2.0);
        }
    }
}
