//! Height maps in the firmware's own format (`--physical`): the nozzle's Z
//! error that the firmware's values leave over the bed, on the grid of a
//! round bed's levelling mesh, as the firmware stores a mesh it probed:
//! Klipper's `[bed_mesh <profile>]` (the keys `SAVE_CONFIG` writes,
//! `bed_mesh.py`'s `ProfileManager`), RepRapFirmware's `heightmap.csv`
//! (`HeightMap::SaveToFile`, format v2) and Marlin's bilinear grid as
//! `M421 I J Z` lines.
//!
//! Every firmware adds its mesh's value to the commanded Z (a high bed
//! reads positive), so a node holds minus the nozzle's Z error there: a
//! nozzle that lands 0.05 mm low is a bed 0.05 mm high. The values are
//! those on the bed (the first layer); the firmware's fade, where set,
//! takes them out higher up.
//!
//! The grid is Klipper's for a round bed (`generate_points`): an odd count
//! of nodes across, their spacing the radius's share floored to 0.01 mm, so
//! that every format writes its coordinates exactly. The nodes a firmware
//! would not probe (outside the radius) are as that firmware leaves them:
//! Klipper repeats each row's outermost value, RepRapFirmware writes them
//! unprobed (`0`, extrapolated on loading), Marlin's lines repeat the row's
//! outermost value as Klipper does (its `G29` extrapolates instead).
//!
//! Each format has its reader here too, by the firmware's own parsing
//! rules, for the tests and for reading a map back.

use super::physical::{self, PhysicalFit};
use crate::description::Mech;
use crate::error::{Error, Result};
use crate::invalid;
use pkmcal::Params;
use std::fmt::Write as _;

/// The firmware whose format a map is written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Klipper's `[bed_mesh <profile>]` section.
    Klipper,
    /// RepRapFirmware's `heightmap.csv`.
    RepRap,
    /// Marlin's `M421 I J Z` lines (bilinear levelling).
    Marlin,
}

/// Klipper's interpolation of a mesh profile (`[bed_mesh]`'s `mesh_pps`,
/// `algorithm`, `bicubic_tension`).
#[derive(Debug, Clone, PartialEq)]
pub struct KlipperInterpolation {
    /// Points interpolated per segment in x and y.
    pub pps: [u32; 2],
    /// `lagrange` or `bicubic` (`direct` with no points per segment).
    pub algo: String,
    /// The bicubic tension.
    pub tension: f64,
}

impl KlipperInterpolation {
    /// Klipper's defaults for `count` nodes across (`mesh_pps: 2, 2`,
    /// `lagrange` up to 6 nodes and `bicubic` above, which Klipper asks
    /// for there, tension 0.2).
    pub fn defaults(count: usize) -> Self {
        KlipperInterpolation {
            pps: [2, 2],
            algo: if count > 6 { "bicubic" } else { "lagrange" }.into(),
            tension: 0.2,
        }
    }
}

/// The name of the Klipper profile written.
pub const KLIPPER_PROFILE: &str = "pkmcal";
/// The version of Klipper's mesh profiles (`PROFILE_VERSION`).
pub const KLIPPER_PROFILE_VERSION: u32 = 1;
/// RepRapFirmware's first line of a height map (`HeightMapComment`).
pub const RRF_HEADER: &str = "RepRapFirmware height map file v2";
/// RepRapFirmware's label lines, oldest first (`HeightMapLabelLines`); it
/// writes the last.
pub const RRF_LABELS: [&str; 3] = [
    "xmin,xmax,ymin,ymax,radius,spacing,xnum,ynum",
    "xmin,xmax,ymin,ymax,radius,xspacing,yspacing,xnum,ynum",
    "axis0,axis1,min0,max0,min1,max1,radius,spacing0,spacing1,num0,num1",
];

/// Nodes across the mesh by default: Klipper's `round_probe_count`.
pub const MESH_POINTS: usize = 5;
/// The most nodes across: RepRapFirmware's smaller boards hold 441 nodes.
pub const MAX_MESH_POINTS: usize = 21;
/// A node this close outside the radius is on it (mm): the nodes' sums
/// leave their last bits.
const ON_CIRCLE_MM: f64 = 1e-9;
/// The least spacing of the nodes (mm): Klipper refuses below 1 mm.
const MIN_SPACING_MM: f64 = 1.0;

/// A count of nodes across a mesh, each way: 3 to [`MAX_MESH_POINTS`] (a
/// round mesh's must also be odd: [`round_mesh_points`]).
pub fn mesh_points(n: usize) -> std::result::Result<usize, String> {
    if (3..=MAX_MESH_POINTS).contains(&n) {
        Ok(n)
    } else {
        Err(format!(
            "{n} nodes across: a mesh has 3 to {MAX_MESH_POINTS} nodes each way"
        ))
    }
}

