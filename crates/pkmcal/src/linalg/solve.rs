//! Square linear solves with a singularity check: LU with partial pivoting
//! on a column- and row-scaled system, refused (`None`, `false`) when the
//! matrix is singular to working precision.

use nalgebra::{DMatrix, DVector};

/// Relative pivot size below which a Jacobian counts as singular.
pub const SINGULAR_RCOND: f64 = 1e-9;

/// LU factorisation (partial pivoting) of a square matrix, or `None` when a
/// pivot falls below [`SINGULAR_RCOND`] times the largest entry (singular).
#[doc(hidden)] // public for the integration tests only
pub fn checked_lu(a: DMatrix<f64>) -> Option<crate::linalg::lu::Lu> {
    let scale = a.amax();
    if scale.is_nan() || scale <= 0.0 {
        return None;
    }
    let lu = crate::linalg::lu::Lu::new(a);
    (lu.min_pivot() >= SINGULAR_RCOND * scale).then_some(lu)
}

/// Solve `A X = B` (square `A`) after scaling `A`'s rows, then its columns, to
/// unit largest entry, with the singularity check of [`checked_lu`] on the
/// scaled matrix. For systems whose blocks have very different units, such as
/// the equilibrium's KKT matrix (stiffness next to constraint gradients).
pub(crate) fn solve_scaled(a: DMatrix<f64>, b: DMatrix<f64>) -> Option<DMatrix<f64>> {
    let (mut a, mut b) = (a, b);
    solve_scaled_in_place(&mut a, &mut b).then_some(b)
}

/// [`solve_scaled`] in place: `b` becomes the solution and `a` its scaled
/// LU factors; `false` (with `a` and `b` overwritten) when `A` is singular.
#[doc(hidden)] // public for the integration tests only
pub fn solve_scaled_in_place(a: &mut DMatrix<f64>, b: &mut DMatrix<f64>) -> bool {
    let n = a.nrows();
    if n == 0 {
        return true;
    }
    let (av, bv) = (a.as_mut_slice(), b.as_mut_slice());
    // Small sizes get loops compiled for their size (unrolled): about 1.4x
    // faster on the reference's 8 x 8 KKT system.
    match n {
        4 => scaled_lu_solve(4, av, bv),
        5 => scaled_lu_solve(5, av, bv),
        6 => scaled_lu_solve(6, av, bv),
        7 => scaled_lu_solve(7, av, bv),
        8 => scaled_lu_solve(8, av, bv),
        9 => scaled_lu_solve(9, av, bv),
        10 => scaled_lu_solve(10, av, bv),
        11 => scaled_lu_solve(11, av, bv),
        12 => scaled_lu_solve(12, av, bv),
        _ => scaled_lu_solve(n, av, bv),
    }
}

