//! Dense kernels: vector kernels on contiguous slices, written in independent
//! 8-wide lanes so that the compiler vectorises them at the level chosen by
//! [`crate::simd`], and the symmetric products `B^T B` of the Hessian
//! assembly (faer's blocked kernels), formed whole or kept up to date row by
//! row ([`IncrementalGram`]).

use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::{Accum, MatMut, MatRef, Par};

use crate::real::LANES;
use crate::simd::{dispatch, lane_sum, Madd, WithMadd, F8};

/// The eight values of `s` from `at`: the lanes of one [`Madd::madd8`] (whose
/// explicit vector form the kernels here use, where per-lane `madd` left the
/// vectorising to the compiler, which at times shuffled two-lane halves).
#[inline(always)]
fn lanes(s: &[f64], at: usize) -> &F8 {
    s[at..at + LANES].try_into().expect("eight lanes")
}

/// Products `src[r] . x` of the `R` rows of `src` (`R x n`, row-major) with `x`.
#[inline(always)]
pub fn rows_dot<M: Madd, const R: usize>(src: &[f64], x: &[f64]) -> [f64; R] {
    rows_dot_many::<M, R, 1>(src, [x])[0]
}

/// Products `src[r] . xs[v]` of the `R` rows of `src` (`R x n`, row-major)
/// with each of the `V` vectors `xs`, in one pass over `src`.
///
/// The R x V dot products run interleaved: one dot alone is a chain of
/// dependent additions, R of them keep the multiply-add units busy; V of them
/// read `src` (the memory traffic) once.
#[inline(always)]
pub fn rows_dot_many<M: Madd, const R: usize, const V: usize>(src: &[f64], xs: [&[f64]; V]) -> [[f64; R]; V] {
    let n = src.len() / R;
    debug_assert!(src.len() == R * n && xs.iter().all(|x| x.len() == n));
    let blocks = n / LANES;
    let mut acc = [[[0.0; LANES]; R]; V];
    for b in 0..blocks {
        let c0 = b * LANES;
        for r in 0..R {
            let row = lanes(src, r * n + c0);
            for (a, x) in acc.iter_mut().zip(&xs) {
                a[r] = M::madd8(row, lanes(x, c0), a[r]);
            }
        }
    }
    let mut out = [[0.0; R]; V];
    for ((o, a), x) in out.iter_mut().zip(&acc).zip(&xs) {
        for (r, (o, a)) in o.iter_mut().zip(a).enumerate() {
            let mut s = lane_sum(a);
            for c in blocks * LANES..n {
                s = M::madd(src[r * n + c], x[c], s);
            }
            *o = s;
        }
    }
    out
}

/// Calls `f(i, m_i . (x - origin))` for every row i of the square row-major
/// `m`, in order: the product of a quadratic energy's matrix with the offset
/// from its centre (the reduced inertia `M (q - qtilde)`, the contact model's
/// elastic `K (q - q0)`), without a vector for the offset.
///
/// The rows go [`ROW_BLOCK`] at a time, the offset formed once per eight
/// columns for all of them. Written as one dot per row with the offset inside,
/// these products were a chain of dependent multiply-adds: 7 us of a contact
/// model evaluation and 5 us of a full one at n = 60, a fifth of the tumbling
/// cheese's step in docs/results.md section 10 (body POD r = 60, fitted cubature).
#[inline(always)]
pub fn offset_rows_dot<M: Madd>(m: &[f64], x: &[f64], origin: &[f64], mut f: impl FnMut(usize, f64)) {
    let n = x.len();
    debug_assert!(m.len() == n * n && origin.len() == n);
    let blocks = n / LANES;
    let row_dot = |acc: &F8, r: usize| {
        let mut s = lane_sum(acc);
        for c in blocks * LANES..n {
            s = M::madd(m[r * n + c], x[c] - origin[c], s);
        }
        s
    };
    let mut i = 0;
    while i + ROW_BLOCK <= n {
        let mut acc = [[0.0; LANES]; ROW_BLOCK];
        for b in 0..blocks {
            let c0 = b * LANES;
            let d: F8 = std::array::from_fn(|l| x[c0 + l] - origin[c0 + l]);
            for (r, a) in acc.iter_mut().enumerate() {
                *a = M::madd8(lanes(m, (i + r) * n + c0), &d, *a);
            }
        }
        for (r, a) in acc.iter().enumerate() {
            f(i + r, row_dot(a, i + r));
        }
        i += ROW_BLOCK;
    }
    for r in i..n {
        let mut acc = [0.0; LANES];
        for b in 0..blocks {
            let c0 = b * LANES;
            let d: F8 = std::array::from_fn(|l| x[c0 + l] - origin[c0 + l]);
            acc = M::madd8(lanes(m, r * n + c0), &d, acc);
        }
        f(r, row_dot(&acc, r));
    }
}