/// A count of nodes across a round mesh: odd (a round bed's grid has a
/// centre node), 3 to [`MAX_MESH_POINTS`].
pub fn round_mesh_points(n: usize) -> std::result::Result<usize, String> {
    if n % 2 == 1 && (3..=MAX_MESH_POINTS).contains(&n) {
        Ok(n)
    } else {
        Err(format!(
            "{n} nodes across: a round bed's mesh has an odd count from 3 to {MAX_MESH_POINTS}"
        ))
    }
}

/// The nodes across a round mesh: the user's `given` count (an even one
/// refused as theirs, [`pkmcal::Field::MeshPoints`], which a front end
/// words as its option), else `default`.
pub fn round_count(given: Option<usize>, default: usize) -> Result<usize> {
    match given {
        Some(n) => round_mesh_points(n).map_err(|p| {
            Error::from(pkmcal::Error::Request(pkmcal::RequestError::invalid(
                pkmcal::Field::MeshPoints,
                format!("{p} (this printer's mesh is round)"),
            )))
        }),
        None => Ok(default),
    }
}

/// Where a round bed's mesh nodes are.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshLayout {
    /// The format it is written in.
    pub format: MeshFormat,
    /// The nodes the firmware probes lie within this radius of the origin
    /// (mm, floored to 0.1 mm as Klipper floors it).
    pub radius: f64,
    /// Nodes across, in x and in y (odd).
    pub count: usize,
    /// The mesh's centre (mm; Klipper's `mesh_origin`).
    pub origin: [f64; 2],
    /// Klipper's interpolation (Klipper only).
    pub klipper: KlipperInterpolation,
    /// A rectangular mesh's corners and counts (Klipper's `mesh_min`,
    /// `mesh_max`, `probe_count`), where the mesh is not round; its nodes
    /// beyond `radius` of the bed's centre (the build volume's, which the
    /// nozzle cannot reach) take their row's outermost value.
    pub rect: Option<Rect>,
}

/// A rectangular mesh as Klipper lays it out (`generate_points`).
#[derive(Debug, Clone, PartialEq)]
pub struct Rect {
    /// The first node (mm).
    pub min: [f64; 2],
    /// The last node as configured (mm); the last written is `min` plus
    /// the spacing times the count less one.
    pub max: [f64; 2],
    /// Nodes in x and in y (at least 3 each).
    pub counts: [usize; 2],
}

impl MeshLayout {
    /// A round mesh of `count` nodes across a circle of `radius` about the
    /// bed's centre, with Klipper's default interpolation.
    pub fn round(format: MeshFormat, radius: f64, count: usize) -> Result<Self> {
        let count = round_mesh_points(count).map_err(Error::Content)?;
        let layout = MeshLayout {
            format,
            radius: (radius * 10.0).floor() / 10.0,
            count,
            origin: [0.0, 0.0],
            klipper: KlipperInterpolation::defaults(count),
            rect: None,
        };
        if !(layout.radius.is_finite() && layout.spacing() >= MIN_SPACING_MM) {
            invalid!(
                "a mesh of {count} nodes across a radius of {radius} mm puts them less than {MIN_SPACING_MM} mm apart: give fewer nodes"
            );
        }
        Ok(layout)
    }

    /// A rectangular mesh of `counts` nodes from `min` to `max` (Klipper's
    /// `mesh_min`, `mesh_max`, `probe_count`), its nodes beyond `radius`
    /// of the bed's centre filled from their row, with Klipper's default
    /// interpolation.
    pub fn rectangular(
        format: MeshFormat,
        min: [f64; 2],
        max: [f64; 2],
        counts: [usize; 2],
        radius: f64,
    ) -> Result<Self> {
        if counts.iter().any(|&n| !(3..=MAX_MESH_POINTS).contains(&n)) {
            invalid!(
                "{} x {} nodes: a rectangular mesh has 3 to {MAX_MESH_POINTS} nodes each way",
                counts[0],
                counts[1]
            );
        }
        if !(min.iter().chain(&max).all(|v| v.is_finite()) && max[0] > min[0] && max[1] > min[1]) {
            invalid!(
                "mesh_min {}, {} and mesh_max {}, {}: the maximum must exceed the minimum each way",
                min[0],
                min[1],
                max[0],
                max[1]
            );
        }
        let layout = MeshLayout {
            format,
            radius,
            count: counts[0],
            origin: [0.0, 0.0],
            klipper: KlipperInterpolation::defaults(counts[0].max(counts[1])),
            rect: Some(Rect { min, max, counts }),
        };
        if layout.spacings().iter().any(|s| *s < MIN_SPACING_MM) {
            invalid!(
                "a mesh of {} x {} nodes from ({}, {}) to ({}, {}) puts them less than {MIN_SPACING_MM} mm apart: give fewer nodes",
                counts[0],
                counts[1],
                min[0],
                min[1],
                max[0],
                max[1]
            );
        }
        Ok(layout)
    }

    /// The nodes' spacing (mm): Klipper's, the diameter's share floored to
    /// 0.01 mm (a rectangular mesh's: in x).
    pub fn spacing(&self) -> f64 {
        self.spacings()[0]
    }

