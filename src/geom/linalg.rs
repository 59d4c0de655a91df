//! Small dense linear algebra in f64 for the CPU-side fits: Cholesky factorisation and
//! triangular solves, non-negative least squares, modified Gram-Schmidt and a Jacobi
//! eigen-solver. Matrices are row-major slices, `n` x `n` unless said otherwise; the sizes
//! are those of an SG basis or a fit (up to a few thousand), so the methods are the plain
//! textbook ones, written for a fixed and reproducible order of the floating-point
//! operations (the SRBF fits and caches depend on it).

/// Dot product in four partial sums, so that it vectorises (a single running sum would
/// have to keep the order of the additions).
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    acc[0] + acc[1] + acc[2] + acc[3] + tail
}

/// In-place Cholesky factor (lower, row-major) of the symmetric positive definite `m`
/// (n x n); the upper triangle is cleared. `None` if a pivot is not positive.
pub fn cholesky(m: &mut [f64], n: usize) -> Option<()> {
    for j in 0..n {
        let mut d = m[j * n + j];
        for k in 0..j {
            d -= m[j * n + k] * m[j * n + k];
        }
        if d.is_nan() || d <= 0.0 || d.is_infinite() {
            return None;
        }
        let d = d.sqrt();
        m[j * n + j] = d;
        for i in j + 1..n {
            let mut s = m[i * n + j];
            for k in 0..j {
                s -= m[i * n + k] * m[j * n + k];
            }
            m[i * n + j] = s / d;
        }
        for i in 0..j {
            m[i * n + j] = 0.0;
        }
    }
    Some(())
}

/// Solves L L^T x = b for the factor from [`cholesky`].
pub fn cholesky_solve(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[k * n + i] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
}

/// Solves the SPD system `m x = b` (n x n), adding a growing ridge if the factorisation
/// fails. `None` if even the largest ridge fails (non-finite input).
fn solve_spd(m: &[f64], n: usize, b: &[f64]) -> Option<Vec<f64>> {
    let scale = (0..n)
        .map(|i| m[i * n + i])
        .fold(0.0f64, f64::max)
        .max(1e-300);
    let mut ridge = 1e-13 * scale;
    for _ in 0..10 {
        let mut l = m.to_vec();
        for i in 0..n {
            l[i * n + i] += ridge;
        }
        if cholesky(&mut l, n).is_some() {
            let mut x = b.to_vec();
            cholesky_solve(&l, n, &mut x);
            if x.iter().all(|v| v.is_finite()) {
                return Some(x);
            }
        }
        ridge *= 100.0;
    }
    None
}

/// Non-negative least squares in normal-equation form: min 1/2 x^T G x - b^T x, x >= 0
/// (Lawson-Hanson active set). `g` is n x n symmetric positive semi-definite.
pub fn nnls(g: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    let mut x = vec![0.0f64; n];
    let mut passive = vec![false; n];
    let bmax = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if bmax == 0.0 {
        return x;
    }
    let tol = 1e-12 * bmax;
    for _ in 0..3 * n + 10 {
        let grad: Vec<f64> = (0..n)
            .map(|i| b[i] - dot(&g[i * n..(i + 1) * n], &x))
            .collect();
        let Some(enter) = (0..n)
            .filter(|&i| !passive[i] && grad[i] > tol)
            .max_by(|&i, &k| grad[i].total_cmp(&grad[k]))
        else {
            break;
        };
        passive[enter] = true;
        for _ in 0..n + 1 {
            let idx: Vec<usize> = (0..n).filter(|&i| passive[i]).collect();
            if idx.is_empty() {
                break;
            }
            let m = idx.len();
            let sub: Vec<f64> = idx
                .iter()
                .flat_map(|&i| idx.iter().map(move |&k| g[i * n + k]))
                .collect();
            let rhs: Vec<f64> = idx.iter().map(|&i| b[i]).collect();
            let Some(z) = solve_spd(&sub, m, &rhs) else {
                passive[enter] = false;
                break;
            };
            if z.iter().all(|v| *v > 0.0) {
                for (&i, v) in idx.iter().zip(&z) {
                    x[i] = *v;
                }
                break;
            }
            // Step from x towards z until the first passive variable hits zero; that one
            // (and any other at or below zero) leaves the passive set.
            let mut alpha = 1.0f64;
            let mut blocking = None;
            for (&i, &zi) in idx.iter().zip(&z) {
                if zi <= 0.0 {
                    let denom = x[i] - zi;
                    let a = if denom > 0.0 { x[i] / denom } else { 0.0 };
                    if a < alpha || blocking.is_none() {
                        alpha = alpha.min(a);
                        blocking = Some(i);
                    }
                }
            }
            for (&i, &zi) in idx.iter().zip(&z) {
                x[i] += alpha * (zi - x[i]);
                if x[i] <= 0.0 {
                    passive[i] = false;
                }
            }
            if let Some(k) = blocking {
                passive[k] = false;
            }
            for i in 0..n {
                if !passive[i] {
                    x[i] = 0.0;
                }
            }
        }
    }
    x
}

