//! Measurement models: what the instrument observes of the tool, with its own
//! parameters and exact derivatives (docs/model.md §7).
//!
//! (A long file: every measurement model with its derivatives is one job.)
//!
//! The mechanism predicts its tool coordinates `x` (base frame) at a pose; a
//! [`MeasurementModel`] turns them into what the instrument reads,
//! `y = h(x, m)`, where `m` are the instrument's parameters:
//!
//! | [`Instrument`] | reads | own parameters |
//! |---|---|---|
//! | `Tool` | any subset of the tool coordinates (e.g. only `z`) | — |
//! | `Targets` | positions of points fixed on the tool body | `t1x t1y [t1z] …` (mm, tool frame) |
//! | `BallBar` | distances `|b − s_j| + d` from the ball `b` to sockets `s_j` | `s1x s1y [s1z] … dbar`, and `ball.x ball.y [ball.z]` on a tool with an orientation |
//! | `Probe` | the tool point's height above a bed plane, `z − h(x, y)` (a z-probe, a dial gauge on a surface plate) | `bed.z` (mm), `bed.rx bed.ry` (rad) |
//!
//! followed by the instrument frame's parameters (`frame.x …`, [`crate::measurement::frame`])
//! unless the data are in the base frame ([`Frame::Base`]). A ball bar has no
//! frame of its own: its sockets fix it. Identification appends `m` to the
//! mechanism's parameters; the instrument's own are fixed unless freed by
//! name, the frame's are free with [`Frame::Free`].
//!
//! A new instrument (distances between two poses, say) is one new variant:
//! its readings, names, units and parameters below.

pub mod ballbar;
pub mod data;
pub mod frame;

use crate::error::{Error, Result};
use crate::linalg::pose::transform;
use crate::measurement::ballbar::Setup;
use crate::mechanism::tool::ToolLayout;
use crate::mechanism::{Scalar, Spec};
use crate::units::Unit;
use nalgebra::DMatrix;
use num_dual::Dual64;
use serde::Serialize;

/// Where the measuring instrument stands relative to the base frame.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub enum Frame {
    /// The data are in the base frame (ball-bar sockets at known places, a
    /// frame already registered).
    Base,
    /// At this known pose ([`crate::measurement::frame`]: `x, y, phi` or
    /// `x, y, z, rx, ry, rz`).
    Known(Vec<f64>),
    /// Unknown (a tracker or camera where it was put): identified with the
    /// rest, from a start found by rigid registration.
    Free,
}

/// What a user asks of the instrument frame (each front end words it:
/// `--frame` on the command line, `frame=` in Python).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameRequest {
    /// Free for whole positions and target points, unless the data say they
    /// are in the base frame (`data_in_base`); the base frame otherwise.
    Auto {
        /// The data declare themselves in the base frame (a data file's
        /// `# frame: base`).
        data_in_base: bool,
    },
    /// An instrument frame identified with the rest.
    Free,
    /// The data are in the base frame.
    Base,
}

/// Why a [`FrameRequest`] cannot be met. Typed, so that each front end says
/// what to change in its own terms.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FrameRequestError {
    /// A free frame for a ball bar, whose sockets are in the base frame.
    BallBar,
    /// A free frame for probed heights, which fix no instrument frame (the
    /// bed plane's height and tilts are the parameters `bed.z`, `bed.rx`,
    /// `bed.ry`).
    Probe,
    /// A free frame for readings of only some tool axes, which cannot
    /// register a frame.
    PartialAxes {
        /// The axes read.
        axes: Vec<String>,
    },
}

impl std::fmt::Display for FrameRequestError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FrameRequestError::BallBar => {
                write!(f, "a ball bar's sockets are in the base frame")
            }
            FrameRequestError::Probe => write!(
                f,
                "probed heights fix no instrument frame; the bed plane's height and tilts are the parameters bed.z, bed.rx, bed.ry"
            ),
            FrameRequestError::PartialAxes { axes } => write!(
                f,
                "a free frame needs whole positions to register the instrument frame; the instrument reads only {}",
                axes.join(", ")
            ),
        }
    }
}

impl std::error::Error for FrameRequestError {}