    /// The nodes' spacing in x and in y (mm), floored to 0.01 mm as
    /// Klipper floors them.
    pub fn spacings(&self) -> [f64; 2] {
        let floor = |d: f64| (d * 100.0).floor() / 100.0;
        match &self.rect {
            None => {
                let s = floor(2.0 * self.radius / (self.count - 1) as f64);
                [s, s]
            }
            Some(r) => [0, 1].map(|k| floor((r.max[k] - r.min[k]) / (r.counts[k] - 1) as f64)),
        }
    }

    /// Nodes in x and in y.
    pub fn counts(&self) -> [usize; 2] {
        self.rect.as_ref().map_or([self.count; 2], |r| r.counts)
    }

    /// The nodes' coordinates along x (`axis` 0) or y (1), lowest first
    /// (mm).
    pub fn nodes(&self, axis: usize) -> Vec<f64> {
        match &self.rect {
            None => self
                .offsets()
                .iter()
                .map(|d| self.origin[axis] + d)
                .collect(),
            Some(r) => {
                let s = self.spacings()[axis];
                (0..r.counts[axis])
                    .map(|i| r.min[axis] + i as f64 * s)
                    .collect()
            }
        }
    }

    /// The mesh in words: its nodes, their spacing and where they lie.
    pub fn words(&self) -> String {
        let [nx, ny] = self.counts();
        let [sx, sy] = self.spacings();
        match &self.rect {
            None => format!(
                "{nx} x {ny} nodes {sx:.2} mm apart within {} mm",
                self.radius
            ),
            // Klipper's nodes to its own 0.01 mm (its spacing is floored
            // there), not a sum's last bits.
            Some(r) => format!(
                "{nx} x {ny} nodes {sx:.2} by {sy:.2} mm apart from ({}, {}) to ({}, {})",
                r.min[0],
                r.min[1],
                ((r.min[0] + sx * (nx - 1) as f64) * 100.0).round() / 100.0,
                ((r.min[1] + sy * (ny - 1) as f64) * 100.0).round() / 100.0
            ),
        }
    }

    /// The nodes' coordinates along x (or y) relative to the origin, from
    /// the lowest.
    pub fn offsets(&self) -> Vec<f64> {
        let s = self.spacing();
        let half = (self.count / 2) as f64;
        (0..self.count).map(|i| (i as f64 - half) * s).collect()
    }

    /// Whether the node `dx`, `dy` from the origin is one the firmware
    /// probes: within the radius (Klipper's `generate_points`; a
    /// RepRapFirmware map's nodes on the circle are written too, and
    /// loaded as given).
    pub fn probed(&self, dx: f64, dy: f64) -> bool {
        (dx * dx + dy * dy).sqrt() <= self.radius + ON_CIRCLE_MM
    }
}

/// A height map: the value the firmware adds to Z at each node.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightMap {
    /// The nodes' x (mm), lowest first.
    pub xs: Vec<f64>,
    /// The nodes' y (mm), lowest first.
    pub ys: Vec<f64>,
    /// By row (y) then column (x): the value at each node (mm); `None`
    /// where the firmware would not probe.
    pub z: Vec<Vec<Option<f64>>>,
    /// Their standard deviations from the fit's uncertainty (mm), where
    /// known.
    pub sd: Vec<Vec<Option<f64>>>,
}

impl HeightMap {
    /// The values given, each row's unprobed nodes taking the nearest
    /// probed one's value in that row (Klipper's rule for a round bed);
    /// a row with none, the nearest row's.
    pub fn filled(&self) -> Vec<Vec<f64>> {
        let rows: Vec<Option<Vec<f64>>> = self
            .z
            .iter()
            .map(|row| {
                let first = row.iter().position(Option::is_some)?;
                let last = row.iter().rposition(Option::is_some)?;
                Some(
                    (0..row.len())
                        .map(|i| row[i.clamp(first, last)].unwrap_or(0.0))
                        .collect(),
                )
            })
            .collect();
        (0..rows.len())
            .map(|j| {
                (0..rows.len())
                    .filter_map(|k| rows[k].as_ref().map(|r| (j.abs_diff(k), r)))
                    .min_by_key(|(d, _)| *d)
                    .map(|(_, r)| r.clone())
                    .unwrap_or_else(|| vec![0.0; self.xs.len()])
            })
            .collect()
    }

    /// The probed values.
    pub fn values(&self) -> Vec<f64> {
        self.z.iter().flatten().flatten().copied().collect()
    }

    /// The largest standard deviation of a node's value (mm), if known.
    pub fn largest_sd(&self) -> Option<f64> {
        self.sd.iter().flatten().flatten().copied().reduce(f64::max)
    }
}

