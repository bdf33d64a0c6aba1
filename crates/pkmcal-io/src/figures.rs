//! Figures of a calibration, as pure functions from results to SVG text and
//! PNG bytes (plotters). Text in PNGs is drawn with the bundled DejaVu Sans
//! (`assets/`), so rendering never depends on the machine's fonts; SVGs name
//! the same family, which the HTML report embeds.

use crate::error::{Error, Result};
use plotters::prelude::*;
use std::sync::Once;

/// The bundled font (DejaVu Sans, free licence in `assets/DejaVuSans-LICENSE.txt`).
pub const FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
/// The font family the figures use.
pub const FONT: &str = "DejaVu Sans";

pub(crate) const BEFORE: RGBColor = RGBColor(200, 55, 45);
pub(crate) const AFTER: RGBColor = RGBColor(30, 100, 200);
const GREY: RGBColor = RGBColor(200, 200, 200);

pub(crate) fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES)
            .map_err(|_| ())
            .expect("the bundled font is valid");
    });
}

/// One rendered figure.
pub struct Figure {
    /// File stem (`errors`, `parameters`, …).
    pub name: &'static str,
    /// Title for the report.
    pub title: String,
    /// Caption: what is shown and how to read it.
    pub caption: String,
    /// SVG text.
    pub svg: String,
    /// PNG bytes.
    pub png: Vec<u8>,
}

pub(crate) fn err<E: std::fmt::Debug>(e: E) -> Error {
    Error::Content(format!("drawing failed: {e:?}"))
}

/// Render one drawing function to SVG and PNG.
/// The drawing body is expanded once per backend (closures cannot be generic).
macro_rules! render {
    ($name:expr, $title:expr, $caption:expr, ($w:expr, $h:expr), |$root:ident| $body:block) => {{
        register_font();
        let mut svg = String::new();
        {
            let area = SVGBackend::with_string(&mut svg, ($w, $h)).into_drawing_area();
            {
                let $root = &area;
                (|| -> Result<()> { $body })()?;
            }
            area.present().map_err(err)?;
        }
        let mut buf = vec![0u8; ($w * $h * 3) as usize];
        {
            let area = BitMapBackend::with_buffer(&mut buf, ($w, $h)).into_drawing_area();
            {
                let $root = &area;
                (|| -> Result<()> { $body })()?;
            }
            area.present().map_err(err)?;
        }
        let mut png = Vec::new();
        {
            // The png crate alone: the image crate's colour management is not needed.
            let mut enc = png::Encoder::new(&mut png, $w, $h);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().map_err(err)?;
            w.write_image_data(&buf).map_err(err)?;
        }
        Ok(Figure {
            name: $name,
            title: $title.into(),
            caption: $caption.into(),
            svg,
            png,
        })
    }};
}

pub(crate) use render;

/// Tick label with about three significant digits and no "-0".
pub(crate) fn tick(v: &f64) -> String {
    if v.abs() < 1e-12 {
        return "0".into();
    }
    let prec = (2 - v.abs().log10().floor() as i32).clamp(0, 8) as usize;
    let s = format!("{v:.prec$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

pub(crate) fn range(values: impl Iterator<Item = f64>, pad: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    if hi - lo < 1e-12 {
        return (lo - 1.0, hi + 1.0);
    }
    let p = (hi - lo) * pad;
    (lo - p, hi + p)
}

/// A panel's values scaled to a readable unit (µm, mrad, …) for their size.
fn readable(values: &[f64], unit: pkmcal::Unit) -> (Vec<f64>, &'static str) {
    let m = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let (f, sym) = unit.readable(m);
    (values.iter().map(|v| v * f).collect(), sym)
}

/// Panels whose before and after scales differ by more than this get an
/// after panel of their own.
const SPLIT_RATIO: f64 = 10.0;
/// The widest figure (px): the report's page is 1100 px with 1 em margins,
/// so a figure this wide is drawn at its own size and its 12 px labels stay
/// 12 px (figures 1,200-1,400 px wide were shrunk to 9 px text).
pub const FIGURE_WIDTH: u32 = 1060;

/// The figures' smallest text, tick labels and axis names, as plotters
/// takes a size: its SVG and bitmap text is this over 1.24 (the font's
/// line height), 13.7 px; drawn at that size, as no figure is wider than
/// [`FIGURE_WIDTH`] (14 gave 11.3 px text).
pub(crate) const LABEL_PX: u32 = 17;
/// Panel titles and captions, as plotters takes a size (14.5 px text).
pub(crate) const TITLE_PX: u32 = 18;

/// Height of one row of panels (px).
const PANEL_HEIGHT: u32 = 158;
/// Height of the legend strip above the panels (px).
const LEGEND_HEIGHT: u32 = 34;

/// One error panel: the values of one or two series at each pose.
fn error_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    numbers: &[f64],
    label: &str,
    series: &[(&[f64], RGBColor)],
) -> Result<()> {
    let (lo, hi) = range(
        series
            .iter()
            .flat_map(|(v, _)| v.iter().copied())
            .chain([0.0]),
        0.08,
    );
    let first = numbers.first().copied().unwrap_or(1.0);
    let last = numbers.last().copied().unwrap_or(1.0).max(first);
    let mut chart = ChartBuilder::on(area)
        .margin(8)
        .x_label_area_size(38)
        .y_label_area_size(62)
        .build_cartesian_2d(first - 0.5..last + 0.5, lo..hi)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("measured pose")
        .y_desc(label)
        .x_labels(8)
        .y_labels(5)
        .x_label_formatter(&|x| format!("{}", x.round() as i64))
        .y_label_formatter(&tick)
        .label_style((FONT, LABEL_PX))
        .axis_desc_style((FONT, LABEL_PX))
        .max_light_lines(0)
        .draw()
        .map_err(err)?;
    chart
        .draw_series(LineSeries::new(
            [(first - 0.5, 0.0), (last + 0.5, 0.0)],
            BLACK.mix(0.4),
        ))
        .map_err(err)?;
    for (vals, color) in series {
        let color = *color;
        chart
            .draw_series(LineSeries::new(
                numbers.iter().zip(vals.iter()).map(|(x, v)| (*x, *v)),
                color.mix(0.5),
            ))
            .map_err(err)?;
        chart
            .draw_series(
                numbers
                    .iter()
                    .zip(vals.iter())
                    .map(|(x, v)| Circle::new((*x, *v), 3, color.filled())),
            )
            .map_err(err)?;
    }
    Ok(())
}

/// The legend strip: coloured dots and names, outside the data.
fn legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    entries: &[(&str, RGBColor)],
) -> Result<()> {
    let mut x = 80;
    for (name, color) in entries {
        area.draw(&Circle::new(
            (x, LEGEND_HEIGHT as i32 / 2),
            5,
            color.filled(),
        ))
        .map_err(err)?;
        area.draw(&Text::new(
            name.to_string(),
            (x + 12, LEGEND_HEIGHT as i32 / 2 - 8),
            (FONT, TITLE_PX).into_font(),
        ))
        .map_err(err)?;
        x += 24 + 9 * name.len() as i32;
    }
    Ok(())
}

