//! The instrument frame: where the measuring instrument (a laser tracker, a
//! camera) stands relative to the mechanism's base frame.
//!
//! A tracker never stands in the base frame. Its data are the tool
//! coordinates seen from its own frame: with `F = (t, R)` the instrument
//! frame's pose in the base frame (origin `t`, axes `R`),
//!
//! ```text
//! position:     y = Rᵀ (x − t)
//! orientation:  planar φ_y = φ − θ;  spatial R_y = Rᵀ R_x (Euler angles again)
//! ```
//!
//! `F` has 3 parameters in the plane (`frame.x frame.y frame.phi`) and 6 in
//! space (`frame.x frame.y frame.z frame.rx frame.ry frame.rz`, the rotation
//! `R = Rz(rz) Ry(ry) Rx(rx)` as for platform poses). Identified with the
//! mechanism's parameters, it starts from the rigid registration of the
//! measured positions onto the nominal ones (Kabsch/Horn, closed form), so
//! Newton starts near the solution wherever the instrument stands.
//!
//! Which coordinates are positions and which orientations is the tool's
//! [`ToolLayout`], declared by the mechanism.

use crate::error::{Error, Result};
use crate::linalg::pose::{euler, rotation};
use crate::linalg::small::apply_transposed;
use crate::mechanism::Scalar;
use crate::mechanism::tool::ToolLayout;
use nalgebra::{DMatrix, Matrix3, Vector3};
use num_dual::Dual64;

/// Tool coordinates `x` (base frame) as the instrument at `frame` sees them.
pub fn observe<D: Scalar>(layout: ToolLayout, x: &[D], frame: &[D], y: &mut [D]) {
    y.copy_from_slice(x);
    match layout.frame_size() {
        3 => {
            let (s, c) = frame[2].sin_cos();
            let (starts, _) = layout.points(x.len());
            for k in starts {
                let dx = x[k] - frame[0];
                let dy = x[k + 1] - frame[1];
                y[k] = c * dx + s * dy;
                y[k + 1] = c * dy - s * dx;
            }
            if layout == ToolLayout::PlanarPose {
                y[2] = x[2] - frame[2];
            }
        }
        6 => {
            let r = rotation(frame[3], frame[4], frame[5]);
            let (starts, _) = layout.points(x.len());
            for k in starts {
                let d = [x[k] - frame[0], x[k + 1] - frame[1], x[k + 2] - frame[2]];
                y[k..k + 3].copy_from_slice(&apply_transposed(&r, d));
            }
            if layout == ToolLayout::SpatialPose {
                let p = rotation(x[3], x[4], x[5]);
                // Rᵀ P, then its Euler angles (R = Rz Ry Rx).
                let m =
                    |i: usize, j: usize| r[0][i] * p[0][j] + r[1][i] * p[1][j] + r[2][i] * p[2][j];
                y[4] = (-m(2, 0)).asin();
                y[3] = m(2, 1).atan2(m(2, 2));
                y[5] = m(1, 0).atan2(m(0, 0));
            }
        }
        _ => {}
    }
}

/// [`observe`] and its exact derivatives with respect to `x` and `frame`.
pub fn observe_jacobian(
    layout: ToolLayout,
    x: &[f64],
    frame: &[f64],
) -> (Vec<f64>, DMatrix<f64>, DMatrix<f64>) {
    let (nx, nf) = (x.len(), frame.len());
    let mut y = vec![0.0; nx];
    observe(layout, x, frame, &mut y);
    let mut dx = DMatrix::zeros(nx, nx);
    let mut df = DMatrix::zeros(nx, nf);
    let xd: Vec<Dual64> = x.iter().map(|&v| Dual64::from(v)).collect();
    let fd: Vec<Dual64> = frame.iter().map(|&v| Dual64::from(v)).collect();
    let mut out = vec![Dual64::from(0.0); nx];
    for j in 0..nx + nf {
        let (mut a, mut b) = (xd.clone(), fd.clone());
        if j < nx {
            a[j] = Dual64::from(x[j]).derivative();
        } else {
            b[j - nx] = Dual64::from(frame[j - nx]).derivative();
        }
        observe(layout, &a, &b, &mut out);
        for i in 0..nx {
            if j < nx {
                dx[(i, j)] = out[i].eps;
            } else {
                df[(i, j - nx)] = out[i].eps;
            }
        }
    }
    (y, dx, df)
}