/// The map of what the firmware's values `fw_params` (and bed `fw_bed`,
/// where the firmware tilts Z) leave on the fitted printer `fit`: at each
/// node of `layout` the firmware probes, minus the nozzle's Z error over the
/// bed for a nozzle sent to that node on the bed; each with its standard
/// deviation from the fit's uncertainty ([`physical::posterior_draws`]).
pub fn residual_map(
    fit: &PhysicalFit,
    fw_mech: &Mech,
    fw_params: &Params,
    fw_bed: Option<&[f64]>,
    layout: &MeshLayout,
) -> Result<HeightMap> {
    let xs = layout.nodes(0);
    let ys = layout.nodes(1);
    let (dxs, dys) = match layout.rect {
        None => (layout.offsets(), layout.offsets()),
        Some(_) => (xs.clone(), ys.clone()),
    };
    let mut nodes = vec![];
    for (j, dy) in dys.iter().enumerate() {
        for (i, dx) in dxs.iter().enumerate() {
            if layout.probed(*dx, *dy) {
                nodes.push((j, i, [xs[i], ys[j], 0.0]));
            }
        }
    }
    let targets: Vec<[f64; 3]> = nodes.iter().map(|n| n.2).collect();
    let cal = &fit.study.calibration;
    let nozzle = fit.delta.nozzle();
    // The firmware's commands for the nodes, the same for every draw.
    let sent = physical::Sent::new(fw_mech, fw_params, fw_bed, &targets)
        .map_err(|e| e.context("a node of the height map"))?;
    // Each node's correction on the printer `params` (bed `bed`), and the
    // printer's joints there; from `starts` (the fitted printer's) where
    // given.
    let at = |params: &Params,
              bed: &[f64],
              starts: Option<&[Vec<f64>]>|
     -> Result<(Vec<f64>, physical::Joints)> {
        let printer = physical::Printer {
            mech: &fit.mech,
            params,
            bed,
            nozzle,
        };
        let (e, q) = sent
            .nozzle_errors(&printer, starts)
            .map_err(|e| e.context("a node of the height map"))?;
        Ok((e.into_iter().map(|e| -e[2]).collect(), q))
    };
    let (best, joints) = at(&cal.params, &cal.measurement, None)?;
    let mut sum = vec![0.0; targets.len()];
    let mut sq = vec![0.0; targets.len()];
    let draws = physical::posterior_draws(fit, physical::CUBE_DRAWS, physical::CUBE_SEED)?;
    for (p, bed) in &draws {
        for (k, v) in at(p, bed, Some(&joints))?.0.into_iter().enumerate() {
            sum[k] += v;
            sq[k] += v * v;
        }
    }
    let n = draws.len().max(2) as f64;
    let mut z = vec![vec![None; xs.len()]; ys.len()];
    let mut sd = z.clone();
    for (k, (j, i, _)) in nodes.iter().enumerate() {
        z[*j][*i] = Some(best[k]);
        sd[*j][*i] = Some(((sq[k] - sum[k] * sum[k] / n) / (n - 1.0)).max(0.0).sqrt());
    }
    Ok(HeightMap { xs, ys, z, sd })
}

/// The map in `layout`'s format; `comment` (lines, without their comment
/// marks) heads it where the format has comments.
pub fn write(map: &HeightMap, layout: &MeshLayout, comment: &str) -> String {
    match layout.format {
        MeshFormat::Klipper => write_klipper(map, layout, comment),
        MeshFormat::RepRap => write_reprap(map, layout),
        MeshFormat::Marlin => write_marlin(map, comment),
    }
}

/// Klipper's float as Python's `str` writes a whole or short number
/// (`-90.0`, `0.2`).
fn py_float(v: f64) -> String {
    format!("{v:?}")
}

fn write_klipper(map: &HeightMap, layout: &MeshLayout, comment: &str) -> String {
    let mut s = String::new();
    for line in comment.lines() {
        let _ = writeln!(s, "# {line}");
    }
    let k = &layout.klipper;
    let _ = writeln!(
        s,
        "[bed_mesh {KLIPPER_PROFILE}]\nversion = {KLIPPER_PROFILE_VERSION}\npoints ="
    );
    for row in map.filled() {
        let cells: Vec<String> = row.iter().map(|v| format!("{v:.6}")).collect();
        let _ = writeln!(s, "\t  {}", cells.join(", "));
    }
    let (x0, x1) = (map.xs[0], map.xs[map.xs.len() - 1]);
    let (y0, y1) = (map.ys[0], map.ys[map.ys.len() - 1]);
    let _ = writeln!(
        s,
        "x_count = {}\ny_count = {}\nmesh_x_pps = {}\nmesh_y_pps = {}\nalgo = {}\ntension = {}\n\
         min_x = {}\nmax_x = {}\nmin_y = {}\nmax_y = {}",
        map.xs.len(),
        map.ys.len(),
        k.pps[0],
        k.pps[1],
        k.algo,
        py_float(k.tension),
        py_float(round2(x0)),
        py_float(round2(x1)),
        py_float(round2(y0)),
        py_float(round2(y1))
    );
    s
}

/// Rounded to 0.01 mm (the grid's coordinates are on it; this takes off
/// the sum's last bits).
fn round2(v: f64) -> f64 {
    let r = (v * 100.0).round() / 100.0;
    if r == 0.0 { 0.0 } else { r }
}