/// Most poses (and residual quantiles) one figure draws: beyond, an evenly
/// spread selection that keeps the largest errors, and the caption says so.
/// The figures then stay a few MB and quick to render whatever the data.
pub const MAX_POSES_SHOWN: usize = 3000;

/// The poses a figure draws of `n` whose errors are `before` and `after`:
/// all of them up to [`MAX_POSES_SHOWN`], else an evenly spread selection
/// with the pose of the largest error before and after calibration.
fn shown(n: usize, before: &[Vec<f64>], after: &[Vec<f64>]) -> Vec<usize> {
    if n <= MAX_POSES_SHOWN {
        return (0..n).collect();
    }
    let size = |e: &Vec<f64>| e.iter().map(|v| v * v).sum::<f64>();
    let largest =
        |v: &[Vec<f64>]| (0..v.len().min(n)).max_by(|&i, &j| size(&v[i]).total_cmp(&size(&v[j])));
    let mut keep = pkmcal::engine::atlas::thin_evenly(n, MAX_POSES_SHOWN - 2);
    keep.extend(largest(before));
    keep.extend(largest(after));
    keep.sort_unstable();
    keep.dedup();
    keep
}

/// What a caption adds when `shown` of `n` poses are drawn.
fn shown_words(shown: usize, n: usize, what: &str) -> String {
    if shown >= n {
        String::new()
    } else {
        format!(
            " Of the {n} {what}, {shown} are drawn, spread evenly through them, the largest errors included."
        )
    }
}