/// The base-frame tool coordinates behind the instrument's `y`: the inverse
/// of [`observe`].
pub fn to_base(layout: ToolLayout, y: &[f64], frame: &[f64]) -> Vec<f64> {
    let mut x = y.to_vec();
    match layout.frame_size() {
        3 => {
            let (s, c) = frame[2].sin_cos();
            let (starts, _) = layout.points(y.len());
            for k in starts {
                x[k] = frame[0] + c * y[k] - s * y[k + 1];
                x[k + 1] = frame[1] + s * y[k] + c * y[k + 1];
            }
            if layout == ToolLayout::PlanarPose {
                x[2] = y[2] + frame[2];
            }
        }
        6 => {
            let r = rotation(frame[3], frame[4], frame[5]);
            let (starts, _) = layout.points(y.len());
            for k in starts {
                for i in 0..3 {
                    x[k + i] = frame[i] + (0..3).map(|j| r[i][j] * y[k + j]).sum::<f64>();
                }
            }
            if layout == ToolLayout::SpatialPose {
                let p = rotation(y[3], y[4], y[5]);
                let m = |i: usize, j: usize| (0..3).map(|k| r[i][k] * p[k][j]).sum::<f64>();
                let (rx, ry, rz) = euler(&m);
                x[3] = rx;
                x[4] = ry;
                x[5] = rz;
            }
        }
        _ => {}
    }
    x
}

/// The frame that best maps the measured positions onto `reference` (base
/// frame), by least squares over every point of every pose: the closed-form
/// rigid registration (Kabsch 1976 / Horn 1987; 2-D: the angle of the summed
/// cross and dot products). Only positions are used; a registration from
/// fewer than 2 (plane) or 3 (space) distinct points is refused.
pub fn register(
    layout: ToolLayout,
    reference: &[Vec<f64>],
    measured: &[Vec<f64>],
) -> Result<Vec<f64>> {
    let nf = layout.frame_size();
    if nf == 0 {
        return Ok(vec![]);
    }
    let (starts, dim) = layout.points(reference.first().map_or(0, Vec::len));
    let mut p: Vec<[f64; 3]> = vec![];
    let mut q: Vec<[f64; 3]> = vec![];
    for (a, b) in reference.iter().zip(measured) {
        for &k in &starts {
            let mut u = [0.0; 3];
            let mut v = [0.0; 3];
            u[..dim].copy_from_slice(&a[k..k + dim]);
            v[..dim].copy_from_slice(&b[k..k + dim]);
            p.push(u);
            q.push(v);
        }
    }
    let need = if dim == 2 { 2 } else { 3 };
    if p.len() < need {
        return Err(Error::InvalidRequest(format!(
            "the instrument frame needs at least {need} measured points to be registered, got {}",
            p.len()
        )));
    }
    let n = p.len() as f64;
    let mean = |s: &[[f64; 3]]| {
        let mut m = [0.0; 3];
        for v in s {
            for i in 0..3 {
                m[i] += v[i] / n;
            }
        }
        m
    };
    let (pm, qm) = (mean(&p), mean(&q));
    if dim == 2 {
        // x = t + R(θ) y: θ maximises Σ (x − x̄)·R(y − ȳ).
        let (mut sc, mut ss) = (0.0, 0.0);
        for (a, b) in p.iter().zip(&q) {
            let (ax, ay) = (a[0] - pm[0], a[1] - pm[1]);
            let (bx, by) = (b[0] - qm[0], b[1] - qm[1]);
            sc += ax * bx + ay * by;
            ss += ay * bx - ax * by;
        }
        let th = ss.atan2(sc);
        let (s, c) = th.sin_cos();
        return Ok(vec![
            pm[0] - (c * qm[0] - s * qm[1]),
            pm[1] - (s * qm[0] + c * qm[1]),
            th,
        ]);
    }
    // Cross-covariance H = Σ (y − ȳ)(x − x̄)ᵀ = U S Vᵀ; R = V diag(1, 1, d) Uᵀ.
    let mut h = Matrix3::zeros();
    for (a, b) in p.iter().zip(&q) {
        let x = Vector3::new(a[0] - pm[0], a[1] - pm[1], a[2] - pm[2]);
        let y = Vector3::new(b[0] - qm[0], b[1] - qm[1], b[2] - qm[2]);
        h += y * x.transpose();
    }
    if h.iter().any(|v| !v.is_finite()) {
        return Err(Error::InvalidRequest(
            "the instrument frame cannot be registered: the positions are not finite".into(),
        ));
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let d = (vt.transpose() * u.transpose()).determinant().signum();
    let r = vt.transpose() * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    let t = Vector3::from(pm) - r * Vector3::from(qm);
    let (rx, ry, rz) = euler(&|i, j| r[(i, j)]);
    Ok(vec![t[0], t[1], t[2], rx, ry, rz])
}