fn write_reprap(map: &HeightMap, layout: &MeshLayout) -> String {
    let v = map.values();
    let n = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / n;
    let dev = (v.iter().map(|x| x * x).sum::<f64>() / n - mean * mean)
        .max(0.0)
        .sqrt();
    let min = v.iter().copied().fold(f64::INFINITY, f64::min);
    let max = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let s_ = layout.spacing();
    let mut s = format!(
        "{RRF_HEADER}, min error {min:.3}, max error {max:.3}, mean {mean:.3}, deviation {dev:.3}\n{}\n",
        RRF_LABELS[2]
    );
    let _ = writeln!(
        s,
        "X,Y,{:.2},{:.2},{:.2},{:.2},{:.2},{s_:.2},{s_:.2},{},{}",
        map.xs[0],
        map.xs[map.xs.len() - 1],
        map.ys[0],
        map.ys[map.ys.len() - 1],
        layout.radius,
        map.xs.len(),
        map.ys.len()
    );
    for row in &map.z {
        let cells: Vec<String> = row
            .iter()
            .map(|v| match v {
                Some(v) => format!("{v:7.3}"),
                None => "      0".into(),
            })
            .collect();
        let _ = writeln!(s, "{}", cells.join(","));
    }
    s
}

fn write_marlin(map: &HeightMap, comment: &str) -> String {
    let mut s = String::new();
    for line in comment.lines() {
        let _ = writeln!(s, "; {line}");
    }
    for (j, row) in map.filled().iter().enumerate() {
        for (i, v) in row.iter().enumerate() {
            let _ = writeln!(s, "M421 I{i} J{j} Z{v:.4}");
        }
    }
    s
}

/// A height map as read back: its nodes and values (`None` where unset).
#[derive(Debug, Clone, PartialEq)]
pub struct ReadMap {
    /// The nodes' x (mm), lowest first.
    pub xs: Vec<f64>,
    /// The nodes' y (mm), lowest first.
    pub ys: Vec<f64>,
    /// By row (y) then column (x).
    pub z: Vec<Vec<Option<f64>>>,
}

/// A Klipper mesh profile `[bed_mesh <name>]` read from `text` as
/// Klipper's `configfile` and `ProfileManager` read it: Python's
/// configparser (`key = value` or `key: value`, a value continued on
/// indented lines, `#` and `;` comment lines), the profile's `version`
/// checked, `points` split at newlines then commas into floats
/// (`getlists(seps=(',', '\n'))`), every `PROFILE_OPTIONS` key required.
pub fn read_klipper(text: &str, name: &str) -> Result<ReadMap> {
    let section = format!("bed_mesh {name}");
    let mut current: Option<String> = None;
    let mut options: Vec<(String, String)> = vec![];
    for (no, line) in text.lines().enumerate() {
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') || trimmed.starts_with(';') {
            continue;
        }
        if line.starts_with([' ', '\t']) {
            if current.as_deref() == Some(section.as_str())
                && let Some(last) = options.last_mut()
            {
                last.1.push('\n');
                last.1.push_str(trimmed);
            }
            continue;
        }
        if let Some(rest) = trimmed.strip_prefix('[') {
            let Some(name) = rest.strip_suffix(']') else {
                invalid!("line {}: `{trimmed}` is not a section header", no + 1);
            };
            current = Some(name.trim().to_string());
            continue;
        }
        if current.as_deref() != Some(section.as_str()) {
            continue;
        }
        let Some(at) = trimmed.find(['=', ':']) else {
            invalid!("line {}: `{trimmed}` is not `key = value`", no + 1);
        };
        options.push((
            trimmed[..at].trim().to_lowercase(),
            trimmed[at + 1..].trim().to_string(),
        ));
    }
    let get = |key: &str| -> Result<&str> {
        options
            .iter()
            .rev()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
            .ok_or_else(|| Error::Content(format!("[{section}] has no `{key}`")))
    };
    let int = |key: &str| -> Result<i64> {
        get(key)?
            .parse::<i64>()
            .map_err(|_| Error::Content(format!("[{section}] {key} is not an integer")))
    };
    let float = |key: &str| -> Result<f64> {
        get(key)?
            .parse::<f64>()
            .map_err(|_| Error::Content(format!("[{section}] {key} is not a number")))
    };
    if int("version")? != i64::from(KLIPPER_PROFILE_VERSION) {
        invalid!("[{section}] is not a version {KLIPPER_PROFILE_VERSION} profile");
    }
    for key in ["mesh_x_pps", "mesh_y_pps"] {
        int(key)?;
    }
    float("tension")?;
    get("algo")?;
    let (nx, ny) = (int("x_count")?, int("y_count")?);
    let (x0, x1, y0, y1) = (
        float("min_x")?,
        float("max_x")?,
        float("min_y")?,
        float("max_y")?,
    );
    let rows: Vec<Vec<Option<f64>>> = get("points")?
        .split('\n')
        .map(str::trim)
        .filter(|r| !r.is_empty())
        .map(|r| {
            r.split(',')
                .map(str::trim)
                .filter(|p| !p.is_empty())
                .map(|p| {
                    p.parse::<f64>().map(Some).map_err(|_| {
                        Error::Content(format!("[{section}] points: `{p}` is not a number"))
                    })
                })
                .collect::<Result<Vec<_>>>()
        })
        .collect::<Result<_>>()?;
    if nx < 2 || ny < 2 || rows.len() as i64 != ny || rows.iter().any(|r| r.len() as i64 != nx) {
        invalid!("[{section}] points is not {ny} rows of {nx}");
    }
    let axis = |a: f64, b: f64, n: i64| -> Vec<f64> {
        (0..n)
            .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
            .collect()
    };
    Ok(ReadMap {
        xs: axis(x0, x1, nx),
        ys: axis(y0, y1, ny),
        z: rows,
    })
}

