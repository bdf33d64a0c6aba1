//! `--report-dir`: the figures (SVG and PNG) and one self-contained
//! `report.html` with the figures inlined, the bundled font embedded and no
//! network resources. Every user-supplied string is escaped.

use crate::description::Mech;
use crate::error::Result;
use crate::figures::{self, Figure, ParamBar};
use base64::Engine;
use pkmcal::identify::{ErrorVectors, RANK_TOL};
use pkmcal::{
    ErrorStats, Measurement, Mechanism, Model, prepare_pose, sample_workspace, tool_covariance,
};
use rayon::prelude::*;
use std::fmt::Write;
use std::path::Path;

/// Every file `--report-dir` writes (checked against the inputs first).
pub const FILES: &[&str] = &[
    "report.html",
    "errors.svg",
    "errors.png",
    "parameters.svg",
    "parameters.png",
    "workspace.svg",
    "workspace.png",
    "maps.svg",
    "maps.png",
    "residuals.svg",
    "residuals.png",
    "singular-values.svg",
    "singular-values.png",
];

/// Most lattice points of the workspace maps (the spacing is coarsened to
/// respect it: 8 mm on the reference, coarser in 6-D).
const MAP_POINTS: usize = 4000;

/// Lattice spacing of the workspace plan view, mm.
const MAP_SPACING_MM: f64 = 8.0;

/// Lattice points of a map slice (about 50 × 50), at most.
const MAP_SLICE_POINTS: f64 = 2500.0;
/// Lattice points of all map slices together (three slices of a spatial
/// tool share them: about 37 × 37 each).
const MAP_TOTAL_POINTS: f64 = 4000.0;
/// Points along each angle of the angle sweeps.
const MAP_SWEEP_POINTS: usize = 41;

/// The error without compensation and the σ of the prediction at a target
/// in the usable workspace (`None` outside it): position only, lengths and
/// angles are not pooled.
fn miss_and_sigma(mech: &Mech, cal: &pkmcal::Calibration, target: &[f64]) -> Option<(f64, f64)> {
    let spec = mech.spec();
    let p = pkmcal::apply::workspace::workspace_point(mech, target).ok()?;
    if p.conditioning < spec.min_conditioning {
        return None;
    }
    let commands: Vec<f64> = spec.actuated.iter().map(|&j| p.q[j]).collect();
    let pose = prepare_pose(mech, &commands, Some(&p.q)).ok()?;
    let (pred, cov) = tool_covariance(
        mech,
        &pose,
        &cal.params,
        cal.model,
        &[],
        &cal.parameter_covariance,
    )
    .ok()?;
    let lengths =
        (0..spec.tool_axes.len()).filter(|&a| spec.tool_units[a] == pkmcal::Unit::Millimetre);
    let miss = lengths
        .clone()
        .map(|a| (pred.x[a] - target[a]).powi(2))
        .sum::<f64>()
        .sqrt();
    let sigma = lengths.map(|a| cov[(a, a)]).sum::<f64>().max(0.0).sqrt();
    Some((miss, sigma))
}

