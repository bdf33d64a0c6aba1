//! Linear algebra and the numbers the rest is written in: the scalar type
//! (`f64` or a dual number), LU factorisations and checked square solves,
//! the equilibrium's KKT solve, the pose convention (rotations), and
//! small vectors and 3×3 matrices as arrays.

use num_dual::DualNum;

#[doc(hidden)] // public for the integration tests only
pub mod kkt;
pub mod lu;
pub mod pose;
pub mod small;
#[doc(hidden)] // public for the integration tests only
pub mod solve;

/// The scalar type mechanism functions are written for: `f64` or a dual number.
pub trait Scalar: DualNum<Primitive = f64> + Copy + Send + Sync {}
impl<T: DualNum<Primitive = f64> + Copy + Send + Sync> Scalar for T {}

/// nalgebra's `mul_to` multiplies matrices by its own loop when one of the
/// product's dimensions is at most this (else by matrixmultiply's kernel).
const LOOPED_PRODUCT: usize = 5;

/// `out = a b` of column-major `a` (`m × k`) and `b` (`k × n`) into `out`
/// (`m × n`), the same to the bit as nalgebra's `a.mul_to(b, out)`: where
/// it loops (`m`, `k` or `n` at most [`LOOPED_PRODUCT`]), each column of
/// `out` is `a`'s first column times `b`'s entry, then every next column's
/// product added to it, in order, as here; else by `mul_to` itself. The
/// equilibrium's and the Jacobian rows' small products (3 × 5 by 5 × 3 on
/// the reference) without its generic dispatch, which was 3 % of a Monte
/// Carlo run.
#[doc(hidden)] // public for the integration tests only
pub fn product_into(a: &[f64], b: &[f64], out: &mut [f64], m: usize, k: usize, n: usize) {
    assert!(a.len() == m * k && b.len() == k * n && out.len() == m * n);
    if m > LOOPED_PRODUCT && k > LOOPED_PRODUCT && n > LOOPED_PRODUCT {
        let (a, b) = (
            nalgebra::DMatrixView::from_slice(a, m, k),
            nalgebra::DMatrixView::from_slice(b, k, n),
        );
        a.mul_to(&b, &mut nalgebra::DMatrixViewMut::from_slice(out, m, n));
        return;
    }
    if k == 0 {
        out.fill(0.0);
        return;
    }
    // Each entry summed in a register, in nalgebra's order (its first
    // product, then each next one added).
    for (y, bj) in out.chunks_exact_mut(m.max(1)).zip(b.chunks_exact(k)) {
        for (i, yi) in y.iter_mut().enumerate() {
            let mut sum = a[i] * bj[0];
            for (l, bl) in bj.iter().enumerate().skip(1) {
                sum += a[l * m + i] * bl;
            }
            *yi = sum;
        }
    }
}

/// `out = g gᵀ` of column-major `g` (`m × k`) into `out` (`m × m`), the
/// same to the bit as [`product_into`] of `g` and its transpose: where that
/// loops, entry `(i, j)` is `Σₗ g_il g_jl` in `l`'s order, which is entry
/// `(j, i)` (each product commutes exactly), so each is computed once;
/// else `gt` (`k × m`) takes the transpose for the kernel's product.
#[doc(hidden)] // public for the integration tests only
pub fn gram_into(g: &nalgebra::DMatrix<f64>, gt: &mut nalgebra::DMatrix<f64>, out: &mut [f64]) {
    let (m, k) = g.shape();
    assert_eq!(out.len(), m * m);
    if m > LOOPED_PRODUCT && k > LOOPED_PRODUCT {
        if gt.shape() != (k, m) {
            *gt = nalgebra::DMatrix::zeros(k, m);
        }
        g.transpose_to(gt);
        product_into(g.as_slice(), gt.as_slice(), out, m, k, m);
        return;
    }
    if k == 0 {
        out.fill(0.0);
        return;
    }
    let g = g.as_slice();
    for j in 0..m {
        for i in 0..=j {
            let mut sum = g[i] * g[j];
            for l in 1..k {
                sum += g[l * m + i] * g[l * m + j];
            }
            out[j * m + i] = sum;
            out[i * m + j] = sum;
        }
    }
}