/// C's `strtof` prefix of `s` as RepRapFirmware's `SafeStrtof` reads it
/// (sign, digits, a point, digits, an exponent): the value and the bytes
/// taken (0: no number).
fn strtof(s: &str) -> (f64, usize) {
    let b = s.as_bytes();
    let mut k = 0;
    if k < b.len() && (b[k] == b'+' || b[k] == b'-') {
        k += 1;
    }
    let digits = |mut k: usize| {
        while k < b.len() && b[k].is_ascii_digit() {
            k += 1;
        }
        k
    };
    let int_end = digits(k);
    let mut end = int_end;
    let mut any = int_end > k;
    if end < b.len() && b[end] == b'.' {
        let frac_end = digits(end + 1);
        any |= frac_end > end + 1;
        end = frac_end;
    }
    if !any {
        return (0.0, 0);
    }
    if end < b.len() && (b[end] == b'e' || b[end] == b'E') {
        let mut e = end + 1;
        if e < b.len() && (b[e] == b'+' || b[e] == b'-') {
            e += 1;
        }
        let exp_end = digits(e);
        if exp_end > e {
            end = exp_end;
        }
    }
    (s[..end].parse().unwrap_or(0.0), end)
}

/// A RepRapFirmware `heightmap.csv` read from `text` as
/// `HeightMap::LoadFromFile` reads it: the first line starting with its
/// header, the second one of its label lines (any version), the grid's
/// parameters, then a row per y of `num0` values, a bare `0` an unprobed
/// node.
pub fn read_reprap(text: &str) -> Result<ReadMap> {
    let mut lines = text.lines();
    let mut next = |what: &str| {
        lines
            .next()
            .ok_or_else(|| Error::Content(format!("the height map ends before its {what}")))
    };
    if !next("header")?.starts_with(RRF_HEADER) {
        invalid!("bad header line or wrong version header");
    }
    let label = next("label line")?;
    let Some(version) = RRF_LABELS.iter().position(|l| label.starts_with(l)) else {
        invalid!("bad label line");
    };
    let params = next("grid parameters")?;
    let mut fields: Vec<&str> = params.split(',').collect();
    if version == 2 {
        if fields.len() < 2 || fields[0].len() != 1 || fields[1].len() != 1 {
            invalid!("failed to parse grid parameters");
        }
        fields.drain(..2);
    }
    let wanted = if version == 0 { 8 } else { 9 };
    if fields.len() != wanted {
        invalid!("failed to parse grid parameters");
    }
    let num = |s: &str| -> Result<f64> {
        let (v, used) = strtof(s);
        if used == 0 {
            invalid!("failed to parse grid parameters");
        }
        Ok(v)
    };
    let (min0, max0, min1, max1) = (
        num(fields[0])?,
        num(fields[1])?,
        num(fields[2])?,
        num(fields[3])?,
    );
    let s0 = num(fields[5])?;
    let s1 = if version == 0 { s0 } else { num(fields[6])? };
    let count = |s: &str| -> Result<usize> {
        s.trim_end()
            .parse::<usize>()
            .map_err(|_| Error::Content("failed to parse grid parameters".into()))
    };
    let (n0, n1) = (count(fields[wanted - 2])?, count(fields[wanted - 1])?);
    if n0 == 0 || n1 == 0 || s0 < 0.1 || s1 < 0.1 || max0 - min0 < 1.0 || max1 - min1 < 1.0 {
        invalid!("invalid grid");
    }
    let mut z = vec![];
    for row in 0..n1 {
        let line = next("rows")?;
        let mut p = 0;
        let mut out = vec![];
        for _ in 0..n0 {
            let b = line.as_bytes();
            while p < b.len() && (b[p] == b' ' || b[p] == b'\t') {
                p += 1;
            }
            if p < b.len() && b[p] == b'0' && (p + 1 == b.len() || b[p + 1] == b',') {
                out.push(None);
                p += 1;
            } else {
                let (v, used) = strtof(&line[p..]);
                if used == 0 {
                    invalid!("number expected at line {} column {}", row + 3, p + 1);
                }
                out.push(Some(v));
                p += used;
            }
            if p < b.len() && b[p] == b',' {
                p += 1;
            }
        }
        z.push(out);
    }
    Ok(ReadMap {
        xs: (0..n0).map(|i| min0 + i as f64 * s0).collect(),
        ys: (0..n1).map(|j| min1 + j as f64 * s1).collect(),
        z,
    })
}

