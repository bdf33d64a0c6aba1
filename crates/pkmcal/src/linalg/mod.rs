//! Linear algebra and the numbers the rest is written in: the scalar type
//! (`f64` or a dual number), LU factorisations and checked square solves,
//! the equilibrium's KKT solve, the pose convention (rotations), and
//! small vectors and 3×3 matrices as arrays.

use num_dual::DualNum;

pub(crate) mod kkt;
pub mod lu;
pub mod pose;
pub mod small;
pub(crate) mod solve;

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
pub(crate) fn product_into(a: &[f64], b: &[f64], out: &mut [f64], m: usize, k: usize, n: usize) {
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
pub(crate) fn gram_into(
    g: &nalgebra::DMatrix<f64>,
    gt: &mut nalgebra::DMatrix<f64>,
    out: &mut [f64],
) {
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

#[cfg(test)]
mod tests {
    /// [`super::product_into`] and [`super::gram_into`] are nalgebra's
    /// `mul_to` to the bit, for shapes on both sides of its loop (seeded
    /// random entries, signed zeros among them).
    #[test]
    fn products_are_nalgebra_s() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(52);
        for (m, k, n) in [
            (3, 5, 3),
            (3, 5, 1),
            (2, 2, 21),
            (1, 1, 1),
            (6, 7, 8),
            (30, 36, 30),
            (7, 6, 5),
            (4, 0, 3),
            (0, 3, 2),
        ] {
            let mut entry = |_, _| match rng.random_range(0..10) {
                0 => -0.0,
                _ => rng.random_range(-1e3..1e3),
            };
            let a = nalgebra::DMatrix::from_fn(m, k, &mut entry);
            let b = nalgebra::DMatrix::from_fn(k, n, &mut entry);
            let mut want = nalgebra::DMatrix::zeros(m, n);
            a.mul_to(&b, &mut want);
            let mut got = vec![f64::NAN; m * n];
            super::product_into(a.as_slice(), b.as_slice(), &mut got, m, k, n);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(want.as_slice()), "{m}x{k} by {k}x{n}");
            // And `a aᵀ` by [`super::gram_into`].
            let mut want = nalgebra::DMatrix::zeros(m, m);
            a.mul_to(&a.transpose(), &mut want);
            let mut got = vec![f64::NAN; m * m];
            super::gram_into(&a, &mut nalgebra::DMatrix::zeros(0, 0), &mut got);
            assert_eq!(
                bits(&got),
                bits(want.as_slice()),
                "{m}x{k} by its transpose"
            );
        }
    }
}