/// `sum_i a[i] b[i]` over the common length.
#[inline(always)]
pub fn dot<M: Madd>(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0; LANES];
    let (ac, bc) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (x, y) in ac.zip(bc) {
        acc = M::madd8(x.try_into().expect("eight lanes"), y.try_into().expect("eight lanes"), acc);
    }
    let mut s = lane_sum(&acc);
    for (x, y) in ar.iter().zip(br) {
        s = M::madd(*x, *y, s);
    }
    s
}

/// `out += alpha m v` for the row-major `m` (`out.len()` x `v.len()`).
///
/// The solvers' small dense products (the convergence norm, the drift of the
/// lagged Hessian and its BFGS update, n = 26-126): written as plain loops
/// they were summed one value at a time and took 8-10 % of a tumbling step at
/// r = 60 (perf, held-out tumbling cheese of docs/results.md section 10).
pub fn mat_vec_add(m: &[f64], v: &[f64], alpha: f64, out: &mut [f64]) {
    assert_eq!(m.len(), out.len() * v.len(), "mat_vec_add: m is not out.len() x v.len()");
    dispatch(MatVecAdd { m, v, alpha, out })
}

/// `v^T m v` for the square row-major `m` ([`mat_vec_add`] for why).
pub fn quadratic_form(m: &[f64], v: &[f64]) -> f64 {
    assert_eq!(m.len(), v.len() * v.len(), "quadratic_form: m is not v.len() x v.len()");
    dispatch(QuadraticForm { m, v })
}

/// Rows of `m` taken together by [`mat_vec_add`] and [`quadratic_form`].
const ROW_BLOCK: usize = 4;

struct MatVecAdd<'a> {
    m: &'a [f64],
    v: &'a [f64],
    alpha: f64,
    out: &'a mut [f64],
}

impl WithMadd for MatVecAdd<'_> {
    type Output = ();
    #[inline(always)]
    fn run<M: Madd>(self) {
        let n = self.v.len();
        let done = self.out.len() / ROW_BLOCK * ROW_BLOCK;
        let mut blocks = self.out.chunks_exact_mut(ROW_BLOCK);
        for (o, rows) in (&mut blocks).zip(self.m.chunks_exact(ROW_BLOCK * n.max(1))) {
            let d = rows_dot::<M, ROW_BLOCK>(rows, self.v);
            for (o, d) in o.iter_mut().zip(d) {
                *o += self.alpha * d;
            }
        }
        for (i, o) in blocks.into_remainder().iter_mut().enumerate() {
            let r = done + i;
            *o += self.alpha * dot::<M>(&self.m[r * n..(r + 1) * n], self.v);
        }
    }
}

struct QuadraticForm<'a> {
    m: &'a [f64],
    v: &'a [f64],
}

impl WithMadd for QuadraticForm<'_> {
    type Output = f64;
    #[inline(always)]
    fn run<M: Madd>(self) -> f64 {
        let n = self.v.len();
        let blocks = n / ROW_BLOCK;
        let mut sum = 0.0;
        for b in 0..blocks {
            let r = b * ROW_BLOCK;
            let d = rows_dot::<M, ROW_BLOCK>(&self.m[r * n..(r + ROW_BLOCK) * n], self.v);
            for (k, d) in d.iter().enumerate() {
                sum += self.v[r + k] * d;
            }
        }
        for r in blocks * ROW_BLOCK..n {
            sum += self.v[r] * dot::<M>(&self.m[r * n..(r + 1) * n], self.v);
        }
        sum
    }
}

