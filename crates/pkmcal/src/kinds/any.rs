//! [`AnyMechanism`]: one type for every mechanism kind pkmcal ships, so that a
//! program (the CLI) can choose the kind at run time from a description.

use crate::Result;
use crate::kinds::gough_stewart::GoughStewart;
use crate::kinds::planar::PlanarLinkage;
use crate::kinds::reference::JeongKim2Dof;
use crate::kinds::spatial::SpatialMechanism;
use crate::mechanism::{Mechanism, Scalar, Spec};
use nalgebra::DMatrix;

/// A mechanism of any shipped kind; it implements [`Mechanism`] by delegation.
#[derive(Debug, Clone)]
pub enum AnyMechanism {
    /// The built-in reference mechanism (docs/model.md §10).
    JeongKim(JeongKim2Dof),
    /// A planar linkage from a description.
    Planar(PlanarLinkage),
    /// A Gough–Stewart platform.
    GoughStewart(GoughStewart),
    /// A spatial mechanism from a description.
    Spatial(SpatialMechanism),
}

macro_rules! each {
    ($s:expr, $m:ident => $e:expr) => {
        match $s {
            AnyMechanism::JeongKim($m) => $e,
            AnyMechanism::Planar($m) => $e,
            AnyMechanism::GoughStewart($m) => $e,
            AnyMechanism::Spatial($m) => $e,
        }
    };
}

impl From<JeongKim2Dof> for AnyMechanism {
    fn from(m: JeongKim2Dof) -> Self {
        Self::JeongKim(m)
    }
}
impl From<PlanarLinkage> for AnyMechanism {
    fn from(m: PlanarLinkage) -> Self {
        Self::Planar(m)
    }
}
impl From<SpatialMechanism> for AnyMechanism {
    fn from(m: SpatialMechanism) -> Self {
        Self::Spatial(m)
    }
}
impl From<GoughStewart> for AnyMechanism {
    fn from(m: GoughStewart) -> Self {
        Self::GoughStewart(m)
    }
}

impl Mechanism for AnyMechanism {
    fn spec(&self) -> &Spec {
        each!(self, m => m.spec())
    }
    fn constraints<D: Scalar>(&self, q: &[D], rho: &[D], g: &mut [D]) {
        each!(self, m => m.constraints(q, rho, g))
    }
    fn tool<D: Scalar>(&self, q: &[D], rho: &[D], x: &mut [D]) {
        each!(self, m => m.tool(q, rho, x))
    }
    fn inverse_kinematics_closed(&self, target: &[f64], rho: &[f64]) -> Option<Result<Vec<f64>>> {
        each!(self, m => m.inverse_kinematics_closed(target, rho))
    }
    fn configuration_guess(&self, commands: &[f64], rho: &[f64]) -> Option<Vec<f64>> {
        each!(self, m => m.configuration_guess(commands, rho))
    }
    fn first_derivatives(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
    ) -> Option<crate::mechanism::autodiff::Jacobians> {
        each!(self, m => m.first_derivatives(q, rho, cols))
    }

    fn first_derivatives_into(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
        out: &mut crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        each!(self, m => m.first_derivatives_into(q, rho, cols, out))
    }
    fn weighted_hessian(&self, q: &[f64], rho: &[f64], lambda: &[f64], mu: &[f64]) -> DMatrix<f64> {
        each!(self, m => m.weighted_hessian(q, rho, lambda, mu))
    }
    fn joint_hessians(&self, q: &[f64], rho: &[f64]) -> Vec<DMatrix<f64>> {
        each!(self, m => m.joint_hessians(q, rho))
    }
    fn joint_hessians_cheap(&self) -> bool {
        each!(self, m => m.joint_hessians_cheap())
    }
    fn joint_hessian_blocks(
        &self,
        q: &[f64],
        rho: &[f64],
        out: &mut dyn FnMut(&[usize], &[f64]),
    ) -> bool {
        each!(self, m => m.joint_hessian_blocks(q, rho, out))
    }
    fn on_branch(&self, q: &[f64], rho: &[f64]) -> bool {
        each!(self, m => m.on_branch(q, rho))
    }
    fn on_branch_near(
        &self,
        q: &[f64],
        rho: &[f64],
        jac: &crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        each!(self, m => m.on_branch_near(q, rho, jac))
    }
    fn check_params(&self, rho: &[f64]) -> Result<()> {
        each!(self, m => m.check_params(rho))
    }
    fn leg_in_other_mode(&self, q: &[f64], rho: &[f64]) -> Option<&str> {
        each!(self, m => m.leg_in_other_mode(q, rho))
    }
}
