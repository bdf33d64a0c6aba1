//! The external load on the tool as a wrench, mapped to generalised forces on
//! the tool coordinates (docs/model.md eq. 10 takes `J_fᵀ` of those).
//!
//! A load is given with one value per tool coordinate, each in the unit that
//! does work with it: a **force** (N) along each length coordinate (x, y, z),
//! a **moment** (N·m) about each angle coordinate's axis (phi: about the
//! plane's normal; rx, ry, rz: about the base frame's x, y, z axes), acting on
//! the tool point (the platform's origin for a pose). The engine works with
//! generalised forces `Q` such that the virtual work is `Q·δx` in N·mm:
//!
//! ```text
//! lengths:          Q = F                      (N)
//! planar angle φ:   Q = 1000 · M_z             (N·mm per rad)
//! Euler angles:     Q = 1000 · Eᵀ M,  ω = E (ṙx, ṙy, ṙz),
//!                   E = [Rz Ry e_x, Rz e_y, e_z] for R = Rz(rz) Ry(ry) Rx(rx)
//! ```
//!
//! Points and readings (target points, ball-bar distances) are measurement
//! outputs, not a body the load acts on: their load is taken as given.

use crate::mechanism::tool::ToolLayout;
use crate::units::M_TO_MM;

/// Generalised forces on the tool coordinates (N on lengths, N·mm per rad on
/// angles) of a wrench `load` (N, N·m) at tool coordinates `x`.
pub fn generalized_forces(layout: ToolLayout, x: &[f64], load: &[f64]) -> Vec<f64> {
    let mut q = load.to_vec();
    match layout {
        ToolLayout::PlanarPose => q[2] = M_TO_MM * load[2],
        ToolLayout::SpatialPose => {
            let (sb, cb) = x[4].sin_cos();
            let (sc, cc) = x[5].sin_cos();
            // Columns of E: the axes of the Euler angles' rotations, in the base.
            let e = [[cc * cb, sc * cb, -sb], [-sc, cc, 0.0], [0.0, 0.0, 1.0]];
            let m = [load[3], load[4], load[5]];
            for (k, axis) in e.iter().enumerate() {
                q[3 + k] = M_TO_MM * (axis[0] * m[0] + axis[1] * m[1] + axis[2] * m[2]);
            }
        }
        _ => {}
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::pose::rotation;

    /// The work of a moment over a small rotation equals `Q·δ(angles)`.
    #[test]
    fn euler_generalised_forces_do_the_work_of_the_moment() {
        let x = [1.0, 2.0, 700.0, 0.1, -0.2, 0.3];
        let load = [0.0, 0.0, 0.0, 2.0, -1.0, 3.0];
        let q = generalized_forces(ToolLayout::SpatialPose, &x, &load);
        let h = 1e-6;
        for k in 0..3 {
            let mut y = x;
            y[3 + k] += h;
            let r0 = rotation(x[3], x[4], x[5]);
            let r1 = rotation(y[3], y[4], y[5]);
            // Small rotation vector ω h = vee(R1 R0ᵀ − I).
            let m = |i: usize, j: usize| (0..3).map(|l| r1[i][l] * r0[j][l]).sum::<f64>();
            let w = [
                (m(2, 1) - m(1, 2)) / 2.0,
                (m(0, 2) - m(2, 0)) / 2.0,
                (m(1, 0) - m(0, 1)) / 2.0,
            ];
            let work = 1e3 * (w[0] * load[3] + w[1] * load[4] + w[2] * load[5]);
            assert!(
                (work / h - q[3 + k]).abs() < 1e-4,
                "{k}: {} vs {}",
                work / h,
                q[3 + k]
            );
        }
    }
}