/// Fig. 9 of the paper: the error of each tool coordinate and the distance
/// error at each measured pose, before and after calibration. Each panel is
/// in a unit readable for its size (mm, µm; mrad, µrad; angles never in mm);
/// when the errors after calibration are more than ten times smaller, they
/// get panels of their own, on the right.
pub fn errors_per_pose(
    poses: &[usize],
    before: &[Vec<f64>],
    after: &[Vec<f64>],
    axes: &[String],
    units: &[pkmcal::Unit],
) -> Result<Figure> {
    use pkmcal::Unit;
    let n = before.len();
    let keep = shown(n, before, after);
    let thinned = shown_words(keep.len(), n, "poses");
    let before: Vec<Vec<f64>> = keep.iter().map(|&i| before[i].clone()).collect();
    let after: Vec<Vec<f64>> = keep.iter().map(|&i| after[i].clone()).collect();
    let (before, after) = (&before[..], &after[..]);
    // Each pose at its number, as its front end numbers it (the command
    // line by file row from 1, Python by array row from 0).
    let numbers: Vec<f64> = keep.iter().map(|&i| poses[i] as f64).collect();
    let lengths: Vec<usize> = (0..units.len())
        .filter(|&k| units[k] == Unit::Millimetre)
        .collect();
    let dist = |e: &Vec<f64>| lengths.iter().map(|&k| e[k] * e[k]).sum::<f64>().sqrt();
    // (name, unit, before, after) per quantity, in internal units.
    let mut rows: Vec<(String, Unit, Vec<f64>, Vec<f64>)> = axes
        .iter()
        .zip(units)
        .enumerate()
        .map(|(k, (a, u))| {
            (
                format!("{a} error"),
                *u,
                before.iter().map(|e| e[k]).collect(),
                after.iter().map(|e| e[k]).collect(),
            )
        })
        .collect();
    if lengths.len() > 1 {
        rows.push((
            "distance error".into(),
            Unit::Millimetre,
            before.iter().map(dist).collect(),
            after.iter().map(dist).collect(),
        ));
    }
    let peak = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let split = rows
        .iter()
        .any(|(_, _, b, a)| peak(b) > SPLIT_RATIO * peak(a).max(1e-300));
    let height = LEGEND_HEIGHT + PANEL_HEIGHT * rows.len() as u32;
    let width = if split { FIGURE_WIDTH } else { 1000 };
    render!(
        "errors",
        "Errors at each measured pose (paper Fig. 9)",
        format!(
            "Error of each tool coordinate{} at each of the {n} measured poses, before (red) and after (blue) calibration{}. Each panel has its own unit (lengths in mm or µm, angles in mrad or µrad).{thinned}",
            if lengths.len() > 1 {
                " and the distance error"
            } else {
                ""
            },
            if split {
                "; the errors after calibration are more than ten times smaller and are drawn on their own scale, on the right"
            } else {
                ""
            }
        ),
        (width, height),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let (top, body) = root.split_vertically(LEGEND_HEIGHT);
            if split {
                let (l, r) = top.split_horizontally(width / 2);
                legend(&l, &[("before calibration", BEFORE)])?;
                legend(&r, &[("after calibration", AFTER)])?;
            } else {
                legend(&top, &[("before", BEFORE), ("after", AFTER)])?;
            }
            let cells = body.split_evenly((rows.len(), if split { 2 } else { 1 }));
            for (r, (name, unit, b, a)) in rows.iter().enumerate() {
                if split {
                    let (bv, bu) = readable(b, *unit);
                    let (av, au) = readable(a, *unit);
                    error_panel(
                        &cells[2 * r],
                        &numbers,
                        &format!("{name} ({bu})"),
                        &[(&bv, BEFORE)],
                    )?;
                    error_panel(
                        &cells[2 * r + 1],
                        &numbers,
                        &format!("{name} ({au})"),
                        &[(&av, AFTER)],
                    )?;
                } else {
                    let all: Vec<f64> = b.iter().chain(a).copied().collect();
                    let m = peak(&all);
                    let (f, u) = unit.readable(m);
                    let bv: Vec<f64> = b.iter().map(|v| v * f).collect();
                    let av: Vec<f64> = a.iter().map(|v| v * f).collect();
                    error_panel(
                        &cells[r],
                        &numbers,
                        &format!("{name} ({u})"),
                        &[(&bv, BEFORE), (&av, AFTER)],
                    )?;
                }
            }
            Ok(())
        }
    )
}

/// Most bars in one panel of the parameter figure.
const PARAMS_PER_PANEL: usize = (ROW_WIDTH as usize - 120) / 55;
/// Widest row of parameter panels (px).
const ROW_WIDTH: u32 = FIGURE_WIDTH;
/// Height of one row of parameter panels (px).
const PARAM_ROW_HEIGHT: u32 = 420;

/// One parameter of Fig. 8.
pub struct ParamBar {
    pub name: String,
    pub change: f64,
    pub sigma: f64,
}

/// What a group's changes are measured from: the nominal value, or (for the
/// instrument's parameters, registered from a start) the starting value.
pub const FROM_NOMINAL: &str = "identified − nominal";
/// See [`FROM_NOMINAL`].
pub const FROM_START: &str = "identified − start";