/// Where the axes other than `except` are held: `z = 700 mm, rx = 0 mrad`.
fn held_text(spec: &pkmcal::Spec, centre: &[f64], except: &[usize]) -> String {
    (0..spec.tool_axes.len())
        .filter(|k| !except.contains(k))
        .map(|k| match spec.tool_units[k] {
            pkmcal::Unit::Radian => {
                format!("{} = {} mrad", spec.tool_axes[k], tick(centre[k] * 1e3))
            }
            _ => format!("{} = {} mm", spec.tool_axes[k], tick(centre[k])),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn tick(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.to_string() }
}

/// The maps' data: slices through the workspace centre on each pair of
/// length axes (lattices of about [`MAP_SLICE_POINTS`] each and
/// [`MAP_TOTAL_POINTS`] together) and a sweep along each
/// angle axis, evaluated in parallel.
fn map_data(
    mech: &Mech,
    cal: &pkmcal::Calibration,
    check: &(dyn Fn() -> pkmcal::Result<()> + Sync),
) -> Result<(Vec<figures::MapSlice>, Vec<figures::MapSweep>)> {
    let spec = mech.spec();
    let bx = &spec.workspace_box;
    let centre: Vec<f64> = bx.iter().map(|b| 0.5 * (b[0] + b[1])).collect();
    let lengths: Vec<usize> = (0..spec.tool_axes.len())
        .filter(|&a| spec.tool_units[a] == pkmcal::Unit::Millimetre)
        .collect();
    let angles: Vec<usize> = (0..spec.tool_axes.len())
        .filter(|&a| spec.tool_units[a] == pkmcal::Unit::Radian)
        .collect();
    let mut planes = vec![];
    for (i, &a) in lengths.iter().enumerate() {
        for &b in &lengths[i + 1..] {
            planes.push((a, b));
        }
    }
    let mut slices = vec![];
    let per_slice = MAP_SLICE_POINTS.min(MAP_TOTAL_POINTS / planes.len().max(1) as f64);
    for (a, b) in planes {
        let (ea, eb) = (bx[a][1] - bx[a][0], bx[b][1] - bx[b][0]);
        let mut spacing = (ea * eb / per_slice).sqrt();
        // A box much thinner along one axis than the other: the lattice is
        // bounded by points, the thin axis then a single row.
        if spacing.is_nan()
            || spacing <= 0.0
            || (ea / spacing + 1.0) * (eb / spacing + 1.0) > 4.0 * per_slice
        {
            spacing = ea.max(eb) / per_slice.sqrt();
        }
        let (na, nb) = ((ea / spacing) as usize + 1, (eb / spacing) as usize + 1);
        let targets: Vec<Vec<f64>> = (0..na)
            .flat_map(|i| (0..nb).map(move |j| (i, j)))
            .map(|(i, j)| {
                let mut t = centre.clone();
                t[a] = bx[a][0] + spacing * i as f64;
                t[b] = bx[b][0] + spacing * j as f64;
                t
            })
            .collect();
        let values: Vec<Option<(f64, f64)>> = targets
            .par_iter()
            .map(|t| check().map(|()| miss_and_sigma(mech, cal, t)))
            .collect::<pkmcal::Result<_>>()?;
        let mut s = figures::MapSlice {
            axes: [spec.tool_axes[a].clone(), spec.tool_axes[b].clone()],
            held: held_text(spec, &centre, &[a, b]),
            points: vec![],
            spacing,
            miss: vec![],
            sigma: vec![],
        };
        for (t, v) in targets.iter().zip(values) {
            if let Some((m, sg)) = v {
                s.points.push([t[a], t[b]]);
                s.miss.push(m);
                s.sigma.push(sg);
            }
        }
        slices.push(s);
    }
    let mut sweeps = vec![];
    if !lengths.is_empty() {
        for &k in &angles {
            let mut s = figures::MapSweep {
                axis: spec.tool_axes[k].clone(),
                held: held_text(spec, &centre, &[k]),
                values: vec![],
                miss: vec![],
                sigma: vec![],
            };
            let targets: Vec<Vec<f64>> = (0..MAP_SWEEP_POINTS)
                .map(|i| {
                    let mut t = centre.clone();
                    t[k] =
                        bx[k][0] + (bx[k][1] - bx[k][0]) * i as f64 / (MAP_SWEEP_POINTS - 1) as f64;
                    t
                })
                .collect();
            let values: Vec<Option<(f64, f64)>> = targets
                .par_iter()
                .map(|t| check().map(|()| miss_and_sigma(mech, cal, t)))
                .collect::<pkmcal::Result<_>>()?;
            for (t, v) in targets.iter().zip(values) {
                if let Some((m, sg)) = v {
                    s.values.push(t[k]);
                    s.miss.push(m);
                    s.sigma.push(sg);
                }
            }
            if !s.values.is_empty() {
                sweeps.push(s);
            }
        }
    }
    Ok((slices, sweeps))
}

/// Everything the HTML report and the figures show: the JSON report (the
/// calibration, its accuracy, validation and cross-validation: the one
/// bundle every front end makes from a study) and what only the figures
/// need (the mechanism, the measurement model, the poses and their errors).
pub struct ReportInputs<'a> {
    pub report: &'a crate::record::Report<'a>,
    /// The front end's words (hints, where lists are kept).
    pub wording: &'a crate::text::Wording,
    pub mech: &'a Mech,
    pub measurement: &'a pkmcal::MeasurementModel,
    pub data: &'a [Measurement],
    pub before: &'a ErrorVectors,
    pub after: &'a ErrorVectors,
}

/// Escape text for HTML.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            _ => out.push(c),
        }
    }
    out
}

