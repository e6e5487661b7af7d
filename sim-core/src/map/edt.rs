//! Exact squared Euclidean distance transform (Felzenszwalb & Huttenlocher, "Distance
//! Transforms of Sampled Functions", 2012): a column pass then a row pass of the 1D lower
//! envelope of parabolas, O(N) overall, in exact integer arithmetic.

const INF: u64 = u64::MAX;

/// For each cell (row-major, `w` x `h`) the squared distance, in cells, from its centre to
/// the nearest occupied cell centre; `u64::MAX` when no cell is occupied.
pub(super) fn squared_edt(w: usize, h: usize, occupied: &[bool]) -> Vec<u64> {
    // Column pass: squared distance to the nearest occupied cell in the same column.
    let mut g = vec![INF; w * h];
    for c in 0..w {
        let mut last: Option<usize> = None;
        for r in 0..h {
            if occupied[r * w + c] {
                last = Some(r);
            }
            if let Some(l) = last {
                let d = (r - l) as u64;
                g[r * w + c] = d * d;
            }
        }
        let mut next: Option<usize> = None;
        for r in (0..h).rev() {
            if occupied[r * w + c] {
                next = Some(r);
            }
            if let Some(n) = next {
                let d = (n - r) as u64;
                let i = r * w + c;
                g[i] = g[i].min(d * d);
            }
        }
    }
    // Row pass: lower envelope of the parabolas (c - q)^2 + g(q).
    let mut out = vec![INF; w * h];
    let mut v = vec![0usize; w];
    let mut z = vec![0f64; w + 1];
    for r in 0..h {
        let row = &g[r * w..(r + 1) * w];
        let f = |q: usize| row[q];
        let mut k: isize = -1;
        for q in 0..w {
            if f(q) == INF {
                continue;
            }
            let fq = f(q) as f64 + (q * q) as f64;
            loop {
                if k < 0 {
                    k = 0;
                    v[0] = q;
                    z[0] = f64::NEG_INFINITY;
                    z[1] = f64::INFINITY;
                    break;
                }
                let p = v[k as usize];
                let s = (fq - (f(p) as f64 + (p * p) as f64)) / (2.0 * (q - p) as f64);
                if s <= z[k as usize] {
                    k -= 1;
                    continue;
                }
                k += 1;
                v[k as usize] = q;
                z[k as usize] = s;
                z[k as usize + 1] = f64::INFINITY;
                break;
            }
        }
        if k < 0 {
            continue;
        }
        let mut j = 0usize;
        for c in 0..w {
            while z[j + 1] < c as f64 {
                j += 1;
            }
            let p = v[j];
            let d = c.abs_diff(p) as u64;
            out[r * w + c] = d * d + f(p);
        }
    }
    out
}