/// Fig. 8 of the paper: identified parameter changes with ±2σ bars, one panel
/// per unit group; each group says what its changes are from
/// ([`FROM_NOMINAL`], [`FROM_START`]).
pub fn parameter_changes(groups: &[(String, &'static str, Vec<ParamBar>)]) -> Result<Figure> {
    // Panels of at most PARAMS_PER_PANEL bars, packed into rows no wider
    // than ROW_WIDTH, so that many parameters stay readable.
    let mut panels: Vec<(String, &'static str, &[ParamBar])> = vec![];
    for (title, from, bars) in groups.iter().filter(|g| !g.2.is_empty()) {
        let chunks = bars.len().div_ceil(PARAMS_PER_PANEL);
        for (k, c) in bars.chunks(bars.len().div_ceil(chunks)).enumerate() {
            let t = if chunks > 1 {
                format!("{title}, {}/{chunks}", k + 1)
            } else {
                title.clone()
            };
            panels.push((t, from, c));
        }
    }
    let width_of = |n: usize| 120 + 55 * n as u32;
    let mut rows: Vec<Vec<usize>> = vec![];
    let mut used = u32::MAX;
    for (i, (_, _, bars)) in panels.iter().enumerate() {
        let w = width_of(bars.len());
        if used.saturating_add(w) > ROW_WIDTH {
            rows.push(vec![]);
            used = 0;
        }
        rows.last_mut().expect("a row").push(i);
        used += w;
    }
    let total: u32 = rows
        .iter()
        .map(|r| r.iter().map(|&i| width_of(panels[i].2.len())).sum::<u32>())
        .max()
        .unwrap_or(0)
        .max(400);
    render!(
        "parameters",
        "Identified parameter changes (paper Fig. 8)",
        "Identified minus nominal value of each free parameter (minus its starting value for the instrument's, registered from a start), grouped by kind and unit; black bars span ±2 standard deviations.",
        (total, PARAM_ROW_HEIGHT * rows.len().max(1) as u32),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let row_areas = root.split_evenly((rows.len().max(1), 1));
            for (row, row_area) in rows.iter().zip(&row_areas) {
                let mut rest = row_area.clone();
                for &i in row {
                    let (title, from, bars) = (&panels[i].0, panels[i].1, panels[i].2);
                    let (area, r) = rest.split_horizontally(width_of(bars.len()));
                    rest = r;
                    let unit = title;
                    let (lo, hi) = range(
                        bars.iter().flat_map(|b| {
                            [b.change - 2.0 * b.sigma, b.change + 2.0 * b.sigma, 0.0]
                        }),
                        0.1,
                    );
                    let n = bars.len();
                    let mut chart = ChartBuilder::on(&area)
                        .margin(10)
                        .caption(unit.as_str(), (FONT, TITLE_PX))
                        .x_label_area_size(40)
                        .y_label_area_size(75)
                        .build_cartesian_2d(-0.5f64..n as f64 - 0.5, lo..hi)
                        .map_err(err)?;
                    chart
                        .configure_mesh()
                        .x_labels(n)
                        .x_label_formatter(&|x| {
                            let i = x.round();
                            if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < n {
                                bars[i as usize].name.clone()
                            } else {
                                String::new()
                            }
                        })
                        .y_desc(from)
                        .y_label_formatter(&tick)
                        .label_style((FONT, LABEL_PX))
                        .axis_desc_style((FONT, LABEL_PX))
                        .max_light_lines(0)
                        .disable_x_mesh()
                        .draw()
                        .map_err(err)?;
                    chart
                        .draw_series(LineSeries::new(
                            [(-0.5, 0.0), (n as f64 - 0.5, 0.0)],
                            BLACK.mix(0.4),
                        ))
                        .map_err(err)?;
                    chart
                        .draw_series(bars.iter().enumerate().map(|(i, b)| {
                            Rectangle::new(
                                [(i as f64 - 0.3, 0.0), (i as f64 + 0.3, b.change)],
                                AFTER.mix(0.55).filled(),
                            )
                        }))
                        .map_err(err)?;
                    chart
                        .draw_series(bars.iter().enumerate().map(|(i, b)| {
                            ErrorBar::new_vertical(
                                i as f64,
                                b.change - 2.0 * b.sigma,
                                b.change,
                                b.change + 2.0 * b.sigma,
                                BLACK.stroke_width(1),
                                8,
                            )
                        }))
                        .map_err(err)?;
                }
            }
            Ok(())
        }
    )
}

/// A round number near `v` (1, 2 or 5 × 10^k).
fn nice(v: f64) -> f64 {
    if v.is_nan() || v <= 0.0 {
        return 1.0;
    }
    let e = v.log10().floor();
    let m = v / 10f64.powf(e);
    let m = if m < 1.5 {
        1.0
    } else if m < 3.5 {
        2.0
    } else if m < 7.5 {
        5.0
    } else {
        10.0
    };
    m * 10f64.powf(e)
}

/// One plan-view panel: the workspace, the measured poses and their error
/// vectors magnified so that the largest spans 10 % of the width, with a
/// scale bar in a readable unit.
pub(crate) fn arrow_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    workspace: &[Vec<f64>],
    points: &[Vec<f64>],
    errors: &[Vec<f64>],
    color: RGBColor,
    title: &str,
    axes: [&str; 2],
) -> Result<()> {
    let (x0, x1) = range(workspace.iter().chain(points).map(|p| p[0]), 0.04);
    let biggest = errors
        .iter()
        .map(|e| e[0].hypot(e[1]))
        .fold(0.0, f64::max)
        .max(1e-12);
    let scale = 0.10 * (x1 - x0) / biggest;
    let tips = || {
        points
            .iter()
            .zip(errors)
            .map(move |(p, e)| [p[0] + scale * e[0], p[1] + scale * e[1]])
    };
    let (x0, x1) = range(
        workspace
            .iter()
            .chain(points)
            .map(|p| p[0])
            .chain(tips().map(|t| t[0])),
        0.04,
    );
    let (y0, y1) = range(
        workspace
            .iter()
            .chain(points)
            .map(|p| p[1])
            .chain(tips().map(|t| t[1])),
        0.06,
    );
    let bar = nice(biggest / 2.0);
    let (f, unit) = pkmcal::Unit::Millimetre.readable(bar);
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .caption(
            format!("{title}, error vectors magnified {}×", tick(&scale.round())),
            (FONT, TITLE_PX),
        )
        .x_label_area_size(36)
        .y_label_area_size(55)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(format!("{} (mm)", axes[0]))
        .y_desc(format!("{} (mm)", axes[1]))
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style((FONT, LABEL_PX))
        .axis_desc_style((FONT, TITLE_PX))
        .max_light_lines(0)
        .draw()
        .map_err(err)?;
    // A spatial lattice seen from one side puts many points on one pixel:
    // each pixel's dot is drawn once (the same picture, a fraction of the
    // SVG).
    let mut seen = std::collections::HashSet::new();
    let dots: Vec<&Vec<f64>> = workspace
        .iter()
        .filter(|p| seen.insert(chart.backend_coord(&(p[0], p[1]))))
        .collect();
    chart
        .draw_series(
            dots.iter()
                .map(|p| Circle::new((p[0], p[1]), 1, GREY.filled())),
        )
        .map_err(err)?;
    chart
        .draw_series(points.iter().zip(errors).map(|(p, e)| {
            PathElement::new(
                vec![(p[0], p[1]), (p[0] + scale * e[0], p[1] + scale * e[1])],
                color.stroke_width(2),
            )
        }))
        .map_err(err)?;
    chart
        .draw_series(
            points
                .iter()
                .map(|p| Circle::new((p[0], p[1]), 3, BLACK.filled())),
        )
        .map_err(err)?;
    // The scale bar below the plot, in the bottom-left corner of the panel
    // (under the y axis's numbers, left of the x axis's name), where no pose
    // or vector can be.
    let (a, _) = chart.backend_coord(&(x0, y0));
    let (b, _) = chart.backend_coord(&(x0 + scale * bar, y0));
    let len = (b - a).max(2);
    let y = area.dim_in_pixel().1 as i32 - 10;
    area.draw(&PathElement::new(
        vec![(12, y), (12 + len, y)],
        color.stroke_width(3),
    ))
    .map_err(err)?;
    area.draw(&Text::new(
        format!("{} {unit} error", tick(&(bar * f))),
        (18 + len, y - 7),
        (FONT, LABEL_PX).into_font(),
    ))
    .map_err(err)?;
    Ok(())
}

/// One view of [`workspace_errors`]: the lattice, the poses, the errors
/// before and after (projected), the axes' names and the row's height.
struct Row<'a> {
    ws: Vec<Vec<f64>>,
    ps: Vec<Vec<f64>>,
    b: Vec<Vec<f64>>,
    a: Vec<Vec<f64>>,
    names: [&'a str; 2],
    h: u32,
}

/// The workspace seen from above (and, for a spatial tool, from the front and
/// the side): measured poses (black) with their error vectors before (left,
/// red) and after (right, blue) calibration, each magnified for its own size,
/// over the usable workspace (grey). `views` are the projections, each the
/// indices of two tool axes and their names; one row per view.
pub fn workspace_errors(
    workspace: &[Vec<f64>],
    points: &[Vec<f64>],
    before: &[Vec<f64>],
    after: &[Vec<f64>],
    views: &[([usize; 2], [&str; 2])],
) -> Result<Figure> {
    let keep = shown(points.len(), before, after);
    let thinned = shown_words(keep.len(), points.len(), "measured poses");
    let pick = |v: &[Vec<f64>]| -> Vec<Vec<f64>> {
        keep.iter().filter_map(|&i| v.get(i).cloned()).collect()
    };
    let (points, before, after) = (&pick(points)[..], &pick(before)[..], &pick(after)[..]);
    let project = |v: &[Vec<f64>], [a, b]: [usize; 2]| -> Vec<Vec<f64>> {
        v.iter().map(|p| vec![p[a], p[b]]).collect()
    };
    let w = FIGURE_WIDTH / 2;
    let rows: Vec<Row> = views
        .iter()
        .map(|&(ix, names)| {
            let (ws, ps) = (project(workspace, ix), project(points, ix));
            let (x0, x1) = range(ws.iter().chain(&ps).map(|p| p[0]), 0.04);
            let (y0, y1) = range(ws.iter().chain(&ps).map(|p| p[1]), 0.06);
            let h = ((w as f64 - 70.0) * (y1 - y0) / (x1 - x0) + 90.0).clamp(400.0, 1000.0) as u32;
            Row {
                ws,
                ps,
                b: project(before, ix),
                a: project(after, ix),
                names,
                h,
            }
        })
        .collect();
    let height: u32 = rows.iter().map(|r| r.h).sum();
    render!(
        "workspace",
        "Errors over the workspace",
        format!(
            "Measured poses (black) over the usable workspace (grey) with each error vector, before calibration (left, red) and after (right, blue); each panel magnifies its vectors for their size and has its own scale bar. A spatial tool is seen from above (x–y), from the front (x–z) and from the side (y–z).{thinned}"
        ),
        (2 * w, height.max(1)),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let mut rest = root.clone();
            for Row {
                ws,
                ps,
                b,
                a,
                names,
                h,
            } in &rows
            {
                let (row, below) = rest.split_vertically(*h);
                let (l, r) = row.split_horizontally(w);
                let view = format!("{}–{}", names[0], names[1]);
                let t = |s: &str| {
                    if rows.len() > 1 {
                        format!("{view}, {s}")
                    } else {
                        s.to_string()
                    }
                };
                arrow_panel(&l, ws, ps, b, BEFORE, &t("before calibration"), *names)?;
                arrow_panel(&r, ws, ps, a, AFTER, &t("after calibration"), *names)?;
                rest = below;
            }
            Ok(())
        }
    )
}