#[inline(always)]
fn scaled_lu_solve(n: usize, av: &mut [f64], bv: &mut [f64]) -> bool {
    // In place on the column-major storage of the two owned matrices: these
    // systems are small (tens of unknowns) and solved once per Newton
    // iteration, where nalgebra's strided row views and its LU's copies
    // cost more than the arithmetic. (Scaling by powers of two, as LAPACK's
    // `dgeequb`, would save the divisions, but changes the last bits of
    // the results, and with them near-tie choices of `plan`.)
    let mut rows_buf = [0.0; SMALL_SYSTEM];
    let mut rows_vec = vec![];
    let r: &mut [f64] = if n <= SMALL_SYSTEM {
        &mut rows_buf[..n]
    } else {
        rows_vec.resize(n, 0.0);
        &mut rows_vec
    };
    // The maxima below skip NaN entries, as `f64::max` does, in a form
    // that compiles to one vector instruction (`f64::max`'s NaN handling
    // does not): every running maximum starts at zero and is never NaN.
    for col in av.chunks_exact(n) {
        for (ri, v) in r.iter_mut().zip(col) {
            *ri = larger(*ri, v.abs());
        }
    }
    // (Without an early exit, so that the check is one vector pass.)
    if r.iter()
        .fold(false, |bad, ri| bad | !(*ri > 0.0 && ri.is_finite()))
    {
        return false;
    }
    for col in av.chunks_exact_mut(n).chain(bv.chunks_exact_mut(n)) {
        for (v, ri) in col.iter_mut().zip(r.iter()) {
            *v /= ri;
        }
    }
    // The column factors, kept (in `r`) to unscale the solution. Each
    // scaled column's largest entry is then exactly 1 (its largest entry
    // divided by itself; the rows' scaling left every entry finite or NaN),
    // so the scaled matrix's largest entry, the scale of the singularity
    // test, is 1.
    for (col, cj) in av.chunks_exact_mut(n).zip(r.iter_mut()) {
        let big = largest_magnitude(col);
        if big <= 0.0 || big.is_nan() {
            return false;
        }
        *cj = big;
        col.iter_mut().for_each(|v| *v /= big);
    }
    // LU with partial pivoting; rows of `b` swapped along.
    let mut min_pivot = f64::INFINITY;
    for k in 0..n {
        let colk = &av[k * n..(k + 1) * n];
        let (mut p, mut big) = (k, colk[k].abs());
        for (i, v) in colk.iter().enumerate().skip(k + 1) {
            if v.abs() > big {
                (p, big) = (i, v.abs());
            }
        }
        if p != k {
            for col in av.chunks_exact_mut(n).chain(bv.chunks_exact_mut(n)) {
                col.swap(k, p);
            }
        }
        let pivot = av[k + k * n];
        // (`f64::min` keeps the non-NaN operand, as this comparison does.)
        if pivot.abs() < min_pivot {
            min_pivot = pivot.abs();
        }
        if pivot == 0.0 {
            continue;
        }
        let (done, rest) = av.split_at_mut((k + 1) * n);
        let lk = &mut done[k * n + k + 1..];
        lk.iter_mut().for_each(|v| *v /= pivot);
        for col in rest.chunks_exact_mut(n) {
            let y = col[k];
            if y == 0.0 {
                continue;
            }
            for (v, l) in col[k + 1..].iter_mut().zip(lk.iter()) {
                *v -= l * y;
            }
        }
    }
    // (A NaN entry gives a NaN solution, which the callers reject as a
    // failed step, as they did with nalgebra's LU.)
    if min_pivot.is_nan() || min_pivot < SINGULAR_RCOND {
        return false;
    }
    for x in bv.chunks_exact_mut(n) {
        for k in 0..n {
            let xk = x[k];
            let col = &av[k * n..(k + 1) * n];
            for (v, l) in x[k + 1..].iter_mut().zip(&col[k + 1..]) {
                *v -= l * xk;
            }
        }
        for k in (0..n).rev() {
            let col = &av[k * n..(k + 1) * n];
            x[k] /= col[k];
            let xk = x[k];
            for (v, u) in x[..k].iter_mut().zip(&col[..k]) {
                *v -= u * xk;
            }
        }
        for (v, cj) in x.iter_mut().zip(r.iter()) {
            *v /= cj;
        }
    }
    true
}

/// The scaled LU of [`solve_scaled_in_place`] in two parts: the factors of
/// a square system kept ([`ScaledLu::factor`]), then right-hand sides
/// solved with them ([`ScaledLu::solve`]). Newton iterations that keep one
/// matrix for several steps (the exact equilibrium's) factor it once. The
/// scale factors are the powers of two nearest below each row's and then
/// each column's largest magnitude (as LAPACK's `dgeequb`), so that scaling
/// and unscaling are exact multiplications, and the pivots are applied as
/// reciprocals: no division but one a pivot. The solutions agree with
/// `solve_scaled_in_place`'s to rounding (its factors are scaled to exactly
/// 1, by divisions); the singularity test is the same, relative to the
/// scaled matrix's largest entry (here between 1 and 2).
#[derive(Debug, Default, Clone)]
#[doc(hidden)] // public for the integration tests only
pub struct ScaledLu {
    /// Size of the system.
    n: usize,
    /// The scaled matrix's LU factors (column-major, unit lower factor
    /// below the diagonal).
    lu: Vec<f64>,
    /// The rows' scale factors (powers of two).
    #[doc(hidden)] // public for the integration tests only
    pub rows: Vec<f64>,
    /// The columns' scale factors (powers of two).
    #[doc(hidden)] // public for the integration tests only
    pub cols: Vec<f64>,
    /// The reciprocals of the pivots.
    inverse_pivots: Vec<f64>,
    /// The row swapped with row `k` at step `k`.
    piv: Vec<usize>,
}