/// Combinations of the `R` rows of `src` (`R x n`, row-major):
/// `out[i] = sum_r coef[i][r] src[r]` for `i < coef.len()` (into `out`, row-major),
/// and in the same pass `acc += sum_r acc_coef[r] src[r]` unless `acc` is empty.
///
/// One pass over `src` in 8-column blocks keeps every block of the R source rows
/// in registers while all outputs are formed from it.
#[inline(always)]
pub fn combine_rows<M: Madd, const R: usize>(src: &[f64], coef: &[[f64; R]], out: &mut [f64], acc_coef: &[f64; R], acc: &mut [f64]) {
    let n = src.len() / R;
    let accumulate = !acc.is_empty();
    debug_assert!(src.len() == R * n && out.len() >= coef.len() * n && (!accumulate || acc.len() == n));
    let blocks = n / LANES;
    for b in 0..blocks {
        let c0 = b * LANES;
        let mut block = [[0.0; LANES]; R];
        for (r, row) in block.iter_mut().enumerate() {
            row.copy_from_slice(&src[r * n + c0..r * n + c0 + LANES]);
        }
        for (i, ci) in coef.iter().enumerate() {
            let mut v = [0.0; LANES];
            for r in 0..R {
                v = M::madd8_splat(ci[r], &block[r], v);
            }
            out[i * n + c0..i * n + c0 + LANES].copy_from_slice(&v);
        }
        if accumulate {
            let a: &mut F8 = (&mut acc[c0..c0 + LANES]).try_into().expect("eight lanes");
            for r in 0..R {
                *a = M::madd8_splat(acc_coef[r], &block[r], *a);
            }
        }
    }
    for c in blocks * LANES..n {
        for (i, ci) in coef.iter().enumerate() {
            out[i * n + c] = (0..R).fold(0.0, |s, r| M::madd(ci[r], src[r * n + c], s));
        }
        if accumulate {
            acc[c] = (0..R).fold(acc[c], |s, r| M::madd(acc_coef[r], src[r * n + c], s));
        }
    }
}

/// `dst (lower triangle) = op(B^T B)` for the `count` rows of the row-major `rows` (width n).
pub fn syrk_rows(dst: &mut [f64], n: usize, rows: &[f64], count: usize, accum: Accum) {
    syrk_lower(dst, n, (count > 0).then(|| MatRef::from_row_major_slice(&rows[..count * n], count, n)), accum, 1.0);
}

/// `dst (lower triangle) = op(B^T B)` for the first `count` rows of the
/// column-major `rows` with column stride `stride`.
pub fn syrk_columns(dst: &mut [f64], n: usize, rows: &[f64], stride: usize, count: usize, accum: Accum) {
    syrk_lower(dst, n, (count > 0).then(|| MatRef::from_column_major_slice_with_stride(rows, count, n, stride)), accum, 1.0);
}

/// `dst (lower triangle) = op(alpha B^T B)` (nothing, or zeros for `Replace`, without B).
pub fn syrk_lower(dst: &mut [f64], n: usize, b: Option<MatRef<'_, f64>>, accum: Accum, alpha: f64) {
    let Some(b) = b else {
        if accum == Accum::Replace {
            dst.fill(0.0);
        }
        return;
    };
    let a = MatMut::from_column_major_slice_mut(dst, n, n);
    triangular_matmul(
        a,
        BlockStructure::TriangularLower,
        accum,
        b.transpose(),
        BlockStructure::Rectangular,
        b,
        BlockStructure::Rectangular,
        alpha,
        Par::Seq,
    );
}

/// Copies the lower triangle of the n x n column-major `a` to its upper triangle.
pub fn mirror_lower(a: &mut [f64], n: usize) {
    for c in 0..n {
        for r in c + 1..n {
            a[r * n + c] = a[c * n + r];
        }
    }
}

/// Adds `B^T B` for the `count` row-major rows (width n) to the full symmetric `dst`.
pub fn add_gram(dst: &mut [f64], n: usize, rows: &[f64], count: usize) {
    if count == 0 {
        return;
    }
    syrk_rows(dst, n, rows, count, Accum::Add);
    mirror_lower(dst, n);
}

/// A symmetric matrix `B^T B` (n x n) kept up to date as rows of B are put in
/// and taken out, so that rows that do not change cost nothing. It is formed
/// from scratch when invalid or once the rows taken out outnumber four times
/// those in it, which bounds the round-off of the updates.
#[derive(Debug, Clone)]
pub struct IncrementalGram {
    n: usize,
    /// n x n, full symmetric.
    matrix: Vec<f64>,
    /// Rows in the matrix, and rows taken out since it was last formed from scratch.
    rows: usize,
    removed: usize,
    /// Whether `matrix` holds the rows put in (else the next update forms it from scratch).
    valid: bool,
}

impl IncrementalGram {
    /// An empty matrix of size n, formed from scratch at the first update.
    pub fn new(n: usize) -> Self {
        Self { n, matrix: vec![0.0; n * n], rows: 0, removed: 0, valid: false }
    }

    /// The matrix (n x n, full symmetric, PSD up to round-off).
    pub fn matrix(&self) -> &[f64] {
        &self.matrix
    }

    /// Forms the matrix from scratch at the next update.
    pub fn invalidate(&mut self) {
        self.valid = false;
    }