fn heat(t: f64) -> RGBColor {
    // Ordered ramp from pale yellow to dark red.
    let t = t.clamp(0.0, 1.0);
    let stops = [
        (255.0, 255.0, 204.0),
        (253.0, 141.0, 60.0),
        (189.0, 0.0, 38.0),
        (80.0, 0.0, 20.0),
    ];
    let f = t * (stops.len() - 1) as f64;
    let i = (f.floor() as usize).min(stops.len() - 2);
    let u = f - i as f64;
    let (a, b) = (stops[i], stops[i + 1]);
    RGBColor(
        (a.0 + u * (b.0 - a.0)) as u8,
        (a.1 + u * (b.1 - a.1)) as u8,
        (a.2 + u * (b.2 - a.2)) as u8,
    )
}

/// A map on two length axes: a slice through the workspace.
pub struct MapSlice {
    /// The two axes (`x`, `y`), mm.
    pub axes: [String; 2],
    /// Where the other axes are held (`z = 700 mm, rx = 0 mrad, …`), empty
    /// for a planar tool without orientation.
    pub held: String,
    /// Lattice points (the two axes' values), mm.
    pub points: Vec<[f64; 2]>,
    /// Lattice spacing, mm.
    pub spacing: f64,
    /// Position error without compensation at each point, mm.
    pub miss: Vec<f64>,
    /// Standard deviation of the predicted position at each point, mm.
    pub sigma: Vec<f64>,
}