impl ScaledLu {
    /// Factor the `n × n` column-major `a` (copied); `false` when it is
    /// singular by [`solve_scaled_in_place`]'s test, or a row's or column's
    /// largest magnitude is outside the normal range of `f64` (below
    /// 2⁻¹⁰²² or from 2¹⁰²² on, far from any mechanism's): the factors are
    /// then not usable.
    #[doc(hidden)] // public for the integration tests only
    pub fn factor(&mut self, a: &[f64], n: usize) -> bool {
        debug_assert_eq!(a.len(), n * n);
        self.n = n;
        self.lu.clear();
        self.lu.extend_from_slice(a);
        for v in [&mut self.rows, &mut self.cols, &mut self.inverse_pivots] {
            v.clear();
            v.resize(n, 0.0);
        }
        self.piv.clear();
        self.piv.resize(n, 0);
        if n == 0 {
            return true;
        }
        let (lu, r, c, ip, piv) = (
            self.lu.as_mut_slice(),
            self.rows.as_mut_slice(),
            self.cols.as_mut_slice(),
            self.inverse_pivots.as_mut_slice(),
            self.piv.as_mut_slice(),
        );
        // (The reference's 8 × 8 system with loops compiled for its size.)
        match n {
            8 => factor_scaled(8, lu, r, c, ip, piv),
            _ => factor_scaled(n, lu, r, c, ip, piv),
        }
    }

    /// Solve with the factors of the last successful [`ScaledLu::factor`]:
    /// `b` (`n` entries) becomes the solution.
    #[doc(hidden)] // public for the integration tests only
    pub fn solve(&self, b: &mut [f64]) {
        let n = self.n;
        debug_assert_eq!(b.len(), n);
        let (lu, r, c, ip, piv) = (
            &self.lu,
            &self.rows,
            &self.cols,
            &self.inverse_pivots,
            &self.piv,
        );
        match n {
            8 => substitute_scaled(8, lu, r, c, ip, piv, b),
            _ => substitute_scaled(n, lu, r, c, ip, piv, b),
        }
    }
}

/// The power of two `f` for which `m · f` is in [1, 2) (`m` positive), or
/// `None` when `m` or `f` would not be a normal number (`m` NaN, infinite,
/// zero, subnormal, or from 2¹⁰²² on).
#[inline(always)]
#[doc(hidden)] // public for the integration tests only
pub fn unit_factor(m: f64) -> Option<f64> {
    // The biased exponent `e` of `m` (its sign bit is clear): `m` is in
    // [2^(e−1023), 2^(e−1022)), and 2^(1023−e) has the biased exponent
    // 2046 − e.
    let e = m.to_bits() >> 52;
    (m > 0.0 && (1..=2045).contains(&e)).then(|| f64::from_bits((2046 - e) << 52))
}

/// [`ScaledLu::factor`] on the column-major `av` in place.
#[inline(always)]
fn factor_scaled(
    n: usize,
    av: &mut [f64],
    r: &mut [f64],
    c: &mut [f64],
    ip: &mut [f64],
    piv: &mut [usize],
) -> bool {
    // The rows' largest magnitudes (NaN skipped), then their factors.
    for col in av.chunks_exact(n) {
        for (ri, v) in r.iter_mut().zip(col) {
            *ri = larger(*ri, v.abs());
        }
    }
    let mut usable = true;
    for ri in r.iter_mut() {
        match unit_factor(*ri) {
            Some(f) => *ri = f,
            None => usable = false,
        }
    }
    if !usable {
        return false;
    }
    for col in av.chunks_exact_mut(n) {
        for (v, ri) in col.iter_mut().zip(r.iter()) {
            *v *= ri;
        }
    }
    // The columns' factors, and the scaled matrix's largest entry.
    let mut scale = 0.0f64;
    for (col, cj) in av.chunks_exact_mut(n).zip(c.iter_mut()) {
        let big = largest_magnitude(col);
        let Some(f) = unit_factor(big) else {
            return false;
        };
        *cj = f;
        scale = larger(scale, big * f);
        col.iter_mut().for_each(|v| *v *= f);
    }
    // LU with partial pivoting, the swaps recorded.
    let mut min_pivot = f64::INFINITY;
    for k in 0..n {
        let colk = &av[k * n..(k + 1) * n];
        let (mut p, mut big) = (k, colk[k].abs());
        for (i, v) in colk.iter().enumerate().skip(k + 1) {
            if v.abs() > big {
                (p, big) = (i, v.abs());
            }
        }
        piv[k] = p;
        if p != k {
            for col in av.chunks_exact_mut(n) {
                col.swap(k, p);
            }
        }
        let pivot = av[k + k * n];
        // (`f64::min` keeps the non-NaN operand, as this comparison does.)
        if pivot.abs() < min_pivot {
            min_pivot = pivot.abs();
        }
        if pivot == 0.0 {
            continue;
        }
        let inverse = 1.0 / pivot;
        ip[k] = inverse;
        let (done, rest) = av.split_at_mut((k + 1) * n);
        let lk = &mut done[k * n + k + 1..];
        lk.iter_mut().for_each(|v| *v *= inverse);
        for col in rest.chunks_exact_mut(n) {
            let y = col[k];
            if y == 0.0 {
                continue;
            }
            for (v, l) in col[k + 1..].iter_mut().zip(lk.iter()) {
                *v -= l * y;
            }
        }
    }
    !(min_pivot.is_nan() || min_pivot < SINGULAR_RCOND * scale)
}