/// The frame rule, the same for every front end: the [`Frame`] that
/// `request` gives `measurement`, or `None` where the instrument carries no
/// frame (a ball bar, a probe, a tool without a pose frame). Whole positions
/// and target points take a free frame unless the data are in the base
/// frame; readings of some axes take the base frame.
pub fn requested_frame(
    measurement: &MeasurementModel,
    spec: &Spec,
    request: FrameRequest,
) -> std::result::Result<Option<Frame>, FrameRequestError> {
    let positions = measurement.is_whole_tool()
        || matches!(measurement.instrument(), Instrument::Targets { .. });
    if request == FrameRequest::Free {
        match measurement.instrument() {
            Instrument::BallBar { .. } => return Err(FrameRequestError::BallBar),
            Instrument::Probe => return Err(FrameRequestError::Probe),
            _ if !positions => {
                return Err(FrameRequestError::PartialAxes {
                    axes: measurement.axes().to_vec(),
                });
            }
            _ => {}
        }
    }
    if matches!(
        measurement.instrument(),
        Instrument::BallBar { .. } | Instrument::Probe
    ) || spec.tool_layout.frame_size() == 0
    {
        return Ok(None);
    }
    Ok(Some(match request {
        FrameRequest::Free => Frame::Free,
        FrameRequest::Base => Frame::Base,
        FrameRequest::Auto { data_in_base } if positions && !data_in_base => Frame::Free,
        FrameRequest::Auto { .. } => Frame::Base,
    }))
}

/// What the instrument observes.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub enum Instrument {
    /// Tool coordinates: these axes (indices into the mechanism's tool axes,
    /// in the order they are read).
    Tool {
        /// Indices of the axes read.
        axes: Vec<usize>,
    },
    /// Positions of points fixed on the tool body (e.g. tracker targets on a
    /// platform), given in the tool frame (mm); read as `t1x t1y [t1z] t2x …`.
    Targets {
        /// Nominal positions in the tool frame.
        points: Vec<Vec<f64>>,
    },
    /// Ball-bar distances from a ball fixed on the tool to sockets fixed on
    /// the base; read as `d1 d2 …`.
    BallBar {
        /// Sockets and bar offset.
        setup: Setup,
        /// Ball centre in the tool frame (mm): empty when the tool is a point
        /// (the ball is the tool point), else its nominal offset.
        ball: Vec<f64>,
    },
    /// Heights of the tool point above a bed plane, read as `probe`: the
    /// plane `h(x, y) = bed.z − x·tan(bed.ry) + y·tan(bed.rx)` (the plane
    /// `z = bed.z` turned by `bed.rx` about x and `bed.ry` about y, to first
    /// order in the tilts, exactly as a height over x and y), the reading
    /// `z − h(x, y)`. Its three parameters are 0 nominally (a flat bed at
    /// z = 0: the reading is the tool's z) and fixed unless freed.
    Probe,
}

/// A measurement model for one mechanism: the instrument, its frame, and the
/// names, units and nominal values of what it reads and of its parameters.
/// Built by [`MeasurementModel::tool`], [`MeasurementModel::tool_axes`],
/// [`MeasurementModel::targets`] or [`MeasurementModel::ball_bar`], each
/// checked against the mechanism.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct MeasurementModel {
    instrument: Instrument,
    frame: Frame,
    tool: ToolLayout,
    tool_axes: Vec<String>,
    axes: Vec<String>,
    units: Vec<Unit>,
    names: Vec<String>,
    param_units: Vec<Unit>,
    nominal: Vec<f64>,
    n_own: usize,
}

/// A summary of a measurement model for reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeasurementSummary {
    /// `tool`, `targets` or `ball_bar`.
    pub kind: &'static str,
    /// What is read, in data-column order.
    pub axes: Vec<String>,
    /// Unit of each.
    pub units: Vec<Unit>,
    /// `base`, `known` or `free`.
    pub frame: &'static str,
}

/// Dimension of the tool's body points (2 in the plane, 3 in space), and
/// whether the tool has an orientation (so that a point off the tool point
/// moves differently).
fn body(layout: ToolLayout) -> Option<(usize, bool)> {
    match layout {
        ToolLayout::PlanarPoint => Some((2, false)),
        ToolLayout::PlanarPose => Some((2, true)),
        ToolLayout::SpatialPose => Some((3, true)),
        ToolLayout::Points { dim, count: 1 } => Some((dim, false)),
        _ => None,
    }
}

