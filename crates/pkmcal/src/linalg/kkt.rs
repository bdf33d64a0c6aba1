//! The KKT systems of the exact model (docs/model.md section 4): each Newton
//! step of the equilibrium and the adjoint of its implicit derivatives solve
//!
//! ```text
//! [W  Gᵀ] [x]   [a]
//! [G  0 ] [y] = [b]
//! ```
//!
//! with `W` the Hessian of the Lagrangian in the joints (`nq × nq`, the
//! stiffness on the actuated joints' diagonal) and `G` the constraint
//! Jacobian (`m × nq`). They are solved on the null space of `G`, which the
//! mechanism's independent joints `U` parametrise: with `D` the dependent
//! joints and `G_D` (`m × m`) their columns of `G`,
//!
//! ```text
//! x_D = s₀ + S x_U,        S = −G_D⁻¹ G_U,  s₀ = G_D⁻¹ b
//! (Zᵀ W Z) x_U = Zᵀ (a − W [0; s₀]),         Z = [I; S]
//! y = G_D⁻ᵀ (a − W x)_D
//! ```
//!
//! an LU of `G_D` and of the `(nq − m)`-square reduced Hessian instead of one
//! of the whole `(nq + m)`-square system, whose zero block and mixed units
//! (stiffness next to constraint gradients) the LU cannot exploit: on the
//! 4-RRR's 21 × 21 system about a third of the operations. Where `G_D` or
//! the reduced Hessian is nearly singular (the independent joints do not
//! parametrise the constraints well at this configuration), the whole
//! system is solved by the scaled LU of
//! [`crate::linalg::solve::solve_scaled_in_place`], which also decides whether
//! it is singular.

use crate::linalg::solve::solve_scaled_in_place;
use nalgebra::DMatrix;

/// A pivot of `G_D` below this fraction of its largest entry sends the
/// system to the whole LU: the null-space basis `S` would be large and its
/// products lose digits.
const DEPENDENT_RCOND: f64 = 1e-7;

/// A pivot of the reduced Hessian below this fraction of its largest entry
/// sends the system to the whole LU (which judges singularity).
const REDUCED_RCOND: f64 = 1e-9;

/// Solve `[W Gᵀ; G 0] [x; y] = [a; b]` in place: `kkt` (`n × n`, `n = nq +
/// m`) holds the matrix (only its `W` and `G` blocks are read), `rhs` (`n ×
/// k`) the right-hand sides, which become the solutions. `independent`: the
/// `nq − m` joints that parametrise the constraints (the spec's independent
/// joints). Returns `false` when the system is singular (`kkt` and `rhs` then
/// overwritten). See the module's documentation.
#[inline]
#[doc(hidden)] // public for the integration tests only
pub fn solve_kkt_in_place(
    kkt: &mut DMatrix<f64>,
    rhs: &mut DMatrix<f64>,
    nq: usize,
    independent: &[usize],
    work: &mut KktWork,
) -> bool {
    let usable = tries_null_space(kkt.nrows(), nq, independent);
    (usable && work.null_space(kkt, rhs, nq, independent)) || solve_scaled_in_place(kkt, rhs)
}

/// Whether [`solve_kkt_in_place`] tries the null-space solve on an `n × n`
/// system of `nq` joints with these independent joints (else it solves the
/// whole system by the scaled LU, whose factors may then be kept for later
/// right-hand sides: [`crate::linalg::solve::ScaledLu`]).
pub(crate) fn tries_null_space(n: usize, nq: usize, independent: &[usize]) -> bool {
    n > nq
        && independent.len() + (n - nq) == nq
        && !independent.is_empty()
        && independent.iter().all(|&u| u < nq)
        && null_space_pays(nq, n - nq)
}

/// Whether the null-space solve is taken for `nq` joints and `m`
/// constraints: where its multiplications (the LUs of `G_D` and of the
/// reduced Hessian, `S`, `W Z`, `Zᵀ W Z`) number at most half of the whole
/// system's LU. Below that, its gathers and extra passes cost what the
/// multiplications save (measured in BENCHMARKS.md, issue 12: the 4-RRR's
/// 12 + 9 system gains, the reference's 5 + 3 and an 8-leg platform's
/// 14 + 8 do not).
#[doc(hidden)] // public for the integration tests only
pub fn null_space_pays(nq: usize, m: usize) -> bool {
    // Three times each count, in integers: the whole LU (nq + m)³/3; the
    // null space m³/3 + 2m²·nu + nq²·nu + nq·nu² + nu³/3.
    let nu = nq.saturating_sub(m);
    let whole = (nq + m).pow(3);
    let null = m.pow(3) + 6 * m * m * nu + 3 * nq * nq * nu + 3 * nq * nu * nu + nu.pow(3);
    2 * null <= whole
}

