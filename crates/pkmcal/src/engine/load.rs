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

use crate::error::{Error, Result};
use crate::mechanism::tool::ToolLayout;
use crate::mechanism::{Mechanism, Params};
use crate::units::{M_TO_MM, Unit};

/// The largest twist a tool load may give a revolute actuator at the
/// mechanism's reference configuration (rad): about 6°; a working load
/// twists a drive by far less.
pub const MAX_LOAD_TWIST_RAD: f64 = 0.1;
/// The largest deflection a tool load may give a prismatic actuator at the
/// reference configuration (mm).
pub const MAX_LOAD_TWIST_MM: f64 = 10.0;

/// Check that a tool load is a working load of `mech` with `params`: at the
/// reference configuration, under the linear model (eq. 11), it twists no
/// actuated joint by more than [`MAX_LOAD_TWIST_RAD`] (revolute) or
/// [`MAX_LOAD_TWIST_MM`] (prismatic). A larger load is a mistake of units
/// (N·mm for N·m, grams for N) that would otherwise surface as a pose that
/// cannot be solved, blamed on the data. Where the reference configuration
/// cannot be predicted at all, the load is not blamed (the failure is
/// reported where it happens).
pub fn check_load<M: Mechanism>(mech: &M, params: &Params, load: &[f64]) -> Result<()> {
    if load.iter().all(|f| *f == 0.0) {
        return Ok(());
    }
    let spec = mech.spec();
    let commands: Vec<f64> = spec.actuated.iter().map(|&j| spec.reference_q[j]).collect();
    // The linear model is linear in the load: its twist per unit of the
    // load's size, scaled, so that a huge load is measured without being
    // solved for.
    let size = load.iter().map(|f| f * f).sum::<f64>().sqrt();
    if !size.is_finite() {
        return Err(Error::InvalidRequest(format!(
            "the tool load {load:?} is not a finite wrench"
        )));
    }
    let unit: Vec<f64> = load.iter().map(|f| f / size).collect();
    let linear = |l: &[f64]| {
        crate::engine::models::predict(
            mech,
            params,
            &commands,
            crate::engine::models::Model::Linear,
            l,
        )
    };
    let (Ok(p0), Ok(p1)) = (linear(&[]), linear(&unit)) else {
        return Ok(());
    };
    let twist: Vec<f64> = p1
        .deflection
        .iter()
        .zip(&p0.deflection)
        .map(|(a, b)| (a - b) * size)
        .collect();
    for (d, &j) in twist.iter().zip(&spec.actuated) {
        let (limit, unit) = match spec.joint_units[j] {
            Unit::Radian => (MAX_LOAD_TWIST_RAD, "rad"),
            _ => (MAX_LOAD_TWIST_MM, "mm"),
        };
        if d.is_nan() || d.abs() > limit {
            return Err(Error::InvalidRequest(format!(
                "the tool load {load:?} would twist actuator `{}` by {:.3e} {unit} at the reference configuration, more than any working load does (at most {limit} {unit}); a load is in N along each length coordinate and N·m about each angle coordinate",
                spec.joints[j],
                d.abs()
            )));
        }
    }
    Ok(())
}

/// Generalised forces on the tool coordinates (N on lengths, N·mm per rad on
/// angles) of a wrench `load` (N, N·m) at tool coordinates `x`.
pub fn generalized_forces(layout: ToolLayout, x: &[f64], load: &[f64]) -> Vec<f64> {
    let mut q = load.to_vec();
    match layout {
        ToolLayout::PlanarPose => q[2] = M_TO_MM * load[2],
        ToolLayout::SpatialPose => {
            // Columns of E: the axes of the Euler angles' rotations, in the base.
            let e = crate::linalg::pose::euler_axes(x[4], x[5]);
            let m = [load[3], load[4], load[5]];
            for (k, axis) in e.iter().enumerate() {
                q[3 + k] = M_TO_MM * crate::linalg::small::dot(*axis, m);
            }
        }
        _ => {}
    }
    q
}