/// The base-frame position of the body point `t` (tool frame) of a tool at
/// `x`: `p + R t` on a tool with an orientation, the tool point otherwise.
fn body_point<D: Scalar>(layout: ToolLayout, x: &[D], t: &[D]) -> [D; 3] {
    let zero = D::from(0.0);
    match layout {
        ToolLayout::PlanarPose => {
            let (s, c) = x[2].sin_cos();
            [x[0] + c * t[0] - s * t[1], x[1] + s * t[0] + c * t[1], zero]
        }
        // No point given: the tool point itself.
        ToolLayout::SpatialPose if t.is_empty() => [x[0], x[1], x[2]],
        ToolLayout::SpatialPose => transform(x, [t[0], t[1], t[2]]),
        _ => {
            let mut p = [zero; 3];
            let dim = body(layout).map_or(0, |b| b.0).min(x.len());
            p[..dim].copy_from_slice(&x[..dim]);
            p
        }
    }
}

const COORD: [&str; 3] = ["x", "y", "z"];

/// The name of the reading of a row that is a distance between two poses
/// ([`crate::Measurement::partner`]).
pub const DISTANCE_AXIS: &str = "distance";

/// The bed plane's parameters of a [`Instrument::Probe`].
pub const PROBE_PARAMS: [&str; 3] = ["bed.z", "bed.rx", "bed.ry"];

impl MeasurementModel {
    fn build(spec: &Spec, instrument: Instrument) -> Self {
        let mut param_units = None;
        let (axes, units, names, nominal) = match &instrument {
            Instrument::Tool { axes } => (
                axes.iter().map(|&a| spec.tool_axes[a].clone()).collect(),
                axes.iter().map(|&a| spec.tool_units[a]).collect(),
                vec![],
                vec![],
            ),
            Instrument::Targets { points } => {
                let mut names = vec![];
                let mut nominal = vec![];
                for (j, p) in points.iter().enumerate() {
                    for (c, v) in COORD.iter().zip(p) {
                        names.push(format!("t{}{c}", j + 1));
                        nominal.push(*v);
                    }
                }
                let units = vec![Unit::Millimetre; names.len()];
                (names.clone(), units, names, nominal)
            }
            Instrument::BallBar { setup, ball } => {
                let mut names = vec![];
                let mut nominal = vec![];
                for (j, s) in setup.sockets.iter().enumerate() {
                    for (c, v) in COORD.iter().zip(s) {
                        names.push(format!("s{}{c}", j + 1));
                        nominal.push(*v);
                    }
                }
                names.push("dbar".into());
                nominal.push(setup.bar_offset);
                for (c, v) in COORD.iter().zip(ball) {
                    names.push(format!("ball.{c}"));
                    nominal.push(*v);
                }
                let k = setup.sockets.len();
                (
                    (1..=k).map(|j| format!("d{j}")).collect(),
                    vec![Unit::Millimetre; k],
                    names,
                    nominal,
                )
            }
            Instrument::Probe => {
                param_units = Some(vec![Unit::Millimetre, Unit::Radian, Unit::Radian]);
                (
                    vec!["probe".into()],
                    vec![Unit::Millimetre],
                    PROBE_PARAMS.map(String::from).to_vec(),
                    vec![0.0; 3],
                )
            }
        };
        let n_own = names.len();
        let param_units = param_units.unwrap_or_else(|| vec![Unit::Millimetre; n_own]);
        Self {
            instrument,
            frame: Frame::Base,
            tool: spec.tool_layout,
            tool_axes: spec.tool_axes.clone(),
            axes,
            units,
            param_units,
            names,
            nominal,
            n_own,
        }
    }

    /// Every tool coordinate, in the base frame: the mechanism's own data.
    pub fn tool(spec: &Spec) -> Self {
        Self::build(
            spec,
            Instrument::Tool {
                axes: (0..spec.tool_axes.len()).collect(),
            },
        )
    }

    /// The tool coordinates named `axes` (e.g. only `z`), in that order.
    pub fn tool_axes<S: AsRef<str>>(spec: &Spec, axes: &[S]) -> Result<Self> {
        if axes.is_empty() {
            return Err(Error::InvalidRequest(format!(
                "name at least one tool axis to measure ({})",
                spec.tool_axes.join(" ")
            )));
        }
        let mut idx = vec![];
        for a in axes {
            let a = a.as_ref();
            let i = spec.tool_axes.iter().position(|t| t == a).ok_or_else(|| {
                Error::InvalidRequest(format!(
                    "`{a}` is not a tool axis of `{}`; its axes are {}",
                    spec.name,
                    spec.tool_axes.join(" ")
                ))
            })?;
            if idx.contains(&i) {
                return Err(Error::InvalidRequest(format!(
                    "tool axis `{a}` is named twice"
                )));
            }
            idx.push(i);
        }
        Ok(Self::build(spec, Instrument::Tool { axes: idx }))
    }

