//! LU factorisation with partial pivoting on contiguous column slices.
//!
//! Written here rather than taken from nalgebra (`DMatrix::lu`) because
//! nalgebra's works through strided views and per-column swaps, which cost
//! more than the arithmetic on the small systems of forward and inverse
//! kinematics; these are the same operations, in the same order, on the
//! matrix's own storage, so every factor, solution and determinant is bit for
//! bit nalgebra's (tested against it).

use nalgebra::{DMatrix, DVector};

/// The factors `P A = L U` of a square matrix: `L` (unit diagonal) below the
/// diagonal of `lu`, `U` on and above it, and the row swaps in order.
#[derive(Debug, Clone)]
pub struct Lu {
    #[doc(hidden)] // public for the integration tests only
    pub lu: DMatrix<f64>,
    swaps: Vec<(usize, usize)>,
}

impl Lu {
    /// Factorise the square matrix `a` (nalgebra's `LU::new`: the pivot is
    /// the first entry of largest magnitude on or below the diagonal; a
    /// column with no non-zero pivot is left as it is).
    pub fn new(mut a: DMatrix<f64>) -> Self {
        let n = a.nrows();
        assert_eq!(n, a.ncols(), "LU of a non-square matrix");
        let mut swaps = Vec::new();
        factor(a.as_mut_slice(), n, |i, p| swaps.push((i, p)));
        Self { lu: a, swaps }
    }

    /// The order of the matrix.
    pub fn n(&self) -> usize {
        self.lu.nrows()
    }

    /// The smallest magnitude on `U`'s diagonal.
    pub fn min_pivot(&self) -> f64 {
        (0..self.n())
            .map(|i| self.lu[(i, i)].abs())
            .fold(f64::INFINITY, f64::min)
    }

    /// The determinant: the product of `U`'s diagonal, negated for an odd
    /// number of row swaps.
    pub fn determinant(&self) -> f64 {
        let d = (0..self.n()).fold(1.0, |d, i| d * self.lu[(i, i)]);
        if self.swaps.len().is_multiple_of(2) {
            d
        } else {
            -d
        }
    }

    /// Solve `A x = b` in place (`b` one column of `n`); `false` when `U`
    /// has a zero on its diagonal.
    pub fn solve_in_place(&self, b: &mut [f64]) -> bool {
        for &(i, p) in &self.swaps {
            b.swap(i, p);
        }
        substitute(self.lu.as_slice(), self.n(), b)
    }

    /// `A⁻¹ b`, or `None` when `U` has a zero on its diagonal.
    pub fn solve(&self, b: &DVector<f64>) -> Option<DVector<f64>> {
        let mut x = b.clone();
        self.solve_in_place(x.as_mut_slice()).then_some(x)
    }

    /// `A⁻¹ B`, column by column, or `None` when `U` has a zero on its
    /// diagonal.
    pub fn solve_matrix(&self, b: &DMatrix<f64>) -> Option<DMatrix<f64>> {
        let mut x = b.clone();
        let n = self.n();
        if n == 0 {
            return Some(x);
        }
        x.as_mut_slice()
            .chunks_exact_mut(n)
            .all(|c| self.solve_in_place(c))
            .then_some(x)
    }
}

/// Solve `A x = b` in place, `A`'s storage receiving its factors: the
/// same operations as [`Lu::new`] then [`Lu::solve_in_place`], without a
/// copy of `A` (for buffers a caller keeps).
pub fn solve_in_place(a: &mut DMatrix<f64>, b: &mut [f64]) -> bool {
    let n = a.nrows();
    assert_eq!(n, a.ncols(), "LU of a non-square matrix");
    factor(a.as_mut_slice(), n, |i, p| b.swap(i, p));
    substitute(a.as_slice(), n, b)
}

/// The factorisation of [`Lu::new`] on the column-major `n × n` slice `s`,
/// reporting each row swap `(i, pivot)` as it is made.
fn factor(s: &mut [f64], n: usize, mut on_swap: impl FnMut(usize, usize)) {
    for i in 0..n {
        let col = &s[i * n..(i + 1) * n];
        let (mut piv, mut max) = (i, col[i].abs());
        for (r, v) in col.iter().enumerate().skip(i + 1) {
            if v.abs() > max {
                max = v.abs();
                piv = r;
            }
        }
        let diag = col[piv];
        if diag == 0.0 {
            continue;
        }
        if piv != i {
            on_swap(i, piv);
            for c in 0..=i {
                s.swap(c * n + i, c * n + piv);
            }
        }
        let inv = 1.0 / diag;
        let (left, right) = s.split_at_mut((i + 1) * n);
        let coeffs = &mut left[i * n + i + 1..];
        coeffs.iter_mut().for_each(|c| *c *= inv);
        for col in right.chunks_exact_mut(n) {
            if piv != i {
                col.swap(i, piv);
            }
            let p = col[i];
            for (y, c) in col[i + 1..].iter_mut().zip(coeffs.iter()) {
                *y -= p * c;
            }
        }
    }
}

/// Forward then back substitution with the factors in `s` (`n × n`,
/// column-major) on the already permuted `b`; `false` when `U` has a zero on
/// its diagonal.
fn substitute(s: &[f64], n: usize, b: &mut [f64]) -> bool {
    for i in 0..n.saturating_sub(1) {
        let c = b[i];
        for (y, l) in b[i + 1..].iter_mut().zip(&s[i * n + i + 1..(i + 1) * n]) {
            *y -= c * l;
        }
    }
    for i in (0..n).rev() {
        let d = s[i * n + i];
        if d == 0.0 {
            return false;
        }
        let c = b[i] / d;
        b[i] = c;
        for (y, u) in b[..i].iter_mut().zip(&s[i * n..i * n + i]) {
            *y -= c * u;
        }
    }
    true
}

/// The determinant of a square matrix as nalgebra's `determinant` computes
/// it: closed forms up to order 3, [`Lu`] above.
pub fn determinant(a: DMatrix<f64>) -> f64 {
    if a.nrows() <= 3 {
        a.determinant()
    } else {
        Lu::new(a).determinant()
    }
}