/// The same quantities along one angle axis, the others held.
pub struct MapSweep {
    /// The angle axis (`rx`, `phi`).
    pub axis: String,
    /// Where the other axes are held.
    pub held: String,
    /// Angle at each point, rad.
    pub values: Vec<f64>,
    /// Position error without compensation, mm.
    pub miss: Vec<f64>,
    /// Standard deviation of the predicted position, mm.
    pub sigma: Vec<f64>,
}

/// Width of one map panel with its colour bar (px).
pub(crate) const MAP_PANEL_WIDTH: u32 = FIGURE_WIDTH / 2;
/// Height of a row title strip (px).
const ROW_TITLE: u32 = 24;
/// Height of the row of angle sweeps (px).
const SWEEP_HEIGHT: u32 = 280;

/// One heat map with a labelled colour bar; values in mm shown in a
/// readable unit.
pub(crate) fn heat_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    slice: &MapSlice,
    title: &str,
    values: &[f64],
) -> Result<()> {
    let (x0, x1) = range(slice.points.iter().map(|p| p[0]), 0.04);
    let (y0, y1) = range(slice.points.iter().map(|p| p[1]), 0.04);
    // Colours span the values' range (the bar gives the numbers), so that
    // the variation shows even when it is small next to the mean.
    let (mut vmin, mut vmax) = range(values.iter().copied(), 0.0);
    if vmax - vmin < 1e-3 * vmax.abs() {
        vmin = 0.0;
    }
    vmax = vmax.max(vmin + 1e-15);
    let (f, unit) = pkmcal::Unit::Millimetre.readable(vmax);
    let (plot, legend) = area.split_horizontally(MAP_PANEL_WIDTH - 110);
    let mut chart = ChartBuilder::on(&plot)
        .margin(10)
        .caption(format!("{title} ({unit})"), (FONT, TITLE_PX))
        .x_label_area_size(34)
        .y_label_area_size(56)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(format!("{} (mm)", slice.axes[0]))
        .y_desc(format!("{} (mm)", slice.axes[1]))
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style((FONT, LABEL_PX))
        .axis_desc_style((FONT, LABEL_PX))
        .max_light_lines(0)
        .draw()
        .map_err(err)?;
    let hs = slice.spacing / 2.0;
    chart
        .draw_series(slice.points.iter().zip(values).map(|(p, v)| {
            Rectangle::new(
                [(p[0] - hs, p[1] - hs), (p[0] + hs, p[1] + hs)],
                heat((v - vmin) / (vmax - vmin)).filled(),
            )
        }))
        .map_err(err)?;
    let (bottom, top) = (vmin * f, vmax * f);
    let mut bar = ChartBuilder::on(&legend)
        .margin_top(44)
        .margin_bottom(44)
        .margin_left(10)
        .right_y_label_area_size(70)
        .build_cartesian_2d(0.0..1.0, bottom..top)
        .map_err(err)?;
    bar.configure_mesh()
        .disable_x_axis()
        .disable_mesh()
        // Ticks long enough, and apart from their numbers, not to read as
        // minus signs.
        .set_tick_mark_size(plotters::chart::LabelAreaPosition::Right, 7)
        .y_labels(5)
        .y_label_formatter(&tick)
        .label_style((FONT, LABEL_PX))
        .draw()
        .map_err(err)?;
    let steps = 60;
    bar.draw_series((0..steps).map(|i| {
        let a = bottom + (top - bottom) * i as f64 / steps as f64;
        let b = bottom + (top - bottom) * (i + 1) as f64 / steps as f64;
        Rectangle::new([(0.0, a), (1.0, b)], heat(i as f64 / steps as f64).filled())
    }))
    .map_err(err)?;
    // The colour bar's label: what and in which unit.
    legend
        .draw(&Text::new(
            unit.to_string(),
            (12, 22),
            (FONT, TITLE_PX).into_font(),
        ))
        .map_err(err)?;
    Ok(())
}

/// One angle sweep: a quantity (mm) against the angle (mrad).
fn sweep_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    sweep: &MapSweep,
    what: &str,
    values: &[f64],
    color: RGBColor,
) -> Result<()> {
    let x: Vec<f64> = sweep.values.iter().map(|v| v * 1e3).collect();
    let (x0, x1) = range(x.iter().copied(), 0.02);
    let vmax = values.iter().fold(0.0f64, |m, v| m.max(*v));
    let (f, unit) = pkmcal::Unit::Millimetre.readable(vmax);
    let mut chart = ChartBuilder::on(area)
        .margin(10)
        .x_label_area_size(34)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, 0.0..(vmax * f * 1.08).max(1e-12))
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(format!("{} (mrad)", sweep.axis))
        .y_desc(format!("{what} ({unit})"))
        .x_labels(6)
        .y_labels(5)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style((FONT, LABEL_PX))
        .axis_desc_style((FONT, LABEL_PX))
        .max_light_lines(0)
        .draw()
        .map_err(err)?;
    chart
        .draw_series(LineSeries::new(
            x.iter().zip(values).map(|(a, v)| (*a, v * f)),
            color.stroke_width(2),
        ))
        .map_err(err)?;
    Ok(())
}

