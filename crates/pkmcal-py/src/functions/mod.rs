//! The package's functions: each takes its call's arguments as one dict
//! (`pkmcal/_api.py` holds their signatures, defaults and documentation).

pub mod apply;
pub mod design;
pub mod firmware;
pub mod fit;
