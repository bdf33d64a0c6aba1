//! The engine: what a mechanism does under its parameters. Loop-closure
//! kinematics (eq. 3), the paper's linearised relations (eq. 4–11), the load
//! as a wrench, the three forward models and the exact equilibrium,
//! identification sensitivities, and the workspace lattice and atlas that
//! start forward kinematics.

pub mod atlas;
pub mod curvature;
pub mod kinematics;
pub mod linearized;
pub mod load;
pub mod models;
pub mod newton;
pub mod sensitivity;
