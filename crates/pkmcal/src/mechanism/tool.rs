//! The tool's coordinates, geometrically ([`ToolLayout`]): positions, planar
//! or spatial poses, points or frame-free readings; how a change of frame
//! acts on them.

use crate::units::Unit;
use serde::Serialize;

/// What the tool coordinates are, geometrically: how a change of frame acts
/// on them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum ToolLayout {
    /// A planar position `x, y` (mm).
    PlanarPoint,
    /// A planar pose `x, y` (mm), `phi` (rad).
    PlanarPose,
    /// A spatial pose `x, y, z` (mm), `rx, ry, rz` (rad), `R = Rz Ry Rx`.
    SpatialPose,
    /// `count` points of dimension `dim` (2 or 3), coordinates in order.
    Points {
        /// Dimension of each point.
        dim: usize,
        /// Number of points.
        count: usize,
    },
    /// Readings that do not depend on a frame (distances).
    Readings,
}

impl ToolLayout {
    /// Number of frame parameters: 3 in the plane, 6 in space, 0 for
    /// frame-free readings.
    pub fn frame_size(self) -> usize {
        match self {
            ToolLayout::PlanarPoint | ToolLayout::PlanarPose => 3,
            ToolLayout::Points { dim: 2, .. } => 3,
            ToolLayout::SpatialPose | ToolLayout::Points { .. } => 6,
            ToolLayout::Readings => 0,
        }
    }

    /// Names of the frame parameters.
    pub fn frame_names(self) -> Vec<String> {
        let names: &[&str] = if self.frame_size() == 3 {
            &["frame.x", "frame.y", "frame.phi"]
        } else if self.frame_size() == 6 {
            &[
                "frame.x", "frame.y", "frame.z", "frame.rx", "frame.ry", "frame.rz",
            ]
        } else {
            &[]
        };
        names.iter().map(|s| s.to_string()).collect()
    }

    /// Units of the frame parameters.
    pub fn frame_units(self) -> Vec<Unit> {
        match self.frame_size() {
            3 => vec![Unit::Millimetre, Unit::Millimetre, Unit::Radian],
            6 => [Unit::Millimetre; 3]
                .into_iter()
                .chain([Unit::Radian; 3])
                .collect(),
            _ => vec![],
        }
    }

    /// The points of a tool vector: start index of each, and its dimension.
    pub(crate) fn points(self, n: usize) -> (Vec<usize>, usize) {
        match self {
            ToolLayout::PlanarPoint | ToolLayout::PlanarPose => (vec![0], 2),
            ToolLayout::SpatialPose => (vec![0], 3),
            ToolLayout::Points { dim, count } => ((0..count).map(|k| k * dim).collect(), dim),
            ToolLayout::Readings => (vec![], n.min(1)),
        }
    }
}
