//! Symmetric eigendecomposition by the cyclic Jacobi method (Golub & Van Loan,
//! "Matrix Computations", section 8.5).
//!
//! CMA-ES needs C = B diag(d) B^T for matrices of modest size (tens of dimensions),
//! decomposed only every few generations. Jacobi is short, unconditionally stable for
//! symmetric matrices, accurate for small eigenvalues, and uses only `+ - * / sqrt`, so
//! its result is the same on every IEEE-754 host.

/// Eigen-pairs of a symmetric `n x n` matrix stored row-major.
///
/// Returns `(eigenvalues, eigenvectors)` with eigenvalues ascending; column `k` of the
/// row-major `eigenvectors` matrix (`v[i * n + k]`) is the unit eigenvector of value `k`.
pub(crate) fn symmetric_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    debug_assert_eq!(a.len(), n * n);
    let mut m = a.to_vec();
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    const MAX_SWEEPS: usize = 100;
    for _ in 0..MAX_SWEEPS {
        let mut off = 0.0;
        let mut diag = 0.0;
        for i in 0..n {
            diag += m[i * n + i] * m[i * n + i];
            for j in (i + 1)..n {
                off += m[i * n + j] * m[i * n + j];
            }
        }
        // Converged when the off-diagonal mass is negligible against the diagonal.
        if off <= 1e-30 * diag || off == 0.0 {
            break;
        }
        for p in 0..n {
            for q in (p + 1)..n {
                let apq = m[p * n + q];
                if apq == 0.0 {
                    continue;
                }
                let app = m[p * n + p];
                let aqq = m[q * n + q];
                // Rotation angle that zeroes m[p][q]: t = tan(phi), the smaller root of
                // t^2 + 2 theta t - 1 = 0.
                let theta = (aqq - app) / (2.0 * apq);
                let t = if theta.is_infinite() {
                    0.5 / theta
                } else {
                    let sign = if theta >= 0.0 { 1.0 } else { -1.0 };
                    sign / (theta.abs() + (theta * theta + 1.0).sqrt())
                };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                // m <- J^T m J, touching rows/columns p and q only.
                for k in 0..n {
                    let mkp = m[k * n + p];
                    let mkq = m[k * n + q];
                    m[k * n + p] = c * mkp - s * mkq;
                    m[k * n + q] = s * mkp + c * mkq;
                }
                for k in 0..n {
                    let mpk = m[p * n + k];
                    let mqk = m[q * n + k];
                    m[p * n + k] = c * mpk - s * mqk;
                    m[q * n + k] = s * mpk + c * mqk;
                }
                m[p * n + q] = 0.0;
                m[q * n + p] = 0.0;
                for k in 0..n {
                    let vkp = v[k * n + p];
                    let vkq = v[k * n + q];
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| m[i * n + i].total_cmp(&m[j * n + j]).then(i.cmp(&j)));
    let values: Vec<f64> = order.iter().map(|&i| m[i * n + i]).collect();
    let mut vectors = vec![0.0; n * n];
    for (col, &src) in order.iter().enumerate() {
        for row in 0..n {
            vectors[row * n + col] = v[row * n + src];
        }
    }
    (values, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reconstructs_a_symmetric_matrix() {
        let n = 5;
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                let x = 1.0 / (1.0 + i as f64 + j as f64) + if i == j { 2.0 } else { 0.0 };
                a[i * n + j] = x;
            }
        }
        let (d, b) = symmetric_eigen(&a, n);
        assert!(d.windows(2).all(|w| w[0] <= w[1]));
        for i in 0..n {
            for j in 0..n {
                let mut r = 0.0;
                let mut orth = 0.0;
                for k in 0..n {
                    r += b[i * n + k] * d[k] * b[j * n + k];
                    orth += b[k * n + i] * b[k * n + j];
                }
                assert!((r - a[i * n + j]).abs() < 1e-12, "A[{i}][{j}]");
                let id = if i == j { 1.0 } else { 0.0 };
                assert!((orth - id).abs() < 1e-12, "B^T B [{i}][{j}]");
            }
        }
    }

    #[test]
    fn diagonal_matrix_is_its_own_decomposition() {
        let a = [3.0, 0.0, 0.0, 1.0];
        let (d, _) = symmetric_eigen(&a, 2);
        assert_eq!(d, vec![1.0, 3.0]);
    }
}