    /// Points fixed on the tool body at `points` (tool frame, mm), whose
    /// positions are read. The tool needs an orientation (a planar or
    /// spatial pose).
    pub fn targets(spec: &Spec, points: &[Vec<f64>]) -> Result<Self> {
        let dim = match body(spec.tool_layout) {
            Some((dim, true)) => dim,
            _ => {
                return Err(Error::InvalidMechanism(format!(
                    "target points need a tool with an orientation (a planar or spatial pose); the tool of `{}` is {}",
                    spec.name,
                    spec.tool_axes.join(" ")
                )));
            }
        };
        if points.is_empty() {
            return Err(Error::InvalidRequest(
                "give at least one target point".into(),
            ));
        }
        for (j, p) in points.iter().enumerate() {
            if p.len() != dim || p.iter().any(|v| !v.is_finite()) {
                return Err(Error::InvalidRequest(format!(
                    "target {} needs {dim} finite coordinates (tool frame, mm), got {p:?}",
                    j + 1
                )));
            }
        }
        Ok(Self::build(
            spec,
            Instrument::Targets {
                points: points.to_vec(),
            },
        ))
    }

    /// A ball bar between sockets on the base (`setup`, base frame) and a
    /// ball on the tool point (on a tool with an orientation, the ball's
    /// offset `ball.x …` is a parameter, nominally 0).
    pub fn ball_bar(spec: &Spec, setup: &Setup) -> Result<Self> {
        let (dim, oriented) = body(spec.tool_layout).ok_or_else(|| {
            Error::InvalidMechanism(format!(
                "a ball bar measures one tool point; the tool of `{}` ({}) has none",
                spec.name,
                spec.tool_axes.join(" ")
            ))
        })?;
        setup.validate(dim)?;
        Ok(Self::build(
            spec,
            Instrument::BallBar {
                setup: setup.clone(),
                ball: if oriented { vec![0.0; dim] } else { vec![] },
            },
        ))
    }

    /// Heights of the tool point probed on a bed plane (read as `probe`;
    /// [`Instrument::Probe`]). The tool needs a spatial tool point.
    pub fn probe(spec: &Spec) -> Result<Self> {
        match body(spec.tool_layout) {
            Some((3, _)) => Ok(Self::build(spec, Instrument::Probe)),
            _ => Err(Error::InvalidMechanism(format!(
                "a height probe needs a spatial tool point (x, y, z); the tool of `{}` is {}",
                spec.name,
                spec.tool_axes.join(" ")
            ))),
        }
    }

    /// The same model with its own parameters (not the frame's) at `own`
    /// (e.g. a tilted bed for a probe, to simulate one).
    pub fn with_own(mut self, own: &[f64]) -> Result<Self> {
        if own.len() != self.n_own || own.iter().any(|v| !v.is_finite()) {
            return Err(Error::Dimension {
                what: format!(
                    "finite values of the instrument's parameters ({})",
                    self.names[..self.n_own].join(" ")
                ),
                expected: self.n_own,
                got: own.len(),
            });
        }
        self.nominal[..self.n_own].copy_from_slice(own);
        Ok(self)
    }