/// Maps over the usable workspace of the position error without
/// compensation and of the uncertainty of the prediction: heat maps on
/// slices through the workspace (x–y, and x–z, y–z for a spatial tool), the
/// other axes held at the workspace centre (`centre` says where); and, for
/// each angle axis, both quantities along that angle. Each panel in a unit
/// readable for its size, every colour bar labelled.
pub fn workspace_maps(slices: &[MapSlice], sweeps: &[MapSweep], centre: &str) -> Result<Figure> {
    let heights: Vec<u32> = slices
        .iter()
        .map(|s| {
            let (x0, x1) = range(s.points.iter().map(|p| p[0]), 0.04);
            let (y0, y1) = range(s.points.iter().map(|p| p[1]), 0.04);
            ((MAP_PANEL_WIDTH as f64 - 170.0) * (y1 - y0) / (x1 - x0) + 90.0).clamp(300.0, 700.0)
                as u32
                + ROW_TITLE
        })
        .collect();
    let sweep_height = if sweeps.is_empty() {
        0
    } else {
        ROW_TITLE + 2 * SWEEP_HEIGHT
    };
    let w = 2 * MAP_PANEL_WIDTH;
    let h = heights.iter().sum::<u32>() + sweep_height;
    let held: Vec<&str> = slices
        .iter()
        .map(|s| s.held.as_str())
        .chain(sweeps.iter().map(|s| s.held.as_str()))
        .filter(|s| !s.is_empty())
        .collect();
    render!(
        "maps",
        "Predicted error over the workspace",
        format!(
            "Left: how far the tool would miss each target without compensation under the identified parameters (nominal commands). Right: standard deviation of the predicted position from the parameters' covariance.{}",
            if held.is_empty() {
                String::new()
            } else {
                " Each map is a slice through the workspace, the other axes held where its title says; the bottom rows follow each angle with the other axes at the centre (red: error without compensation, blue: σ).".to_string()
            }
        ),
        (w, h),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let mut rest = root.clone();
            for (s, hgt) in slices.iter().zip(&heights) {
                let (row, r) = rest.split_vertically(*hgt);
                rest = r;
                let (title, body) = row.split_vertically(ROW_TITLE);
                let text = if s.held.is_empty() {
                    format!("{}–{}, over the usable workspace", s.axes[0], s.axes[1])
                } else {
                    format!("{}–{} slice at {}", s.axes[0], s.axes[1], s.held)
                };
                title
                    .draw(&Text::new(text, (12, 4), (FONT, TITLE_PX).into_font()))
                    .map_err(err)?;
                let (l, r) = body.split_horizontally(MAP_PANEL_WIDTH);
                heat_panel(&l, s, "error without compensation", &s.miss)?;
                heat_panel(&r, s, "uncertainty of the prediction, σ", &s.sigma)?;
            }
            if !sweeps.is_empty() {
                let (title, body) = rest.split_vertically(ROW_TITLE);
                title
                    .draw(&Text::new(
                        format!("along each angle, the other axes at the centre ({centre})"),
                        (12, 4),
                        (FONT, TITLE_PX).into_font(),
                    ))
                    .map_err(err)?;
                let cells = body.split_evenly((2, sweeps.len()));
                for (k, s) in sweeps.iter().enumerate() {
                    sweep_panel(&cells[k], s, "error without compensation", &s.miss, BEFORE)?;
                    sweep_panel(
                        &cells[sweeps.len() + k],
                        s,
                        "σ of the prediction",
                        &s.sigma,
                        AFTER,
                    )?;
                }
            }
            Ok(())
        }
    )
}

