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