/// Marlin's `M421 I J Z` lines read from `text` onto a bilinear grid of
/// `count` nodes across (`GRID_MAX_POINTS_X` and `_Y`) whose nodes are at
/// `xs`, `ys`: comments (`;`) dropped, each line with I, J and Z in the
/// grid setting its node (a later line wins), an index outside it refused
/// as Marlin refuses it.
pub fn read_marlin(text: &str, xs: &[f64], ys: &[f64]) -> Result<ReadMap> {
    let mut z = vec![vec![None; xs.len()]; ys.len()];
    for (no, line) in text.lines().enumerate() {
        let code = line.split(';').next().unwrap_or("").trim();
        let mut words = code.split_whitespace();
        if !words.next().is_some_and(|w| w.eq_ignore_ascii_case("M421")) {
            continue;
        }
        let (mut i, mut j, mut v) = (None, None, None);
        for w in words {
            let (letter, value) = w.split_at(1);
            match letter.to_ascii_uppercase().as_str() {
                "I" => i = value.parse::<i64>().ok(),
                "J" => j = value.parse::<i64>().ok(),
                "Z" => v = value.parse::<f64>().ok(),
                _ => {}
            }
        }
        let (Some(i), Some(j), Some(v)) = (i, j, v) else {
            invalid!("line {}: M421 needs I, J and Z", no + 1);
        };
        if i < 0 || j < 0 || i as usize >= xs.len() || j as usize >= ys.len() {
            invalid!("line {}: I{i} J{j} is outside the mesh", no + 1);
        }
        z[j as usize][i as usize] = Some(v);
    }
    Ok(ReadMap {
        xs: xs.to_vec(),
        ys: ys.to_vec(),
        z,
    })
}