    /// The same model with the instrument at `frame`. A ball bar and a probe
    /// have no frame (the sockets and the bed plane are in the base frame):
    /// only [`Frame::Base`] is accepted.
    pub fn in_frame(mut self, frame: Frame) -> Result<Self> {
        let layout = self.frame_layout();
        let size = layout.frame_size();
        if size == 0 && frame != Frame::Base {
            return Err(Error::InvalidRequest(match self.instrument {
                Instrument::Probe => "a probe's bed plane is in the base frame (its height and tilts are the parameters bed.z, bed.rx, bed.ry): it has no instrument frame to identify or give".into(),
                _ => "a ball bar's sockets are in the base frame: it has no instrument frame to identify or give".into(),
            }));
        }
        self.names.truncate(self.n_own);
        self.param_units.truncate(self.n_own);
        self.nominal.truncate(self.n_own);
        match &frame {
            Frame::Base => {}
            Frame::Known(f) => {
                if f.len() != size || f.iter().any(|v| !v.is_finite()) {
                    return Err(Error::Dimension {
                        what: format!("instrument frame ({})", layout.frame_names().join(" ")),
                        expected: size,
                        got: f.len(),
                    });
                }
                // A frame farther than a length can be, or turned by more
                // than a few turns, is a mistake (positions of 1e300 mm).
                let units = layout.frame_units();
                if let Some((k, v)) = f.iter().enumerate().find(|(k, v)| {
                    let limit = if units[*k] == Unit::Radian {
                        crate::units::MAX_ANGLE_RAD
                    } else {
                        crate::units::MAX_LENGTH_MM
                    };
                    v.abs() > limit
                }) {
                    return Err(Error::InvalidRequest(format!(
                        "instrument frame: {} = {v:e} {} is beyond any instrument's place (at most {:e})",
                        layout.frame_names()[k],
                        units[k],
                        if units[k] == Unit::Radian {
                            crate::units::MAX_ANGLE_RAD
                        } else {
                            crate::units::MAX_LENGTH_MM
                        }
                    )));
                }
                self.nominal.extend(f);
            }
            Frame::Free => self.nominal.extend(vec![0.0; size]),
        }
        if frame != Frame::Base {
            self.names.extend(layout.frame_names());
            self.param_units.extend(layout.frame_units());
        }
        self.frame = frame;
        Ok(self)
    }

