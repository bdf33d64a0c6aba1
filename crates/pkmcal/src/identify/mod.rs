//! Identification (docs/model.md eq. 12): the least-squares problem, its
//! identifiability, noise groups and weights, robust losses and outliers,
//! the fit, uncertainty and validation.

pub mod calibration;
pub mod noise;
pub mod stats;
