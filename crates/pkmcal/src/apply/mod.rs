//! Using a mechanism and its calibration: simulated measurements,
//! compensated commands and correction tables, measurement planning, Monte
//! Carlo studies of a plan, and the usable workspace's targets.

pub mod budget;
pub mod compensation;
pub mod montecarlo;
pub mod planning;
pub mod rows;
#[doc(hidden)] // public for the integration tests only
pub mod screening;
pub mod simulate;
pub mod tooldrift;
pub mod workspace;