    /// The instrument.
    pub fn instrument(&self) -> &Instrument {
        &self.instrument
    }
    /// Where the instrument stands.
    pub fn frame(&self) -> &Frame {
        &self.frame
    }
    /// Names of the readings (data columns), in order.
    pub fn axes(&self) -> &[String] {
        &self.axes
    }
    /// Unit of each reading.
    pub fn units(&self) -> &[Unit] {
        &self.units
    }
    /// Number of readings per pose.
    pub fn len(&self) -> usize {
        self.axes.len()
    }
    /// Whether a pose has no reading (never, for a built model).
    pub fn is_empty(&self) -> bool {
        self.axes.is_empty()
    }
    /// Names of the model's parameters: its own, then the frame's.
    pub fn param_names(&self) -> &[String] {
        &self.names
    }
    /// Units of the model's parameters.
    pub fn param_units(&self) -> &[Unit] {
        &self.param_units
    }
    /// Nominal values of the model's parameters (the frame's: the known
    /// pose, or 0 before registration).
    pub fn nominal(&self) -> &[f64] {
        &self.nominal
    }
    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        self.names.len()
    }
    /// Indices (into [`MeasurementModel::param_names`]) of the frame's
    /// parameters.
    pub fn frame_range(&self) -> std::ops::Range<usize> {
        self.n_own..self.names.len()
    }
    /// Index of parameter `name` in the identification vector: the
    /// mechanism's parameters, then this model's.
    pub fn index_of(&self, spec: &Spec, name: &str) -> Result<usize> {
        if let Some(i) = self.names.iter().position(|n| n == name) {
            return Ok(spec.n_params() + i);
        }
        spec.param_index(name).map_err(|_| {
            let all = self.all_names(spec);
            Error::UnknownParameter {
                name: name.to_string(),
                known: all.join(" "),
                suggestion: crate::error::did_you_mean(name, all.iter().map(String::as_str)),
            }
        })
    }

    /// Names of the identification vector: the mechanism's, then this
    /// model's.
    pub fn all_names(&self, spec: &Spec) -> Vec<String> {
        spec.param_names()
            .iter()
            .map(|s| s.to_string())
            .chain(self.names.iter().cloned())
            .collect()
    }

    /// Whether this model reads every tool coordinate in order.
    pub fn is_whole_tool(&self) -> bool {
        matches!(&self.instrument, Instrument::Tool { axes }
            if axes.len() == self.tool_axes.len() && axes.iter().enumerate().all(|(i, a)| i == *a))
    }

    /// How a change of the instrument's frame acts: on the tool coordinates
    /// (then the axes read are picked), on the target points, or not at all.
    fn frame_layout(&self) -> ToolLayout {
        match &self.instrument {
            Instrument::Tool { .. } => self.tool,
            Instrument::Targets { points } => ToolLayout::Points {
                dim: points.first().map_or(3, Vec::len),
                count: points.len(),
            },
            Instrument::BallBar { .. } | Instrument::Probe => ToolLayout::Readings,
        }
    }

    /// The summary for reports.
    pub fn summary(&self) -> MeasurementSummary {
        MeasurementSummary {
            kind: match self.instrument {
                Instrument::Tool { .. } => "tool",
                Instrument::Targets { .. } => "targets",
                Instrument::BallBar { .. } => "ball_bar",
                Instrument::Probe => "probe",
            },
            axes: self.axes.clone(),
            units: self.units.clone(),
            frame: match self.frame {
                Frame::Base => "base",
                Frame::Known(_) => "known",
                Frame::Free => "free",
            },
        }
    }

    /// A one-line description ("x y phi", "3 target points", "ball bar, 3
    /// sockets").
    pub fn describe(&self) -> String {
        match &self.instrument {
            Instrument::Tool { .. } => format!("tool coordinates {}", self.axes.join(" ")),
            Instrument::Targets { points } => {
                crate::error::count(points.len(), "target point", "target points")
            }
            Instrument::BallBar { setup, .. } => {
                format!("ball bar, {} sockets", setup.sockets.len())
            }
            Instrument::Probe => "heights probed on a bed plane".into(),
        }
    }

    /// How many readings a data row holds: one for a distance between two
    /// poses ([`crate::Measurement::partner`]), the instrument's otherwise.
    pub fn row_len(&self, row: &crate::Measurement) -> usize {
        if row.partner.is_some() { 1 } else { self.len() }
    }

    /// The unit of reading `a` of a data row.
    pub fn row_unit(&self, row: &crate::Measurement, a: usize) -> Unit {
        if row.partner.is_some() {
            Unit::Millimetre
        } else {
            self.units[a]
        }
    }

    /// The name of reading `a` of a data row.
    pub fn row_axis<'s>(&'s self, row: &crate::Measurement, a: usize) -> &'s str {
        if row.partner.is_some() {
            DISTANCE_AXIS
        } else {
            &self.axes[a]
        }
    }

    /// Check a row's point of the tool body ([`crate::Measurement::point`]):
    /// only a probe reads a point other than the tool point, on a spatial
    /// tool with an orientation, at three finite coordinates within any
    /// tool's size.
    pub fn check_point(&self, row: &crate::Measurement) -> Result<()> {
        let Some(p) = &row.point else {
            return Ok(());
        };
        if self.instrument != Instrument::Probe || row.partner.is_some() {
            return Err(Error::InvalidRequest(
                "only a probe's height reads a point of the tool other than the tool point; give the row without its point".into(),
            ));
        }
        if self.tool != ToolLayout::SpatialPose {
            return Err(Error::InvalidMechanism(format!(
                "a point off the tool point moves with the tool's orientation, which this mechanism's tool ({}) does not give; give the tool as a whole pose (x y z rx ry rz)",
                self.tool_axes.join(" ")
            )));
        }
        if p.len() != 3
            || p.iter()
                .any(|v| !(v.is_finite() && v.abs() <= crate::units::MAX_LENGTH_MM))
        {
            return Err(Error::InvalidRequest(format!(
                "the point read needs 3 finite coordinates in the tool frame (mm) within ±{:e} mm, got {p:?}",
                crate::units::MAX_LENGTH_MM
            )));
        }
        Ok(())
    }

    /// Check that the tool has a point whose distances between poses can be
    /// measured (every position coordinate).
    pub fn check_distances(&self) -> Result<()> {
        match body(self.tool) {
            Some(_) => Ok(()),
            None => Err(Error::InvalidRequest(format!(
                "distances between poses need the tool point's every position coordinate; this mechanism's tool is {}",
                self.tool_axes.join(" ")
            ))),
        }
    }

    /// The distance between the tool points of tools at `a` and `b` (base
    /// frame, mm): the reading of a row that pairs two poses. It needs no
    /// instrument frame and no instrument parameter (calipers on a printed
    /// object, a gauge block).
    pub fn distance<D: Scalar>(&self, a: &[D], b: &[D]) -> D {
        let (pa, pb) = (body_point(self.tool, a, &[]), body_point(self.tool, b, &[]));
        let mut sum = D::from(0.0);
        for k in 0..3 {
            let d = pa[k] - pb[k];
            sum += d * d;
        }
        sum.sqrt()
    }

    /// [`MeasurementModel::distance`] and its exact derivatives with respect
    /// to `a` and to `b`.
    pub fn distance_jacobian(&self, a: &[f64], b: &[f64]) -> (f64, Vec<f64>, Vec<f64>) {
        let n = a.len();
        let mut ad: Vec<Dual64> = a.iter().map(|&v| Dual64::from(v)).collect();
        let mut bd: Vec<Dual64> = b.iter().map(|&v| Dual64::from(v)).collect();
        let (mut da, mut db) = (vec![0.0; n], vec![0.0; n]);
        for j in 0..n {
            ad[j] = Dual64::from(a[j]).derivative();
            da[j] = self.distance(&ad, &bd).eps;
            ad[j] = Dual64::from(a[j]);
            bd[j] = Dual64::from(b[j]).derivative();
            db[j] = self.distance(&ad, &bd).eps;
            bd[j] = Dual64::from(b[j]);
        }
        (self.distance(a, b), da, db)
    }

    /// The readings `y = h(x, m)` of a tool at `x` (base frame) under the
    /// model's parameters `m`.
    pub fn observe<D: Scalar>(&self, x: &[D], m: &[D], y: &mut [D]) {
        self.observe_point(x, m, None, y)
    }

    /// The readings of a row whose probe reads the tool body's `point`
    /// (tool frame, mm; [`crate::Measurement::point`], checked by
    /// [`MeasurementModel::check_point`]); `None`: [`MeasurementModel::observe`].
    pub fn observe_point<D: Scalar>(&self, x: &[D], m: &[D], point: Option<&[f64]>, y: &mut [D]) {
        let f = &m[self.n_own..];
        let zero = D::from(0.0);
        match &self.instrument {
            Instrument::Tool { axes } => {
                let mut full = [zero; 6];
                let n = x.len();
                if self.frame == Frame::Base {
                    full[..n].copy_from_slice(x);
                } else {
                    frame::observe(self.tool, x, f, &mut full[..n]);
                }
                for (out, &a) in y.iter_mut().zip(axes) {
                    *out = full[a];
                }
            }
            Instrument::Targets { points } => {
                let dim = points.first().map_or(3, Vec::len);
                for j in 0..points.len() {
                    let p = body_point(self.tool, x, &m[dim * j..dim * (j + 1)]);
                    y[dim * j..dim * (j + 1)].copy_from_slice(&p[..dim]);
                }
                if self.frame != Frame::Base {
                    let base = y.to_vec();
                    frame::observe(self.frame_layout(), &base, f, y);
                }
            }
            Instrument::BallBar { setup, ball } => {
                let (k, dim) = (setup.sockets.len(), body(self.tool).map_or(2, |b| b.0));
                let b = if ball.is_empty() {
                    body_point(self.tool, x, &[])
                } else {
                    body_point(self.tool, x, &m[k * dim + 1..k * dim + 1 + dim])
                };
                let offset = m[k * dim];
                for (j, out) in y.iter_mut().enumerate().take(k) {
                    let mut sum = zero;
                    for (a, bc) in b.iter().enumerate().take(dim) {
                        let d = *bc - m[j * dim + a];
                        sum += d * d;
                    }
                    *out = sum.sqrt() + offset;
                }
            }
            Instrument::Probe => {
                let t: Vec<D> = point.unwrap_or(&[]).iter().map(|&v| D::from(v)).collect();
                let p = body_point(self.tool, x, &t);
                let h = m[0] - p[0] * m[2].tan() + p[1] * m[1].tan();
                y[0] = p[2] - h;
            }
        }
    }

    /// [`MeasurementModel::observe`] and its exact derivatives (dual numbers)
    /// with respect to the tool coordinates and to the model's parameters.
    pub fn observe_jacobian(&self, x: &[f64], m: &[f64]) -> (Vec<f64>, DMatrix<f64>, DMatrix<f64>) {
        self.observe_point_jacobian(x, m, None)
    }

    /// [`MeasurementModel::observe_point`] and its exact derivatives, as
    /// [`MeasurementModel::observe_jacobian`].
    pub fn observe_point_jacobian(
        &self,
        x: &[f64],
        m: &[f64],
        point: Option<&[f64]>,
    ) -> (Vec<f64>, DMatrix<f64>, DMatrix<f64>) {
        let mut work = ObserveJacobian::default();
        self.observe_point_jacobian_into(x, m, point, &mut work);
        (work.y, work.dx, work.dm)
    }

    /// [`MeasurementModel::observe_point_jacobian`] into `work`'s readings
    /// and derivatives, whose storage (and that of the dual numbers) is
    /// kept from one row to the next: the same numbers.
    pub(crate) fn observe_point_jacobian_into(
        &self,
        x: &[f64],
        m: &[f64],
        point: Option<&[f64]>,
        work: &mut ObserveJacobian,
    ) {
        let (nx, nm, ny) = (x.len(), m.len(), self.len());
        let ObserveJacobian {
            y,
            dx,
            dm,
            xd,
            md,
            out,
        } = work;
        y.clear();
        y.resize(ny, 0.0);
        self.observe_point(x, m, point, y);
        // (Every entry of both is written below.)
        if dx.shape() != (ny, nx) {
            *dx = DMatrix::zeros(ny, nx);
        }
        if dm.shape() != (ny, nm) {
            *dm = DMatrix::zeros(ny, nm);
        }
        xd.clear();
        xd.extend(x.iter().map(|&v| Dual64::from(v)));
        md.clear();
        md.extend(m.iter().map(|&v| Dual64::from(v)));
        out.clear();
        out.resize(ny, Dual64::from(0.0));
        for j in 0..nx + nm {
            if j < nx {
                xd[j] = Dual64::from(x[j]).derivative();
            } else {
                md[j - nx] = Dual64::from(m[j - nx]).derivative();
            }
            self.observe_point(xd, md, point, out);
            for (i, o) in out.iter().enumerate() {
                if j < nx {
                    dx[(i, j)] = o.eps;
                } else {
                    dm[(i, j - nx)] = o.eps;
                }
            }
            if j < nx {
                xd[j] = Dual64::from(x[j]);
            } else {
                md[j - nx] = Dual64::from(m[j - nx]);
            }
        }
    }

    /// The base-frame tool coordinates behind readings `y` of the whole tool
    /// (`None` for any other model: its readings are compared as read).
    pub fn to_base(&self, y: &[f64], m: &[f64]) -> Option<Vec<f64>> {
        if !self.is_whole_tool() {
            return None;
        }
        Some(match self.frame {
            Frame::Base => y.to_vec(),
            _ => frame::to_base(self.tool, y, &m[self.n_own..]),
        })
    }

    /// The model's parameters `own` (its own, the frame's ignored) with the
    /// frame found by rigid registration of the readings onto those of tools
    /// at `predicted` (Kabsch/Horn, [`crate::measurement::frame::register`]): a start near
    /// the solution wherever the instrument stands. Models whose readings are
    /// not whole positions (a subset of axes) keep the frame of `own`.
    pub fn registered(
        &self,
        own: &[f64],
        predicted: &[Vec<f64>],
        measured: &[Vec<f64>],
    ) -> Result<Vec<f64>> {
        let mut m = own.to_vec();
        if self.frame_range().is_empty() {
            return Ok(m);
        }
        let positions = match &self.instrument {
            Instrument::Tool { .. } => self.is_whole_tool(),
            Instrument::Targets { .. } => true,
            Instrument::BallBar { .. } | Instrument::Probe => false,
        };
        if !positions {
            return Ok(m);
        }
        // Readings of the predicted tools with the instrument in the base
        // frame, registered onto the measured readings.
        let base = self.clone().in_frame(Frame::Base)?;
        let own_only = &m[..self.n_own];
        let reference: Vec<Vec<f64>> = predicted
            .iter()
            .map(|x| {
                let mut y = vec![0.0; self.len()];
                base.observe(x, own_only, &mut y);
                y
            })
            .collect();
        let f = frame::register(self.frame_layout(), &reference, measured)?;
        m[self.n_own..].copy_from_slice(&f);
        Ok(m)
    }
}

/// The readings `y` and their derivatives `dx` (by the tool's coordinates)
/// and `dm` (by the model's parameters) of
/// [`MeasurementModel::observe_point_jacobian_into`], with the dual numbers
/// it evaluates: kept from one row to the next.
#[derive(Debug)]
pub(crate) struct ObserveJacobian {
    pub(crate) y: Vec<f64>,
    pub(crate) dx: DMatrix<f64>,
    pub(crate) dm: DMatrix<f64>,
    xd: Vec<Dual64>,
    md: Vec<Dual64>,
    out: Vec<Dual64>,
}

impl Default for ObserveJacobian {
    fn default() -> Self {
        Self {
            y: vec![],
            dx: DMatrix::zeros(0, 0),
            dm: DMatrix::zeros(0, 0),
            xd: vec![],
            md: vec![],
            out: vec![],
        }
    }
}