    /// Whether the next update must form the matrix from scratch: then every
    /// row must be put in again and none taken out.
    pub fn needs_rebuild(&self) -> bool {
        !self.valid || self.removed > 4 * self.rows.max(64)
    }

    /// Puts in the first `plus` rows of `rows_in` and takes out the first
    /// `minus` rows of `rows_out` (both row-major, n wide); after
    /// [`Self::needs_rebuild`], the matrix is formed from the rows put in.
    /// `total`: the rows in the matrix afterwards.
    pub fn update(&mut self, rows_in: &[f64], plus: usize, rows_out: &[f64], minus: usize, total: usize) {
        let n = self.n;
        if self.needs_rebuild() {
            debug_assert!(minus == 0, "a rebuild takes no rows out");
            syrk_rows(&mut self.matrix, n, rows_in, plus, Accum::Replace);
            self.removed = 0;
        } else {
            if plus > 0 {
                syrk_rows(&mut self.matrix, n, rows_in, plus, Accum::Add);
            }
            if minus > 0 {
                let b = MatRef::from_row_major_slice(&rows_out[..minus * n], minus, n);
                syrk_lower(&mut self.matrix, n, Some(b), Accum::Add, -1.0);
            }
            self.removed += minus;
        }
        mirror_lower(&mut self.matrix, n);
        self.rows = total;
        self.valid = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simd::Separate;
    use crate::testing::Rng;

    #[test]
    fn kernels_match_naive_loops() {
        let mut rng = Rng::new(1);
        for n in [0, 1, 7, 8, 13, 32, 45] {
            let a = rng.vec(n, 1.0);
            let b = rng.vec(n, 1.0);
            let naive: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            assert!((dot::<Separate>(&a, &b) - naive).abs() < 1e-12);

            let src = rng.vec(3 * n, 1.0);
            let coef = [[0.5, -1.0, 2.0], [1.5, 0.25, -0.75]];
            let acc_coef = [0.1, 0.2, 0.3];
            let mut out = vec![0.0; 2 * n];
            let mut acc = b.clone();
            combine_rows::<Separate, 3>(&src, &coef, &mut out, &acc_coef, &mut acc);
            for c in 0..n {
                for (i, ci) in coef.iter().enumerate() {
                    let e: f64 = (0..3).map(|r| ci[r] * src[r * n + c]).sum();
                    assert!((out[i * n + c] - e).abs() < 1e-12);
                }
                let e = b[c] + (0..3).map(|r| acc_coef[r] * src[r * n + c]).sum::<f64>();
                assert!((acc[c] - e).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn matrix_products_match_naive_loops() {
        let mut rng = Rng::new(2);
        // Sizes on both sides of the row blocks and the 8-wide lanes.
        for (rows, n) in [(0, 3), (1, 1), (3, 7), (4, 8), (5, 13), (9, 66), (72, 72)] {
            let m = rng.vec(rows * n, 1.0);
            let v = rng.vec(n, 1.0);
            let start = rng.vec(rows, 1.0);
            let mut out = start.clone();
            mat_vec_add(&m, &v, -0.5, &mut out);
            for r in 0..rows {
                let e = start[r] - 0.5 * (0..n).map(|c| m[r * n + c] * v[c]).sum::<f64>();
                assert!((out[r] - e).abs() < 1e-12, "mat_vec_add row {r} of {rows} x {n}");
            }
            let sq = rng.vec(n * n, 1.0);
            let naive: f64 = (0..n).map(|r| v[r] * (0..n).map(|c| sq[r * n + c] * v[c]).sum::<f64>()).sum();
            assert!((quadratic_form(&sq, &v) - naive).abs() < 1e-10 * (1.0 + naive.abs()), "quadratic_form, n = {n}");
        }
    }

    #[test]
    fn offset_products_match_naive_loops_row_by_row_in_order() {
        let mut rng = Rng::new(3);
        for n in [0, 1, 3, 4, 5, 8, 13, 66] {
            let (m, x, origin) = (rng.vec(n * n, 1.0), rng.vec(n, 1.0), rng.vec(n, 1.0));
            let mut seen = Vec::new();
            offset_rows_dot::<Separate>(&m, &x, &origin, |i, v| seen.push((i, v)));
            assert_eq!(seen.iter().map(|(i, _)| *i).collect::<Vec<_>>(), (0..n).collect::<Vec<_>>(), "rows out of order, n = {n}");
            for (i, v) in seen {
                let e: f64 = (0..n).map(|c| m[i * n + c] * (x[c] - origin[c])).sum();
                assert!((v - e).abs() < 1e-12, "row {i} of {n}: {v} against {e}");
            }
        }
    }
}
