//! Exact first and second derivatives of a mechanism's constraints and tool map
//! by forward-mode automatic differentiation (num-dual).
//!
//! The input vector is `v = [q; ρ]` (joints, then geometric parameters). The
//! Jacobian is computed in chunks of columns with static-size dual vectors (no
//! allocation per operation; the chunk size is picked from the number of
//! columns); second derivatives in blocks with hyper-dual vectors.

use crate::mechanism::{Mechanism, Scalar};
use nalgebra::{Const, DMatrix, U1};
use num_dual::{DualSVec64, HyperDualSVec64};
use std::ops::Range;

fn eval<M: Mechanism, D: Scalar>(mech: &M, v: &[D], g: &mut [D], x: &mut [D]) {
    let nq = mech.spec().joints.len();
    mech.constraints(&v[..nq], &v[nq..], g);
    mech.tool(&v[..nq], &v[nq..], x);
}

/// First derivatives of the constraints and the tool map.
#[derive(Debug, Clone)]
pub struct Jacobians {
    /// Constraint values g (n_constraints).
    pub g: Vec<f64>,
    /// Tool coordinates x.
    pub x: Vec<f64>,
    /// ∂g/∂v over the requested columns.
    pub dg: DMatrix<f64>,
    /// ∂x/∂v over the requested columns.
    pub dx: DMatrix<f64>,
}

impl Jacobians {
    /// Empty buffers, to be filled by [`jacobians_into`].
    pub fn empty() -> Self {
        Self {
            g: vec![],
            x: vec![],
            dg: DMatrix::zeros(0, 0),
            dx: DMatrix::zeros(0, 0),
        }
    }

    /// Size the buffers for `ng` constraints, `nx` tool coordinates and
    /// `nc` columns, reusing their storage when the sizes already fit.
    pub fn resize(&mut self, ng: usize, nx: usize, nc: usize) {
        self.g.resize(ng, 0.0);
        self.x.resize(nx, 0.0);
        if self.dg.shape() != (ng, nc) {
            self.dg = DMatrix::zeros(ng, nc);
        }
        if self.dx.shape() != (nx, nc) {
            self.dx = DMatrix::zeros(nx, nc);
        }
    }
}

/// [`jacobians`] into `out`, reusing its buffers where the mechanism's
/// closed form can ([`Mechanism::first_derivatives_into`]): the form for
/// loops that evaluate the derivatives at every iteration.
pub fn jacobians_into<M: Mechanism>(
    mech: &M,
    q: &[f64],
    rho: &[f64],
    cols: Range<usize>,
    out: &mut Jacobians,
) {
    if !mech.first_derivatives_into(q, rho, cols.clone(), out) {
        *out = automatic_jacobians(mech, q, rho, cols);
    }
}

/// Values and exact first derivatives of `g` and `x` with respect to the columns
/// `cols` of `v = [q; ρ]` (docs/model.md eq. 4: ∂g/∂q, ∂g/∂ρ; eq. 9: ∂x/∂q).
/// Uses the mechanism's closed-form derivatives
/// ([`Mechanism::first_derivatives`]) when it has them.
pub fn jacobians<M: Mechanism>(mech: &M, q: &[f64], rho: &[f64], cols: Range<usize>) -> Jacobians {
    if let Some(j) = mech.first_derivatives(q, rho, cols.clone()) {
        return j;
    }
    automatic_jacobians(mech, q, rho, cols)
}

/// [`jacobians`] by automatic differentiation always (the oracle for
/// closed-form derivatives).
pub fn automatic_jacobians<M: Mechanism>(
    mech: &M,
    q: &[f64],
    rho: &[f64],
    cols: Range<usize>,
) -> Jacobians {
    match cols.len() {
        0 => values(mech, q, rho),
        1..=3 => jacobians_chunked::<M, 3>(mech, q, rho, cols),
        4..=6 => jacobians_chunked::<M, 6>(mech, q, rho, cols),
        7..=8 => jacobians_chunked::<M, 8>(mech, q, rho, cols),
        _ => jacobians_chunked::<M, 11>(mech, q, rho, cols),
    }
}

fn values<M: Mechanism>(mech: &M, q: &[f64], rho: &[f64]) -> Jacobians {
    let spec = mech.spec();
    let mut g = vec![0.0; spec.n_constraints];
    let mut x = vec![0.0; spec.tool_axes.len()];
    mech.constraints(q, rho, &mut g);
    mech.tool(q, rho, &mut x);
    Jacobians {
        g,
        x,
        dg: DMatrix::zeros(spec.n_constraints, 0),
        dx: DMatrix::zeros(spec.tool_axes.len(), 0),
    }
}

