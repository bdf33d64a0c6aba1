//! The kinds of mechanism, each from its description: the paper's reference
//! mechanism, planar linkages, Gough–Stewart platforms and spatial
//! mechanisms, what their descriptions share, and [`any::AnyMechanism`],
//! which holds any of them.

pub mod any;
pub(crate) mod build;
pub mod description;
pub mod gough_stewart;
pub mod planar;
pub mod reference;
pub mod spatial;