/// The null-space solve's buffers (column-major), kept with the other
/// buffers of the equilibrium's Newton iterations.
#[derive(Default)]
#[doc(hidden)] // public for the integration tests only
pub struct KktWork {
    /// The dependent joints `D`, in order.
    dep: Vec<usize>,
    /// `G_D`, then its LU factors.
    gd: Vec<f64>,
    /// The row swapped with row `k` at step `k` of `G_D`'s LU.
    gd_piv: Vec<usize>,
    /// `[S | s₀]` (`m × (nu + k)`).
    s: Vec<f64>,
    /// `W Z` (`nq × nu`).
    wz: Vec<f64>,
    /// The reduced Hessian `Zᵀ W Z`, then its LU factors.
    h: Vec<f64>,
    h_piv: Vec<usize>,
    /// `a − W [0; s₀]` for one right-hand side (`nq`).
    t: Vec<f64>,
    /// The solution `x` for one right-hand side (`nq`), then `W x`.
    x: Vec<f64>,
    wx: Vec<f64>,
    /// The reduced right-hand side, then `x_U` (`nu`), and `y` (`m`).
    c: Vec<f64>,
    y: Vec<f64>,
}

/// `v` sized to `n` entries (every one is written before it is read).
fn sized<T: Copy + Default>(v: &mut Vec<T>, n: usize) {
    v.resize(n, T::default());
}

/// LU with partial pivoting of the `n × n` column-major `a` in place (unit
/// lower factor below the diagonal), the swaps in `piv`; `false` when a
/// pivot is below `rcond` times the largest entry (or not a number).
fn factor(a: &mut [f64], piv: &mut [usize], n: usize, rcond: f64) -> bool {
    let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(scale > 0.0 && scale.is_finite()) {
        return false;
    }
    let tiny = rcond * scale;
    for k in 0..n {
        let colk = &a[k * n..(k + 1) * n];
        let (mut p, mut big) = (k, colk[k].abs());
        for (i, v) in colk.iter().enumerate().skip(k + 1) {
            if v.abs() > big {
                (p, big) = (i, v.abs());
            }
        }
        if big.is_nan() || big < tiny {
            return false;
        }
        piv[k] = p;
        if p != k {
            for col in a.chunks_exact_mut(n) {
                col.swap(k, p);
            }
        }
        let (done, rest) = a.split_at_mut((k + 1) * n);
        let pivot = done[k * n + k];
        let lk = &mut done[k * n + k + 1..];
        lk.iter_mut().for_each(|v| *v /= pivot);
        for col in rest.chunks_exact_mut(n) {
            let y = col[k];
            if y != 0.0 {
                for (v, l) in col[k + 1..].iter_mut().zip(lk.iter()) {
                    *v -= l * y;
                }
            }
        }
    }
    true
}

/// Solve `A z = b` in place from [`factor`]'s factors of `A`.
fn solve(lu: &[f64], piv: &[usize], n: usize, b: &mut [f64]) {
    for (k, &p) in piv.iter().enumerate() {
        b.swap(k, p);
    }
    for k in 0..n {
        let v = b[k];
        if v != 0.0 {
            for (bi, l) in b[k + 1..n].iter_mut().zip(&lu[k * n + k + 1..(k + 1) * n]) {
                *bi -= l * v;
            }
        }
    }
    for k in (0..n).rev() {
        b[k] /= lu[k * n + k];
        let v = b[k];
        for (bi, u) in b[..k].iter_mut().zip(&lu[k * n..k * n + k]) {
            *bi -= u * v;
        }
    }
}

/// Solve `Aᵀ z = b` in place from [`factor`]'s factors of `A` (`PA = LU`,
/// so `Aᵀ = Uᵀ Lᵀ P`).
fn solve_transposed(lu: &[f64], piv: &[usize], n: usize, b: &mut [f64]) {
    for k in 0..n {
        let col = &lu[k * n..k * n + k];
        let s: f64 = col.iter().zip(&b[..k]).map(|(u, z)| u * z).sum();
        b[k] = (b[k] - s) / lu[k * n + k];
    }
    for k in (0..n).rev() {
        let col = &lu[k * n + k + 1..(k + 1) * n];
        let s: f64 = col.iter().zip(&b[k + 1..n]).map(|(l, z)| l * z).sum();
        b[k] -= s;
    }
    for (k, &p) in piv.iter().enumerate().rev() {
        b.swap(k, p);
    }
}