fn jacobians_chunked<M: Mechanism, const C: usize>(
    mech: &M,
    q: &[f64],
    rho: &[f64],
    cols: Range<usize>,
) -> Jacobians {
    let spec = mech.spec();
    let (m, nx) = (spec.n_constraints, spec.tool_axes.len());
    let v0: Vec<f64> = q.iter().chain(rho).copied().collect();
    let mut v: Vec<DualSVec64<C>> = v0.iter().map(|&a| DualSVec64::from_re(a)).collect();
    let mut g = vec![DualSVec64::from_re(0.0); m];
    let mut x = vec![DualSVec64::from_re(0.0); nx];
    let mut dg = DMatrix::zeros(m, cols.len());
    let mut dx = DMatrix::zeros(nx, cols.len());
    let mut start = cols.start;
    while start < cols.end {
        let end = (start + C).min(cols.end);
        for (k, i) in (start..end).enumerate() {
            v[i] = DualSVec64::from_re(v0[i]).derivative(k);
        }
        eval(mech, &v, &mut g, &mut x);
        for (out, vals) in [(&mut dg, &g), (&mut dx, &x)] {
            for (r, val) in vals.iter().enumerate() {
                let e = val.eps.unwrap_generic(Const::<C>, U1);
                for k in 0..end - start {
                    out[(r, start - cols.start + k)] = e[k];
                }
            }
        }
        for i in start..end {
            v[i] = DualSVec64::from_re(v0[i]);
        }
        start = end;
    }
    Jacobians {
        g: g.iter().map(|d| d.re).collect(),
        x: x.iter().map(|d| d.re).collect(),
        dg,
        dx,
    }
}

/// Second derivatives `∂²y/∂v_r∂v_c` of every output `y` (the constraints, then
/// the tool coordinates) for rows `rows` and columns `cols` of `v = [q; ρ]`.
/// One matrix per output, `rows.len() × cols.len()`.
pub fn output_hessians<M: Mechanism>(
    mech: &M,
    q: &[f64],
    rho: &[f64],
    rows: Range<usize>,
    cols: Range<usize>,
) -> Vec<DMatrix<f64>> {
    // Small blocks: large hyper-dual numbers cost more to copy than the
    // extra passes (measured: one 6×24 pass is slower than three 8×8 ones).
    match (rows.len(), cols.len()) {
        (0..=6, 0..=6) => hessians_chunked::<M, 6, 6>(mech, q, rho, rows, cols),
        _ => hessians_chunked::<M, 8, 8>(mech, q, rho, rows, cols),
    }
}

fn hessians_chunked<M: Mechanism, const R: usize, const C: usize>(
    mech: &M,
    q: &[f64],
    rho: &[f64],
    rows: Range<usize>,
    cols: Range<usize>,
) -> Vec<DMatrix<f64>> {
    type H<const R: usize, const C: usize> = HyperDualSVec64<R, C>;
    let spec = mech.spec();
    let (m, nx) = (spec.n_constraints, spec.tool_axes.len());
    let v0: Vec<f64> = q.iter().chain(rho).copied().collect();
    let mut out = vec![DMatrix::zeros(rows.len(), cols.len()); m + nx];
    let mut g = vec![H::<R, C>::from_re(0.0); m];
    let mut x = vec![H::<R, C>::from_re(0.0); nx];
    let mut v: Vec<H<R, C>> = Vec::with_capacity(v0.len());
    let mut r0 = rows.start;
    while r0 < rows.end {
        let r1 = (r0 + R).min(rows.end);
        let mut c0 = cols.start;
        while c0 < cols.end {
            let c1 = (c0 + C).min(cols.end);
            v.clear();
            v.extend(v0.iter().enumerate().map(|(i, &a)| {
                let mut d = H::<R, C>::from_re(a);
                if (r0..r1).contains(&i) {
                    d = d.derivative1(i - r0);
                }
                if (c0..c1).contains(&i) {
                    d = d.derivative2(i - c0);
                }
                d
            }));
            eval(mech, &v, &mut g, &mut x);
            for (o, y) in out.iter_mut().zip(g.iter().chain(&x)) {
                let block = y.eps1eps2.unwrap_generic(Const::<R>, Const::<C>);
                for i in 0..r1 - r0 {
                    for j in 0..c1 - c0 {
                        o[(r0 - rows.start + i, c0 - cols.start + j)] = block[(i, j)];
                    }
                }
            }
            c0 = c1;
        }
        r0 = r1;
    }
    out
}

/// `Σ_i w_i H_i` for per-output Hessians `hessians` and weights `weights`.
pub fn weighted_sum(hessians: &[DMatrix<f64>], weights: &[f64]) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(hessians[0].nrows(), hessians[0].ncols());
    for (h, &w) in hessians.iter().zip(weights) {
        if w != 0.0 {
            // In place: `out += h * w` would allocate the product.
            out.zip_apply(h, |o, v| *o += v * w);
        }
    }
    out
}