/// x with L^T x = b, L lower triangular (row-major, k x k).
pub fn solve_upper_transposed(l: &[f64], k: usize, b: &[f32]) -> Vec<f64> {
    let mut x = vec![0.0f64; k];
    for i in (0..k).rev() {
        let mut s = b[i] as f64;
        for (j, xj) in x.iter().enumerate().skip(i + 1) {
            s -= l[j * k + i] * xj;
        }
        x[i] = s / l[i * k + i];
    }
    x
}

/// Modified Gram-Schmidt on the rows of `q` (dimension `k`, at most `k` rows); a row that
/// vanishes is replaced by a unit vector orthogonal to the others.
pub fn orthonormalise(q: &mut [f64], k: usize) {
    let rows = q.len() / k;
    for i in 0..rows {
        for attempt in 0..=k {
            for j in 0..i {
                let (head, tail) = q.split_at_mut(i * k);
                let qj = &head[j * k..(j + 1) * k];
                let qi = &mut tail[..k];
                let d: f64 = qi.iter().zip(qj).map(|(a, b)| a * b).sum();
                qi.iter_mut().zip(qj).for_each(|(a, b)| *a -= d * b);
            }
            let qi = &mut q[i * k..(i + 1) * k];
            let norm = qi.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm > 1e-12 {
                qi.iter_mut().for_each(|x| *x /= norm);
                break;
            }
            // Degenerate: try the next coordinate axis.
            qi.iter_mut().for_each(|x| *x = 0.0);
            qi[(i + attempt) % k] = 1.0;
        }
    }
}

/// The p leading eigenpairs of a symmetric positive semi-definite operator on R^n by block
/// subspace iteration and a Rayleigh-Ritz step: `apply` maps p rows of length n (row-major)
/// to the operator applied to each. The block starts from the rows of `init` (at most p;
/// e.g. a previous solution) completed by random rows (`seed`), and iterates until the
/// captured trace changes by at most `tol` or `max_steps` steps. Returns the p Ritz values in
/// decreasing order and their vectors as p rows of length n, each with its largest entry
/// positive (a deterministic sign). For such an operator the Ritz values never fall from one
/// step to the next, so the result captures at least what `init` did.
pub fn subspace_eigen(
    n: usize,
    p: usize,
    init: &[f64],
    seed: u64,
    max_steps: usize,
    tol: f64,
    apply: impl Fn(&[f64]) -> Vec<f64>,
) -> (Vec<f64>, Vec<f64>) {
    let mut rng = crate::geom::Rng::new(seed);
    let mut x: Vec<f64> = (0..p * n).map(|_| rng.f32() as f64 - 0.5).collect();
    let given = (init.len() / n).min(p);
    x[..given * n].copy_from_slice(&init[..given * n]);
    orthonormalise(&mut x, n);
    let mut last = f64::NEG_INFINITY;
    for _ in 0..max_steps {
        let mut y = apply(&x);
        let captured: f64 = x.iter().zip(&y).map(|(u, v)| u * v).sum();
        orthonormalise(&mut y, n);
        x = y;
        if (captured - last).abs() <= tol {
            break;
        }
        last = captured;
    }
    let y = apply(&x);
    let mut t = vec![0f64; p * p];
    for i in 0..p {
        for j in 0..p {
            t[i * p + j] = dot(&x[i * n..(i + 1) * n], &y[j * n..(j + 1) * n]);
        }
    }
    let (vals, vecs) = jacobi_eigen(t, p);
    let mut order: Vec<usize> = (0..p).collect();
    order.sort_by(|&i, &j| vals[j].total_cmp(&vals[i]).then(i.cmp(&j)));
    let mut out = vec![0f64; p * n];
    for (c, &e) in order.iter().enumerate() {
        let row = &mut out[c * n..(c + 1) * n];
        for i in 0..p {
            let s = vecs[i * p + e];
            for (o, xv) in row.iter_mut().zip(&x[i * n..(i + 1) * n]) {
                *o += s * xv;
            }
        }
        let big = row
            .iter()
            .cloned()
            .fold(0f64, |m, v| if v.abs() > m.abs() { v } else { m });
        if big < 0.0 {
            row.iter_mut().for_each(|v| *v = -*v);
        }
    }
    (order.iter().map(|&i| vals[i]).collect(), out)
}