/// Render every figure of a calibration.
pub fn figures(r: &ReportInputs) -> Result<Vec<Figure>> {
    figures_cancellable(r, None)
}

/// [`figures`], stopped at its next pose, workspace point or figure once
/// `cancel` is set (the library's [`pkmcal::Error::Cancelled`]).
pub fn figures_cancellable(
    r: &ReportInputs,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<Vec<Figure>> {
    let check = || pkmcal::error::check_cancel(cancel);
    let spec = r.mech.spec();
    let cal = r.report.calibration;
    // Parameter groups by kind and unit (angles in mrad for readability).
    let mut groups: Vec<(String, &'static str, Vec<ParamBar>)> = vec![];
    let mut keys: Vec<(pkmcal::ParamKind, pkmcal::Unit)> = vec![];
    for p in cal.parameters.iter().filter(|p| p.free) {
        let (f, symbol) = match p.unit {
            pkmcal::Unit::Radian => (1e3, "mrad"),
            u => (1.0, u.symbol()),
        };
        let key = (p.kind, p.unit);
        let g = match keys.iter().position(|k| *k == key) {
            Some(g) => g,
            None => {
                keys.push(key);
                let what = match p.kind {
                    pkmcal::ParamKind::Geometry => p.unit.group_name(),
                    k => k.name(),
                };
                let from = if p.kind == pkmcal::ParamKind::Instrument {
                    figures::FROM_START
                } else {
                    figures::FROM_NOMINAL
                };
                groups.push((format!("{what} ({symbol})"), from, vec![]));
                groups.len() - 1
            }
        };
        groups[g].2.push(ParamBar {
            name: p.name.clone(),
            change: p.change * f,
            sigma: p.std_dev * f,
        });
    }
    // Where each pose is: its target, else the calibrated prediction.
    let positions: Vec<Vec<f64>> = r
        .data
        .par_iter()
        .map(|m| match &m.target {
            Some(t) => Ok(t.clone()),
            None => {
                check()?;
                let pose = prepare_pose(r.mech, &m.commands, None)?;
                Ok(pkmcal::predict_pose(r.mech, &pose, &cal.params, cal.model, &[])?.x)
            }
        })
        .collect::<pkmcal::Result<_>>()?;
    // The workspace lattice behind the plan view, within a point budget.
    let spacing = pkmcal::engine::atlas::lattice_spacing(spec, MAP_SPACING_MM, MAP_POINTS);
    check()?;
    let lattice = sample_workspace(r.mech, spacing);
    let (slices, sweeps) = map_data(r.mech, cal, &check)?;
    check()?;
    let unit_weight = cal.unit_weight_sigma.max(f64::MIN_POSITIVE);
    let standardized: Vec<f64> = cal
        .residuals
        .iter()
        .zip(&cal.sigmas)
        .map(|(e, s)| e / s / unit_weight)
        .collect();
    let lattice_targets: Vec<Vec<f64>> = lattice.iter().map(|p| p.target.clone()).collect();
    let mut out = vec![
        figures::errors_per_pose(
            &r.data
                .iter()
                .enumerate()
                .map(|(i, m)| m.origin.map_or(i + 1, |o| o.pose))
                .collect::<Vec<_>>(),
            r.before,
            r.after,
            r.measurement.axes(),
            r.measurement.units(),
        )?,
        figures::parameter_changes(&groups)?,
    ];
    // Error vectors over the workspace: when the errors are tool positions
    // in the base frame (other readings have no direction in the plan view).
    if r.measurement.is_whole_tool() {
        let axis = |a: &str| {
            spec.tool_axes
                .iter()
                .zip(&spec.tool_units)
                .position(|(n, u)| n == a && *u == pkmcal::Unit::Millimetre)
        };
        let views: Vec<([usize; 2], [&str; 2])> = match (axis("x"), axis("y"), axis("z")) {
            (Some(x), Some(y), Some(z)) => vec![
                ([x, y], ["x", "y"]),
                ([x, z], ["x", "z"]),
                ([y, z], ["y", "z"]),
            ],
            _ => vec![([0, 1], ["x", "y"])],
        };
        check()?;
        out.push(figures::workspace_errors(
            &lattice_targets,
            &positions,
            r.before,
            r.after,
            &views,
        )?);
    }
    if slices.iter().any(|s| !s.points.is_empty()) || !sweeps.is_empty() {
        let bx = &spec.workspace_box;
        let centre: Vec<f64> = bx.iter().map(|b| 0.5 * (b[0] + b[1])).collect();
        check()?;
        out.push(figures::workspace_maps(
            &slices,
            &sweeps,
            &held_text(spec, &centre, &[]),
        )?);
    }
    check()?;
    out.push(figures::residuals(&standardized)?);
    let sv = &cal.identifiability.singular_values;
    let smax = sv.first().copied().unwrap_or(1.0);
    out.push(figures::singular_values(sv, RANK_TOL * smax)?);
    Ok(out)
}

fn stats_row(html: &mut String, label: &str, s: &ErrorStats) {
    let _ = write!(html, "<tr><td>{}</td>", escape(label));
    if s.axis_units.contains(&pkmcal::Unit::Millimetre) {
        let _ = write!(
            html,
            "<td>{:.4}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td>",
            s.distance_min, s.distance_mean, s.distance_rms, s.distance_max
        );
    }
    if let (Some(r), Some(m)) = (s.angle_rms, s.angle_max) {
        let _ = write!(html, "<td>{:.4}</td><td>{:.4}</td>", r * 1e3, m * 1e3);
    }
    html.push_str("</tr>");
}

/// The start of a report page: its head (the embedded font, the CSS every
/// report shares: a 1100 px page) and its `<h1>` title.
pub(crate) fn page_start(title: &str) -> String {
    let font = base64::engine::general_purpose::STANDARD.encode(figures::FONT_BYTES);
    let mut h = String::with_capacity(2_000_000);
    let _ = write!(
        h,
        r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
@font-face {{ font-family: "DejaVu Sans"; src: url(data:font/ttf;base64,{font}) format("truetype"); }}
body {{ font-family: "DejaVu Sans", sans-serif; margin: 2em auto; max-width: 1100px; color: #222; line-height: 1.4; padding: 0 1em; }}
h1 {{ font-size: 1.6em; }} h2 {{ font-size: 1.25em; border-bottom: 1px solid #ccc; margin-top: 2em; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }}
td, th {{ border: 1px solid #ddd; padding: 3px 8px; text-align: right; }}
td:first-child, th:first-child {{ text-align: left; }}
th[colspan] {{ text-align: center; }}
.wide {{ overflow-x: auto; }} .wide td {{ white-space: nowrap; }} .wide tr:nth-child(2) th {{ text-align: right; }}
th {{ background: #f4f4f4; }}
.fixed {{ color: #888; }} .warn {{ background: #fff4e0; border-left: 4px solid #e8a33d; padding: 0.5em 1em; margin: 0.5em 0; }}
figure {{ margin: 1.5em 0; }} figure svg {{ max-width: 100%; height: auto; display: block; }}
figcaption {{ font-size: 0.9em; color: #444; margin-top: 0.3em; }}
.kv td {{ text-align: left; }} .kv td:first-child {{ font-weight: bold; }}
</style></head><body>
<h1>{title}</h1>
"#,
        title = escape(title),
        font = font
    );
    h
}

/// The end of a report page.
pub(crate) const PAGE_END: &str = "<p style=\"color:#888;font-size:0.8em\">Generated by pkmcal. Font: DejaVu Sans (embedded).</p></body></html>\n";

/// The report page.
pub fn html(r: &ReportInputs, figs: &[Figure]) -> String {
    let spec = r.mech.spec();
    let cal = r.report.calibration;
    let mut h = page_start(&format!("pkmcal calibration report — {}", spec.name));
    let _ = write!(
        h,
        "<table class=\"kv\"><tr><td>mechanism</td><td>{}</td></tr><tr><td>joints</td><td>{} (actuated: {})</td></tr><tr><td>data</td><td>{} ({} poses{})</td></tr><tr><td>model</td><td>{}</td></tr><tr><td>solver</td><td>{} after {} iterations, {} evaluations</td></tr><tr><td>noise</td><td>{}</td></tr><tr><td>instrument frame</td><td>{}</td></tr><tr><td>pkmcal</td><td>{}</td></tr></table>",
        escape(&spec.name),
        escape(&spec.joints.join(", ")),
        escape(&spec.actuated_names().join(", ")),
        escape(&r.report.data),
        cal.poses,
        if cal.distances > 0 {
            format!(", {} distances between poses", cal.distances)
        } else {
            String::new()
        },
        match cal.model {
            Model::Rigid => "rigid (no compliance)",
            Model::Linear => "linear (paper eq. 11)",
            Model::Exact => "exact static equilibrium",
        },
        escape(&cal.termination_reason),
        cal.iterations,
        cal.evaluations,
        cal.noise
            .iter()
            .map(|g| escape(&crate::text::noise_text(g)))
            .collect::<Vec<_>>()
            .join("<br>"),
        escape(
            &crate::text::frame_text(cal, r.measurement, r.wording).unwrap_or_else(|| {
                match r.measurement.instrument() {
                    pkmcal::Instrument::BallBar { .. } => {
                        "none: the ball-bar sockets are given in the base frame".into()
                    }
                    _ => format!("the base frame; readings: {}", r.measurement.describe()),
                }
            })
        ),
        env!("CARGO_PKG_VERSION")
    );
    for w in &cal.warnings {
        let _ = write!(
            h,
            "<div class=\"warn\"><b>warning:</b> {}<br><i>{}</i></div>",
            escape(&w.message),
            escape(&(r.wording.hint)(w))
        );
    }
    // The headline distance and angle errors in one table, each axis's
    // range in another with the axes as rows: a 6-DOF measurement's nine
    // axes as columns pushed the headline out of a 1100 px page.
    let units = r.measurement.units();
    let lengths = units.contains(&pkmcal::Unit::Millimetre);
    let angles = units.contains(&pkmcal::Unit::Radian);
    let mut rows: Vec<(String, &ErrorStats)> = vec![
        (
            "calibration poses, before".into(),
            &r.report.accuracy.before,
        ),
        ("calibration poses, after".into(), &r.report.accuracy.after),
    ];
    if let Some(v) = &r.report.validation {
        rows.push((
            format!("validation ({}), before", v.source),
            &v.accuracy.before,
        ));
        rows.push((
            format!("validation ({}), after", v.source),
            &v.accuracy.after,
        ));
    }
    if let Some(cv) = &r.report.cross_validation {
        rows.push((format!("{}-fold cross-validation", cv.folds), &cv.pooled));
    }
    let _ = write!(
        h,
        "<h2>Accuracy</h2><div class=\"wide\"><table><tr><th rowspan=\"2\">poses</th>{}{}</tr><tr>",
        if lengths {
            "<th colspan=\"4\">distance error, mm</th>"
        } else {
            ""
        },
        if angles {
            "<th colspan=\"2\">angle error, mrad</th>"
        } else {
            ""
        },
    );
    if lengths {
        h.push_str("<th>min</th><th>mean</th><th>RMS</th><th>max</th>");
    }
    if angles {
        h.push_str("<th>RMS</th><th>max</th>");
    }
    h.push_str("</tr>");
    for (label, s) in &rows {
        stats_row(&mut h, label, s);
    }
    let _ = write!(
        h,
        "</table></div><div class=\"wide\"><table><tr><th rowspan=\"2\">axis</th><th colspan=\"{}\">error range of each axis</th></tr><tr>",
        rows.len()
    );
    for (label, _) in &rows {
        let _ = write!(h, "<th>{}</th>", escape(label));
    }
    h.push_str("</tr>");
    for (k, (a, u)) in r.measurement.axes().iter().zip(units).enumerate() {
        let (f, unit) = crate::text::column_unit(*u);
        let _ = write!(h, "<tr><td>{}, {unit}</td>", escape(&a.to_uppercase()));
        for (_, s) in &rows {
            match (s.axis_min.get(k), s.axis_max.get(k)) {
                (Some(lo), Some(hi)) => {
                    let _ = write!(h, "<td>{:.4} … {:.4}</td>", lo * f, hi * f);
                }
                _ => h.push_str("<td></td>"),
            }
        }
        h.push_str("</tr>");
    }
    let _ = write!(
        h,
        "</table></div><p>Improvement on the calibration poses: maximum distance error {:.1} %, RMS {:.1} %.</p>",
        r.report.accuracy.improvement_max_percent, r.report.accuracy.improvement_rms_percent
    );
    if let Some(d) = &r.report.accuracy.distances {
        let _ = write!(
            h,
            "<p>{} distances between poses (calipers, a gauge): error max {:.4} mm, RMS {:.4} mm before; max {:.4} mm, RMS {:.4} mm after.</p>",
            d.count, d.before_max, d.before_rms, d.after_max, d.after_rms
        );
    }
    // With priors: each one's tolerance and its information from the data.
    let priors = !cal.priors.is_empty();
    // A note column only where a parameter has a note (a renamed name).
    let notes = cal.parameters.iter().any(|p| p.note.is_some());
    let _ = write!(
        h,
        "<h2>Parameters</h2>{}<table><tr><th>parameter</th><th>unit</th><th>nominal</th><th>identified</th><th>change</th><th>σ</th>{}{}</tr>",
        if priors {
            "<p>The fit is held by the parameters' tolerances (priors, one σ about nominal): <i>from data</i> is the share of what is known of each that the measurements gave.</p>"
        } else {
            ""
        },
        if priors {
            "<th>tolerance</th><th>from data</th>"
        } else {
            ""
        },
        if notes { "<th>note</th>" } else { "" }
    );
    for p in &cal.parameters {
        let class = if p.free { "" } else { " class=\"fixed\"" };
        let prior = match (priors, p.tolerance) {
            (false, _) => String::new(),
            (true, None) => "<td></td><td></td>".into(),
            (true, Some(t)) => format!(
                "<td>{t:.3e}</td><td>{}</td>",
                p.from_data
                    .map_or_else(String::new, |f| format!("{:.0} %", 100.0 * f))
            ),
        };
        let _ = write!(
            h,
            "<tr{class}><td>{}</td><td>{}</td><td>{:.6}</td><td>{:.8}</td><td>{:+.4e}</td><td>{}</td>{prior}{}</tr>",
            escape(&p.name),
            escape(p.unit.symbol()),
            p.nominal,
            p.identified,
            p.change,
            if p.free {
                format!("{:.3e}", p.std_dev)
            } else {
                "fixed".into()
            },
            if notes {
                format!("<td>{}</td>", escape(p.note.as_deref().unwrap_or("")))
            } else {
                String::new()
            }
        );
    }
    h.push_str("</table>");
    let id = &cal.identifiability;
    let o = &id.observability;
    let _ = write!(
        h,
        "<h2>Identifiability</h2><p>Rank {} of {} free parameters; column-scaled identification Jacobian: {}.</p><table><tr><th>index</th><th>O1</th><th>O2</th><th>O3</th><th>O4</th><th>O5</th></tr><tr><td>value</td><td>{:.4e}</td><td>{:.4e}</td><td>{:.4e}</td><td>{:.4e}</td><td>{:.4e}</td></tr></table>",
        id.rank,
        id.singular_values.len(),
        escape(&crate::text::condition_text(id)),
        o.o1,
        o.o2,
        o.o3,
        o.o4,
        o.o5
    );
    if !id.held.is_empty() {
        h.push_str("<p>Held by the tolerances (the data alone cannot see them):</p><ul>");
        for u in &id.held {
            let _ = write!(h, "<li>{}</li>", escape(&u.combination));
        }
        h.push_str("</ul>");
    }
    if id.unidentifiable.is_empty() && !id.held.is_empty() {
        h.push_str(
            "<p>Every free parameter is identified, these poses and the tolerances together.</p>",
        );
    } else if id.unidentifiable.is_empty() {
        h.push_str("<p>Every free parameter is identifiable from these poses.</p>");
    } else {
        h.push_str("<p>Unidentifiable directions:</p><ul>");
        for u in &id.unidentifiable {
            let _ = write!(
                h,
                "<li>{}{}</li>",
                escape(&u.combination),
                u.fixed
                    .as_ref()
                    .map(|f| format!(" — fixed <b>{}</b>", escape(f)))
                    .unwrap_or_default()
            );
        }
        h.push_str("</ul>");
    }
    if !cal.correlations.is_empty() {
        h.push_str("<p>Strongly correlated parameters (|r| > 0.9): ");
        let list: Vec<String> = cal
            .correlations
            .iter()
            .map(|c| format!("{} – {} ({:+.3})", escape(&c.a), escape(&c.b), c.r))
            .collect();
        h.push_str(&list.join(", "));
        h.push_str("</p>");
    }
    h.push_str("<h2>Figures</h2>");
    for f in figs {
        let _ = write!(
            h,
            "<figure id=\"{}\"><h3>{}</h3>{}<figcaption>{}</figcaption></figure>",
            f.name,
            escape(&f.title),
            f.svg
                .trim_start_matches("<?xml version=\"1.0\" encoding=\"UTF-8\"?>"),
            escape(&f.caption)
        );
    }
    h.push_str(PAGE_END);
    h
}

/// Write the figures and `report.html` into `dir`.
pub fn write_report_dir(run: &crate::Run<'_>, dir: &Path, r: &ReportInputs) -> Result<()> {
    write_report_dir_cancellable(run, dir, r, None)
}

/// [`write_report_dir`], its figures stopped once `cancel` is set
/// ([`figures_cancellable`]; nothing is written then).
pub fn write_report_dir_cancellable(
    run: &crate::Run<'_>,
    dir: &Path,
    r: &ReportInputs,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<()> {
    run.files.create_dir(dir)?;
    let figs = figures_cancellable(r, cancel)?;
    for f in &figs {
        run.files
            .stage(&dir.join(format!("{}.svg", f.name)), f.svg.as_bytes())?;
        run.files
            .stage(&dir.join(format!("{}.png", f.name)), &f.png)?;
    }
    run.files
        .stage(&dir.join("report.html"), html(r, &figs).as_bytes())?;
    Ok(())
}