impl KktWork {
    /// The null-space solve; `false` (nothing written) when `G_D` or the
    /// reduced Hessian is nearly singular.
    #[doc(hidden)] // public for the integration tests only
    pub fn null_space(
        &mut self,
        kkt: &DMatrix<f64>,
        rhs: &mut DMatrix<f64>,
        nq: usize,
        u: &[usize],
    ) -> bool {
        let n = kkt.nrows();
        let m = n - nq;
        let nu = u.len();
        let k = rhs.ncols();
        let a = kkt.as_slice();
        // W's column `c` (`nq` entries) and G's entry `(r, c)`.
        let wcol = |c: usize| &a[c * n..c * n + nq];
        let g = |r: usize, c: usize| a[c * n + nq + r];
        self.dep.clear();
        self.dep.extend((0..nq).filter(|j| !u.contains(j)));
        if self.dep.len() != m {
            return false;
        }
        let KktWork {
            dep,
            gd,
            gd_piv,
            s,
            wz,
            h,
            h_piv,
            t,
            x,
            wx,
            c,
            y,
        } = self;
        // G_D and its LU.
        sized(gd, m * m);
        for (j, &d) in dep.iter().enumerate() {
            for r in 0..m {
                gd[j * m + r] = g(r, d);
            }
        }
        sized(gd_piv, m);
        if !factor(gd, gd_piv, m, DEPENDENT_RCOND) {
            return false;
        }
        // [S | s₀] = G_D⁻¹ [−G_U | b].
        sized(s, m * (nu + k));
        for (j, &uj) in u.iter().enumerate() {
            let col = &mut s[j * m..(j + 1) * m];
            for (r, v) in col.iter_mut().enumerate() {
                *v = -g(r, uj);
            }
            solve(gd, gd_piv, m, col);
        }
        let b = rhs.as_slice();
        for col_k in 0..k {
            let col = &mut s[(nu + col_k) * m..(nu + col_k + 1) * m];
            col.copy_from_slice(&b[col_k * n + nq..(col_k + 1) * n]);
            solve(gd, gd_piv, m, col);
        }
        // W Z = W_:U + W_:D S, and Zᵀ W Z = (W Z)_U + Sᵀ (W Z)_D.
        sized(wz, nq * nu);
        for (j, &uj) in u.iter().enumerate() {
            let out = &mut wz[j * nq..(j + 1) * nq];
            out.copy_from_slice(wcol(uj));
            for (i, &d) in dep.iter().enumerate() {
                let sij = s[j * m + i];
                if sij != 0.0 {
                    for (o, w) in out.iter_mut().zip(wcol(d)) {
                        *o += w * sij;
                    }
                }
            }
        }
        sized(h, nu * nu);
        for j in 0..nu {
            let wzj = &wz[j * nq..(j + 1) * nq];
            for (r, &ur) in u.iter().enumerate() {
                let sr = &s[r * m..(r + 1) * m];
                let v: f64 = sr.iter().zip(dep.iter()).map(|(s, &d)| s * wzj[d]).sum();
                h[j * nu + r] = wzj[ur] + v;
            }
        }
        sized(h_piv, nu);
        if !factor(h, h_piv, nu, REDUCED_RCOND) {
            return false;
        }
        // Each right-hand side in turn; the solutions are written into `rhs`
        // only when every one is finite.
        sized(t, nq);
        sized(x, nq * k);
        sized(wx, nq);
        sized(c, nu);
        sized(y, m * k);
        for col_k in 0..k {
            let acol = &b[col_k * n..col_k * n + nq];
            let s0 = &s[(nu + col_k) * m..(nu + col_k + 1) * m];
            // t = a − W_:D s₀; c = t_U + Sᵀ t_D.
            t.copy_from_slice(acol);
            for (i, &d) in dep.iter().enumerate() {
                let si = s0[i];
                if si != 0.0 {
                    for (o, w) in t.iter_mut().zip(wcol(d)) {
                        *o -= w * si;
                    }
                }
            }
            for (r, &ur) in u.iter().enumerate() {
                let sr = &s[r * m..(r + 1) * m];
                let v: f64 = sr.iter().zip(dep.iter()).map(|(s, &d)| s * t[d]).sum();
                c[r] = t[ur] + v;
            }
            solve(h, h_piv, nu, c);
            // x_U, then x_D = s₀ + S x_U.
            let xk = &mut x[col_k * nq..(col_k + 1) * nq];
            for (r, &ur) in u.iter().enumerate() {
                xk[ur] = c[r];
            }
            for (i, &d) in dep.iter().enumerate() {
                let v: f64 = (0..nu).map(|j| s[j * m + i] * c[j]).sum();
                xk[d] = s0[i] + v;
            }
            // y = G_D⁻ᵀ (a − W x)_D.
            wx.iter_mut().for_each(|v| *v = 0.0);
            for (cidx, &xc) in xk.iter().enumerate() {
                if xc != 0.0 {
                    for (o, w) in wx.iter_mut().zip(wcol(cidx)) {
                        *o += w * xc;
                    }
                }
            }
            let yk = &mut y[col_k * m..(col_k + 1) * m];
            for (i, &d) in dep.iter().enumerate() {
                yk[i] = acol[d] - wx[d];
            }
            solve_transposed(gd, gd_piv, m, yk);
        }
        if !x.iter().chain(y.iter()).all(|v| v.is_finite()) {
            return false;
        }
        let out = rhs.as_mut_slice();
        for col_k in 0..k {
            out[col_k * n..col_k * n + nq].copy_from_slice(&x[col_k * nq..(col_k + 1) * nq]);
            out[col_k * n + nq..(col_k + 1) * n].copy_from_slice(&y[col_k * m..(col_k + 1) * m]);
        }
        true
    }
}