/// Klipper's mesh for a height map: the configuration's round `[bed_mesh]`
/// where it has one (`mesh_radius`, `mesh_origin`, `round_probe_count`,
/// `mesh_pps`, `algorithm`, `bicubic_tension`), else `radius` and
/// Klipper's defaults; `count` nodes across where given. The algorithm is
/// as Klipper checks it: `bicubic` above 6 nodes (`lagrange` oscillates),
/// `lagrange` below 4, `direct` with no points per segment.
pub fn klipper_layout(
    ini: &super::klipper::Ini,
    radius: f64,
    count: Option<usize>,
) -> Result<MeshLayout> {
    let section = "bed_mesh";
    let get = |key: &str| ini.get(section, key).map(|e| e.value.trim().to_string());
    let own_radius = ini.length(section, "mesh_radius", true)?;
    let config_count = match get("round_probe_count") {
        Some(v) => Some(v.parse::<usize>().map_err(|_| {
            Error::Content(format!(
                "[bed_mesh] round_probe_count = `{v}` is not a count of nodes"
            ))
        })?),
        None => None,
    };
    let pair = |key: &str| -> Result<Option<Vec<f64>>> {
        let Some(v) = get(key) else { return Ok(None) };
        let parts: Option<Vec<f64>> = v
            .split(',')
            .map(|p| p.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
            .collect();
        match parts {
            Some(p) if (1..=2).contains(&p.len()) => Ok(Some(p)),
            _ => invalid!("[bed_mesh] {key} = `{v}` is not one or two numbers"),
        }
    };
    let corners = match (own_radius, pair("mesh_min")?, pair("mesh_max")?) {
        (None, Some(lo), Some(hi)) if lo.len() == 2 && hi.len() == 2 => {
            Some(([lo[0], lo[1]], [hi[0], hi[1]]))
        }
        (None, Some(_), Some(_)) => {
            invalid!("[bed_mesh] mesh_min and mesh_max must be two numbers each (x, y)")
        }
        _ => None,
    };
    let mut layout = match corners {
        // Klipper's rectangular bed: `probe_count` (one or two whole
        // numbers, 3 by default) nodes from `mesh_min` to `mesh_max`.
        Some((lo, hi)) => {
            let counts = match (count, pair("probe_count")?) {
                (Some(n), _) => [n, n],
                (None, None) => [3, 3],
                (None, Some(p)) => {
                    let whole = |x: f64| -> Result<usize> {
                        if x.fract() == 0.0 && (3.0..=MAX_MESH_POINTS as f64).contains(&x) {
                            Ok(x as usize)
                        } else {
                            invalid!(
                                "[bed_mesh] probe_count must be whole numbers from 3 to {MAX_MESH_POINTS}"
                            )
                        }
                    };
                    [whole(p[0])?, whole(*p.last().unwrap_or(&p[0]))?]
                }
            };
            MeshLayout::rectangular(MeshFormat::Klipper, lo, hi, counts, radius)
        }
        None => MeshLayout::round(
            MeshFormat::Klipper,
            own_radius.unwrap_or(radius),
            // A printer's own mesh beyond the most nodes pkmcal writes (a
            // real configuration probes 23 across) gets a profile of the
            // most: the profile is loaded by its own name, its own count.
            round_count(
                count,
                config_count
                    .filter(|_| own_radius.is_some())
                    .map_or(MESH_POINTS, |n| n.min(MAX_MESH_POINTS)),
            )?,
        ),
    }
    .map_err(|e| e.context("the [bed_mesh] of the configuration"))?;
    if own_radius.is_none() && corners.is_none() {
        return Ok(layout);
    }
    if let Some(o) = pair("mesh_origin")?.filter(|_| corners.is_none()) {
        layout.origin = [o[0], *o.last().unwrap_or(&o[0])];
    }
    if let Some(p) = pair("mesh_pps")? {
        let v = |x: f64| -> Result<u32> {
            if (0.0..=100.0).contains(&x) && x.fract() == 0.0 {
                Ok(x as u32)
            } else {
                invalid!("[bed_mesh] mesh_pps must be whole numbers from 0 to 100")
            }
        };
        layout.klipper.pps = [v(p[0])?, v(*p.last().unwrap_or(&p[0]))?];
    }
    if let Some(a) = get("algorithm") {
        layout.klipper.algo = a.to_lowercase();
    }
    if let Some(t) = ini.number(section, "bicubic_tension")? {
        if !(0.0..=2.0).contains(&t) {
            invalid!("[bed_mesh] bicubic_tension = {t} must be from 0 to 2");
        }
        layout.klipper.tension = t;
    }
    let [most, least] = {
        let [a, b] = layout.counts();
        [a.max(b), a.min(b)]
    };
    let k = &mut layout.klipper;
    if k.pps == [0, 0] {
        k.algo = "direct".into();
    } else if most > 6 && least < 4 {
        invalid!(
            "[bed_mesh] probe_count {}, {}: Klipper interpolates 3 nodes one way and more than 6 the other with neither of its algorithms; give at least 4 each way",
            layout.counts()[0],
            layout.counts()[1]
        );
    } else if most > 6 {
        k.algo = "bicubic".into();
    } else if least < 4 {
        k.algo = "lagrange".into();
    } else if !["lagrange", "bicubic"].contains(&k.algo.as_str()) {
        invalid!(
            "[bed_mesh] algorithm = `{}` is not one Klipper knows (lagrange, bicubic)",
            k.algo
        );
    }
    Ok(layout)
}

/// A height map of what a printer's written values leave, in its
/// firmware's format.
pub struct Written {
    /// The map.
    pub map: HeightMap,
    /// Its mesh.
    pub layout: MeshLayout,
    /// The file's text, with a comment saying where it came from and how
    /// the firmware loads it.
    pub text: String,
}

/// The height map of the nozzle's Z error the written values `fw_params`
/// (bed `fw_bed` where the firmware tilts Z) leave on the fitted printer,
/// in `printer`'s format, `mesh_points` nodes across (its default where
/// `None`); `None` for a firmware that keeps no map pkmcal writes.
pub fn for_printer(
    printer: &dyn super::Firmware,
    fit: &super::physical::PhysicalFit,
    fw_mech: &crate::description::Mech,
    fw_params: &pkmcal::Params,
    fw_bed: Option<&[f64]>,
    source: &str,
    mesh_points: Option<usize>,
) -> Result<Option<Written>> {
    let ld = &fit.delta;
    let Some(layout) = printer.mesh_layout(ld.print_radius(), mesh_points)? else {
        return Ok(None);
    };
    let map = residual_map(fit, fw_mech, fw_params, fw_bed, &layout)?;
    let n = layout.count;
    let (lo, hi) = (map.xs[0], map.xs[map.xs.len() - 1]);
    let how = match layout.format {
        MeshFormat::Klipper => format!(
            "[include] this file in printer.cfg (which needs a [bed_mesh] section), then\n\
             BED_MESH_PROFILE LOAD={KLIPPER_PROFILE}"
        ),
        MeshFormat::RepRap => "load it with G29 S1 P\"<this file>\"".to_string(),
        MeshFormat::Marlin => format!(
            "for bilinear levelling with GRID_MAX_POINTS_X and _Y {n}: run G29 L{lo:.2} R{hi:.2} F{:.2} B{:.2}\n\
             once (the grid's bounds), send these lines, then M420 S1, and M500 to keep them",
            map.ys[0],
            map.ys[n - 1]
        ),
    };
    let mesh = match &layout.rect {
        None => format!(
            "{} of\n({}, {}), each row's outermost value beyond.",
            layout.words(),
            layout.origin[0],
            layout.origin[1],
        ),
        Some(_) => format!(
            "{},\nthose beyond {} mm of the centre (out of the nozzle's reach) their row's outermost.",
            layout.words(),
            layout.radius
        ),
    };
    let comment = format!(
        "pkmcal {}, the physical model, from {source}:\n\
         the nozzle's Z error the written values leave over the bed, as a mesh whose\n\
         value the firmware adds to Z: {mesh}\n{how}",
        env!("CARGO_PKG_VERSION"),
    );
    let text = write(&map, &layout, &comment);
    Ok(Some(Written { map, layout, text }))
}