/// [`ScaledLu::solve`]: the substitutions with [`factor_scaled`]'s factors.
#[inline(always)]
fn substitute_scaled(
    n: usize,
    av: &[f64],
    r: &[f64],
    c: &[f64],
    ip: &[f64],
    piv: &[usize],
    x: &mut [f64],
) {
    for (v, ri) in x.iter_mut().zip(r.iter()) {
        *v *= ri;
    }
    for (k, &p) in piv.iter().enumerate() {
        x.swap(k, p);
    }
    for k in 0..n {
        let xk = x[k];
        let col = &av[k * n..(k + 1) * n];
        for (v, l) in x[k + 1..].iter_mut().zip(&col[k + 1..]) {
            *v -= l * xk;
        }
    }
    for k in (0..n).rev() {
        let col = &av[k * n..(k + 1) * n];
        x[k] *= ip[k];
        let xk = x[k];
        for (v, u) in x[..k].iter_mut().zip(&col[..k]) {
            *v -= u * xk;
        }
    }
    for (v, cj) in x.iter_mut().zip(c.iter()) {
        *v *= cj;
    }
}

/// `m.max(v)` for a running maximum `m` that is not NaN: a NaN `v` is
/// skipped, as `f64::max` skips it.
#[inline(always)]
#[doc(hidden)] // public for the integration tests only
pub fn larger(m: f64, v: f64) -> f64 {
    if v > m { v } else { m }
}

/// The largest magnitude in `v` (NaN entries skipped; 0 when empty), in four
/// lanes: a maximum does not depend on the order it is taken in, so this is
/// the sequential `fold` of [`larger`], bit for bit, in fewer dependent
/// steps.
#[inline(always)]
#[doc(hidden)] // public for the integration tests only
pub fn largest_magnitude(v: &[f64]) -> f64 {
    let mut lanes = [0.0f64; 4];
    let mut chunks = v.chunks_exact(4);
    for c in &mut chunks {
        for (l, x) in lanes.iter_mut().zip(c) {
            *l = larger(*l, x.abs());
        }
    }
    let m = larger(larger(lanes[0], lanes[1]), larger(lanes[2], lanes[3]));
    chunks.remainder().iter().fold(m, |m, x| larger(m, x.abs()))
}

/// Systems up to this size keep their scale factors on the stack.
const SMALL_SYSTEM: usize = 32;

/// Solve a square system by LU with a singularity check on the pivots.
pub(crate) fn solve_square(a: DMatrix<f64>, b: DVector<f64>) -> Option<DVector<f64>> {
    let (mut a, mut x) = (a, b);
    solve_square_in_place(&mut a, x.as_mut_slice()).then_some(x)
}

/// `A x = b` in place: `b` becomes the solution and `a` its LU factors;
/// `false` when `A` is singular (by [`checked_lu`]'s test). The same
/// operations as [`checked_lu`] then [`crate::linalg::lu::Lu::solve`], so the same
/// bits.
#[doc(hidden)] // public for the integration tests only
pub fn solve_square_in_place(a: &mut DMatrix<f64>, b: &mut [f64]) -> bool {
    // `amax` skips NaN entries as this does, and where every entry is NaN
    // both scales are rejected (NaN there, 0 here).
    let scale = largest_magnitude(a.as_slice());
    if scale.is_nan() || scale <= 0.0 {
        return false;
    }
    let solved = crate::linalg::lu::solve_in_place(a, b);
    let n = a.nrows();
    // The smallest pivot, NaN skipped as `f64::min` skips it.
    let min_pivot = a
        .as_slice()
        .iter()
        .step_by(n + 1)
        .fold(f64::INFINITY, |m, v| if v.abs() < m { v.abs() } else { m });
    min_pivot >= SINGULAR_RCOND * scale && solved
}