/// Inverse of the standard normal distribution function (the rational
/// approximation of P. J. Acklam, |error| < 1.2e-9; one function, so no
/// statistics crate).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.38357751867269e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// Residual histogram with the standard normal density, and a normal Q–Q plot,
/// of standardised residuals.
pub fn residuals(standardized: &[f64]) -> Result<Figure> {
    let mut sorted: Vec<f64> = standardized
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len().max(1);
    let lim = sorted.iter().fold(3.0f64, |m, v| m.max(v.abs())).ceil();
    let bins = 16usize;
    let width = 2.0 * lim / bins as f64;
    let mut counts = vec![0usize; bins];
    for v in &sorted {
        let i = (((v + lim) / width).floor() as isize).clamp(0, bins as isize - 1) as usize;
        counts[i] += 1;
    }
    let density: Vec<f64> = counts
        .iter()
        .map(|c| *c as f64 / (n as f64 * width))
        .collect();
    let top = density.iter().fold(0.45f64, |m, v| m.max(*v)) * 1.1;
    // The Q–Q plot's points: every quantile up to MAX_POSES_SHOWN, else an
    // even selection with both extremes (each at its own probability).
    let mut quantiles = pkmcal::engine::atlas::thin_evenly(sorted.len(), MAX_POSES_SHOWN);
    if quantiles.len() < sorted.len() {
        quantiles.insert(0, 0);
        quantiles.push(sorted.len() - 1);
        quantiles.dedup();
    }
    let thinned = if quantiles.len() < sorted.len() {
        format!(
            " The Q–Q plot draws {} of the {n} quantiles, spread evenly, both extremes included; the histogram counts them all.",
            quantiles.len()
        )
    } else {
        String::new()
    };
    render!(
        "residuals",
        "Residuals after calibration",
        format!(
            "The {n} residuals (predicted minus measured coordinates) divided by the residual standard deviation: histogram with the standard normal density, and quantiles against the normal ones (on the line if the noise is Gaussian).{thinned}"
        ),
        (1000u32, 420u32),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let (l, r) = root.split_horizontally(500);
            let mut hist = ChartBuilder::on(&l)
                .margin(10)
                .caption("residual histogram", (FONT, TITLE_PX))
                .x_label_area_size(34)
                .y_label_area_size(50)
                .build_cartesian_2d(-lim..lim, 0.0..top)
                .map_err(err)?;
            hist.configure_mesh()
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .x_desc("residual / σ")
                .y_desc("density")
                .label_style((FONT, LABEL_PX))
                .axis_desc_style((FONT, LABEL_PX))
                .max_light_lines(0)
                .draw()
                .map_err(err)?;
            hist.draw_series(density.iter().enumerate().map(|(i, d)| {
                let a = -lim + i as f64 * width;
                Rectangle::new([(a, 0.0), (a + width, *d)], AFTER.mix(0.5).filled())
            }))
            .map_err(err)?;
            hist.draw_series(LineSeries::new(
                (0..=200).map(|i| {
                    let x = -lim + 2.0 * lim * i as f64 / 200.0;
                    (
                        x,
                        (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt(),
                    )
                }),
                BLACK.stroke_width(2),
            ))
            .map_err(err)?;
            let mut qq = ChartBuilder::on(&r)
                .margin(10)
                .caption("normal Q–Q plot", (FONT, TITLE_PX))
                .x_label_area_size(34)
                .y_label_area_size(50)
                .build_cartesian_2d(-lim..lim, -lim..lim)
                .map_err(err)?;
            qq.configure_mesh()
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .x_desc("normal quantile")
                .y_desc("residual / σ")
                .label_style((FONT, LABEL_PX))
                .axis_desc_style((FONT, LABEL_PX))
                .max_light_lines(0)
                .draw()
                .map_err(err)?;
            qq.draw_series(LineSeries::new([(-lim, -lim), (lim, lim)], BLACK.mix(0.5)))
                .map_err(err)?;
            qq.draw_series(quantiles.iter().map(|&i| {
                let p = (i as f64 + 0.5) / n as f64;
                Circle::new((normal_quantile(p), sorted[i]), 3, AFTER.filled())
            }))
            .map_err(err)?;
            Ok(())
        }
    )
}

/// Singular values of the column-scaled identification Jacobian (log scale),
/// with the rank threshold.
pub fn singular_values(sv: &[f64], threshold: f64) -> Result<Figure> {
    let positive: Vec<f64> = sv.iter().map(|s| s.max(1e-16)).collect();
    let lo = positive
        .iter()
        .fold(f64::INFINITY, |m, v| m.min(*v))
        .min(threshold)
        / 3.0;
    let hi = positive.iter().fold(0.0f64, |m, v| m.max(*v)) * 3.0;
    let n = positive.len();
    render!(
        "singular-values",
        "Identifiability: singular values",
        format!(
            "The {n} singular values of the identification Jacobian with columns scaled to unit norm; below the red line a direction counts as unidentifiable. Their spread is the condition number."
        ),
        (
            (800u32).max(60 + 22 * n as u32).min(FIGURE_WIDTH),
            380u32 + LEGEND_HEIGHT
        ),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let (top, body) = root.split_vertically(LEGEND_HEIGHT);
            // The legend above the data.
            top.draw(&PathElement::new(
                vec![
                    (80, LEGEND_HEIGHT as i32 / 2),
                    (104, LEGEND_HEIGHT as i32 / 2),
                ],
                BEFORE.stroke_width(2),
            ))
            .map_err(err)?;
            top.draw(&Text::new(
                "rank threshold: below it a direction is unidentifiable",
                (112, LEGEND_HEIGHT as i32 / 2 - 8),
                (FONT, TITLE_PX).into_font(),
            ))
            .map_err(err)?;
            let mut chart = ChartBuilder::on(&body)
                .margin(12)
                .x_label_area_size(34)
                .y_label_area_size(70)
                .build_cartesian_2d(0.5f64..n as f64 + 0.5, (lo..hi).log_scale())
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("index")
                .x_label_formatter(&|x| format!("{}", x.round() as i64))
                .y_desc("singular value (column-scaled)")
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .label_style((FONT, LABEL_PX))
                .axis_desc_style((FONT, LABEL_PX))
                .max_light_lines(0)
                .draw()
                .map_err(err)?;
            chart
                .draw_series(positive.iter().enumerate().map(|(i, s)| {
                    Rectangle::new(
                        [(i as f64 + 0.65, lo), (i as f64 + 1.35, *s)],
                        AFTER.mix(0.6).filled(),
                    )
                }))
                .map_err(err)?;
            chart
                .draw_series(LineSeries::new(
                    [(0.5, threshold), (n as f64 + 0.5, threshold)],
                    BEFORE.stroke_width(2),
                ))
                .map_err(err)?;
            Ok(())
        }
    )
}