/// Eigen-decomposition of a symmetric n x n matrix by cyclic Jacobi rotations: (eigenvalues,
/// eigenvectors as columns, row-major).
pub fn jacobi_eigen(mut a: Vec<f64>, n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut v = vec![0f64; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    for _sweep in 0..64 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i * n + j].powi(2))
            .sum();
        let scale: f64 = (0..n).map(|i| a[i * n + i].powi(2)).sum::<f64>();
        if off <= 1e-24 * scale.max(1e-300) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = a[p * n + q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
                let t = theta.signum().max(0.0) * 2.0 - 1.0;
                let t = t / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for r in 0..n {
                    let (arp, arq) = (a[r * n + p], a[r * n + q]);
                    a[r * n + p] = c * arp - s * arq;
                    a[r * n + q] = s * arp + c * arq;
                }
                for r in 0..n {
                    let (apr, aqr) = (a[p * n + r], a[q * n + r]);
                    a[p * n + r] = c * apr - s * aqr;
                    a[q * n + r] = s * apr + c * aqr;
                }
                for r in 0..n {
                    let (vrp, vrq) = (v[r * n + p], v[r * n + q]);
                    v[r * n + p] = c * vrp - s * vrq;
                    v[r * n + q] = s * vrp + c * vrq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i * n + i]).collect(), v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Rng;

    /// A = L L^T with a small integer L: the factor is exact in floating point.
    const L: [f64; 9] = [2.0, 0.0, 0.0, 6.0, 1.0, 0.0, -8.0, 5.0, 3.0];
    const A: [f64; 9] = [4.0, 12.0, -16.0, 12.0, 37.0, -43.0, -16.0, -43.0, 98.0];

    #[test]
    fn cholesky_of_a_known_spd_matrix() {
        let mut m = A;
        cholesky(&mut m, 3).unwrap();
        // Lower triangle the factor, upper triangle cleared.
        assert_eq!(m, L);
        // A x = b for x = (1, 2, 3).
        let mut b = [-20.0, -43.0, 192.0];
        cholesky_solve(&m, 3, &mut b);
        for (x, want) in b.iter().zip([1.0, 2.0, 3.0]) {
            assert!((x - want).abs() < 1e-12, "{b:?}");
        }
        // L^T x = b for x = (1, -1, 2).
        let x = solve_upper_transposed(&m, 3, &[-20.0, 9.0, 6.0]);
        assert_eq!(x, [1.0, -1.0, 2.0]);
    }

    #[test]
    fn cholesky_refuses_matrices_that_are_not_positive_definite() {
        // Indefinite (eigenvalues 3 and -1), semi-definite (a zero pivot), non-finite.
        for (mut m, n) in [
            (vec![1.0, 2.0, 2.0, 1.0], 2),
            (vec![1.0, 1.0, 1.0, 1.0], 2),
            (vec![f64::NAN], 1),
            (vec![f64::INFINITY], 1),
        ] {
            assert!(cholesky(&mut m, n).is_none(), "{m:?}");
        }
    }

    #[test]
    fn dot_of_every_remainder_length() {
        for n in 0..11 {
            let a: Vec<f64> = (1..=n).map(|i| i as f64).collect();
            // sum i^2 = n (n + 1) (2n + 1) / 6, exact in f64 at these sizes.
            assert_eq!(dot(&a, &a), (n * (n + 1) * (2 * n + 1) / 6) as f64, "n {n}");
        }
    }

    /// min |A x - y|^2, x >= 0, as NNLS on (A^T A, A^T y), A = [a1 a2 a3] with a2 = e1,
    /// a3 = e2 and a1 = (0.8, 0.8, 0.1), y = (1, 1, -0.05). The unconstrained optimum is
    /// (-0.5, 1.4, 1.4); the constrained one (0, 1, 1). Lawson-Hanson takes a1 first (the
    /// largest gradient), a2 and a3 join, then a1 must leave: the removal step is exercised.
    #[test]
    fn nnls_drops_a_variable_that_entered_first() {
        let a = [[0.8, 0.8, 0.1], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let y = [1.0, 1.0, -0.05];
        let dot3 = |u: &[f64; 3], v: &[f64; 3]| u.iter().zip(v).map(|(p, q)| p * q).sum::<f64>();
        let g: Vec<f64> = (0..9).map(|i| dot3(&a[i / 3], &a[i % 3])).collect();
        let b: Vec<f64> = a.iter().map(|c| dot3(c, &y)).collect();
        let x = nnls(&g, &b, 3);
        assert_eq!(x[0], 0.0, "{x:?}");
        assert!(
            (x[1] - 1.0).abs() < 1e-12 && (x[2] - 1.0).abs() < 1e-12,
            "{x:?}"
        );
    }

    #[test]
    fn nnls_matches_a_known_solution() {
        // G = A^T A with A = I + small; b chosen so the unconstrained optimum has a
        // negative entry: the NNLS answer clamps it and re-solves.
        let g = [4.0, 1.0, 0.0, 1.0, 3.0, 1.0, 0.0, 1.0, 2.0];
        let x = nnls(&g, &[1.0, 2.0, -3.0], 3);
        // With x2 = 0: [[4,1],[1,3]] x = [1,2] -> x = (1/11, 7/11).
        assert!((x[0] - 1.0 / 11.0).abs() < 1e-12 && (x[1] - 7.0 / 11.0).abs() < 1e-12);
        assert_eq!(x[2], 0.0);
    }

    #[test]
    fn nnls_interior_and_empty_active_sets() {
        // A positive unconstrained optimum is the answer: G^-1 b = (1, 2, 3) for G = A.
        let rhs: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|j| A[i * 3 + j] * [1.0, 2.0, 3.0][j]).sum())
            .collect();
        let x = nnls(&A, &rhs, 3);
        for (v, want) in x.iter().zip([1.0, 2.0, 3.0]) {
            assert!((v - want).abs() < 1e-9, "{x:?}");
        }
        // b <= 0: no variable can help, x = 0.
        assert_eq!(nnls(&[2.0, 0.5, 0.5, 1.0], &[-1.0, 0.0], 2), [0.0, 0.0]);
    }

    /// Q diag(5, 2, -1) Q^T with Q = [[1, 2, 2], [2, 1, -2], [2, -2, 1]] / 3 (orthogonal).
    #[test]
    fn jacobi_finds_a_known_spectrum() {
        let q = [1.0, 2.0, 2.0, 2.0, 1.0, -2.0, 2.0, -2.0, 1.0].map(|x: f64| x / 3.0);
        let lambda = [5.0, 2.0, -1.0];
        let a: Vec<f64> = (0..9)
            .map(|x| {
                (0..3)
                    .map(|k| q[(x / 3) * 3 + k] * lambda[k] * q[(x % 3) * 3 + k])
                    .sum()
            })
            .collect();
        let (values, vectors) = jacobi_eigen(a.clone(), 3);
        for (e, want) in lambda.iter().enumerate() {
            // The eigenvalue, and its eigenvector +-column e of Q.
            let found = (0..3)
                .find(|&f| (values[f] - want).abs() < 1e-12)
                .unwrap_or_else(|| panic!("{want} not among {values:?}"));
            let cos: f64 = (0..3).map(|i| vectors[i * 3 + found] * q[i * 3 + e]).sum();
            assert!(
                (cos.abs() - 1.0).abs() < 1e-12,
                "eigenvector {e}: cos {cos}"
            );
        }
        // A V = V diag(values), V orthogonal.
        for e in 0..3 {
            for i in 0..3 {
                let av: f64 = (0..3).map(|j| a[i * 3 + j] * vectors[j * 3 + e]).sum();
                assert!((av - values[e] * vectors[i * 3 + e]).abs() < 1e-10);
                let vv: f64 = (0..3)
                    .map(|j| vectors[j * 3 + i] * vectors[j * 3 + e])
                    .sum();
                assert!((vv - if i == e { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn jacobi_of_a_diagonal_matrix_is_the_identity() {
        let (values, vectors) = jacobi_eigen(vec![3.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 7.0], 3);
        assert_eq!(values, [3.0, -1.0, 7.0]);
        assert_eq!(vectors, [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn jacobi_diagonalises() {
        let a = vec![4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 1.0];
        let (vals, vecs) = jacobi_eigen(a.clone(), 3);
        for e in 0..3 {
            for i in 0..3 {
                let av: f64 = (0..3).map(|j| a[i * 3 + j] * vecs[j * 3 + e]).sum();
                assert!((av - vals[e] * vecs[i * 3 + e]).abs() < 1e-10);
            }
        }
    }

    /// Rows `q` (dimension `k`) are orthonormal, and every row of `original` lies in the
    /// span of the first `prefix(i)` of them.
    fn check_orthonormal_span(
        q: &[f64],
        original: &[f64],
        k: usize,
        prefix: impl Fn(usize) -> usize,
    ) {
        let rows = q.len() / k;
        let row = |m: &[f64], i: usize| m[i * k..(i + 1) * k].to_vec();
        for i in 0..rows {
            for j in 0..rows {
                let d = dot(&row(q, i), &row(q, j));
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((d - want).abs() < 1e-12, "rows {i}, {j}: {d}");
            }
        }
        for i in 0..rows {
            let mut r = row(original, i);
            for j in 0..prefix(i) {
                let qj = row(q, j);
                let c = dot(&r, &qj);
                r.iter_mut().zip(&qj).for_each(|(x, y)| *x -= c * y);
            }
            let left = dot(&r, &r).sqrt();
            assert!(left < 1e-12, "row {i}: {left} outside the span");
        }
    }

    #[test]
    fn gram_schmidt_gives_orthonormal_rows_with_the_same_spans() {
        let (rows, k) = (5, 8);
        let mut rng = Rng::new(5);
        let original: Vec<f64> = (0..rows * k).map(|_| rng.f32() as f64 - 0.5).collect();
        let mut q = original.clone();
        orthonormalise(&mut q, k);
        // Gram-Schmidt keeps every leading span: row i lies in span(q_0..=q_i).
        check_orthonormal_span(&q, &original, k, |i| i + 1);
    }

    #[test]
    fn gram_schmidt_replaces_vanishing_rows() {
        // Row 1 repeats row 0, row 2 is zero: both are replaced by unit vectors orthogonal
        // to the others; the original rows stay in the span.
        let k = 4;
        let original = [1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let mut q = original.to_vec();
        orthonormalise(&mut q, k);
        check_orthonormal_span(&q, &original, k, |_| 3);
    }
}
