//! Figures of a calibration, as pure functions from results to SVG text and
//! PNG bytes (plotters). Text in PNGs is drawn with the bundled DejaVu Sans
//! (`assets/`), so rendering never depends on the machine's fonts; SVGs name
//! the same family, which the HTML report embeds.

use anyhow::{Result, anyhow};
use plotters::prelude::*;
use std::sync::Once;

/// The bundled font (DejaVu Sans, free licence in `assets/DejaVuSans-LICENSE.txt`).
pub const FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
/// The font family the figures use.
pub const FONT: &str = "DejaVu Sans";

const BEFORE: RGBColor = RGBColor(200, 55, 45);
const AFTER: RGBColor = RGBColor(30, 100, 200);
const GREY: RGBColor = RGBColor(200, 200, 200);

fn register_font() {
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

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("drawing failed: {e:?}")
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
        let img =
            image::RgbImage::from_raw($w, $h, buf).ok_or_else(|| anyhow!("bad image buffer"))?;
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
        Ok(Figure {
            name: $name,
            title: $title.into(),
            caption: $caption.into(),
            svg,
            png,
        })
    }};
}

/// Tick label with about three significant digits and no "-0".
fn tick(v: &f64) -> String {
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

fn range(values: impl Iterator<Item = f64>, pad: f64) -> (f64, f64) {
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

/// Fig. 9 of the paper: X, Y and distance error at each measured pose, before
/// and after calibration (lengths in mm, angles in mrad).
pub fn errors_per_pose(
    before: &[Vec<f64>],
    after: &[Vec<f64>],
    axes: &[String],
    units: &[pkmcal::Unit],
) -> Result<Figure> {
    let n = before.len();
    let lengths: Vec<usize> = (0..units.len())
        .filter(|&k| units[k] == pkmcal::Unit::Millimetre)
        .collect();
    let dist = |e: &Vec<f64>| lengths.iter().map(|&k| e[k] * e[k]).sum::<f64>().sqrt();
    let mut panels: Vec<(String, Vec<f64>, Vec<f64>)> = axes
        .iter()
        .zip(units)
        .enumerate()
        .map(|(k, (a, u))| {
            let (f, sym) = match u {
                pkmcal::Unit::Radian => (1e3, "mrad"),
                u => (1.0, u.symbol()),
            };
            (
                format!("{} error ({sym})", a.to_uppercase()),
                before.iter().map(|e| e[k] * f).collect(),
                after.iter().map(|e| e[k] * f).collect(),
            )
        })
        .collect();
    if !lengths.is_empty() {
        panels.push((
            "distance error (mm)".into(),
            before.iter().map(dist).collect(),
            after.iter().map(dist).collect(),
        ));
    }
    render!(
        "errors",
        "Errors at each measured pose (paper Fig. 9)",
        format!(
            "Error of each tool coordinate and distance error of each of the {n} measured poses before (red) and after (blue) calibration (lengths in mm, angles in mrad)."
        ),
        (1000u32, 780u32),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let rows = root.split_evenly((panels.len(), 1));
            for (area, (label, b, a)) in rows.iter().zip(&panels) {
                let (lo, hi) = range(b.iter().chain(a).copied().chain([0.0]), 0.08);
                let mut chart = ChartBuilder::on(area)
                    .margin(8)
                    .x_label_area_size(32)
                    .y_label_area_size(70)
                    .build_cartesian_2d(0.5f64..n as f64 + 0.5, lo..hi)
                    .map_err(err)?;
                chart
                    .configure_mesh()
                    .x_desc("measured pose")
                    .y_desc(label.as_str())
                    .x_label_formatter(&|x| format!("{}", x.round() as i64))
                    .y_label_formatter(&tick)
                    .label_style((FONT, 13))
                    .axis_desc_style((FONT, 14))
                    .light_line_style(WHITE)
                    .draw()
                    .map_err(err)?;
                chart
                    .draw_series(LineSeries::new(
                        [(0.5, 0.0), (n as f64 + 0.5, 0.0)],
                        BLACK.mix(0.4),
                    ))
                    .map_err(err)?;
                for (vals, color, name) in [(b, BEFORE, "before"), (a, AFTER, "after")] {
                    chart
                        .draw_series(LineSeries::new(
                            vals.iter().enumerate().map(|(i, v)| (i as f64 + 1.0, *v)),
                            color.mix(0.5),
                        ))
                        .map_err(err)?;
                    chart
                        .draw_series(
                            vals.iter()
                                .enumerate()
                                .map(|(i, v)| Circle::new((i as f64 + 1.0, *v), 3, color.filled())),
                        )
                        .map_err(err)?
                        .label(name)
                        .legend(move |(x, y)| Circle::new((x + 8, y), 4, color.filled()));
                }
                chart
                    .configure_series_labels()
                    .label_font((FONT, 13))
                    .border_style(BLACK.mix(0.3))
                    .background_style(WHITE.mix(0.9))
                    .position(SeriesLabelPosition::UpperRight)
                    .draw()
                    .map_err(err)?;
            }
            Ok(())
        }
    )
}

/// One parameter of Fig. 8.
pub struct ParamBar {
    pub name: String,
    pub change: f64,
    pub sigma: f64,
}

/// Fig. 8 of the paper: identified parameter changes with ±2σ bars, one panel
/// per unit group.
pub fn parameter_changes(groups: &[(String, Vec<ParamBar>)]) -> Result<Figure> {
    let groups: Vec<&(String, Vec<ParamBar>)> = groups.iter().filter(|g| !g.1.is_empty()).collect();
    let widths: Vec<u32> = groups.iter().map(|g| 120 + 55 * g.1.len() as u32).collect();
    let total: u32 = widths.iter().sum::<u32>().max(400);
    render!(
        "parameters",
        "Identified parameter changes (paper Fig. 8)",
        "Identified minus nominal value of each free parameter, grouped by unit; black bars span ±2 standard deviations.",
        (total, 460u32),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let mut rest = root.clone();
            for (g, w) in groups.iter().zip(&widths) {
                let (area, r) = rest.split_horizontally(*w);
                rest = r;
                let (unit, bars) = (&g.0, &g.1);
                let (lo, hi) = range(
                    bars.iter()
                        .flat_map(|b| [b.change - 2.0 * b.sigma, b.change + 2.0 * b.sigma, 0.0]),
                    0.1,
                );
                let n = bars.len();
                let mut chart = ChartBuilder::on(&area)
                    .margin(10)
                    .caption(unit.as_str(), (FONT, 15))
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
                    .y_desc("identified − nominal")
                    .y_label_formatter(&tick)
                    .label_style((FONT, 13))
                    .axis_desc_style((FONT, 13))
                    .light_line_style(WHITE)
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

/// The workspace seen from above: measured poses with their error vectors
/// before and after (scaled), over the usable workspace.
pub fn workspace_errors(
    workspace: &[Vec<f64>],
    points: &[Vec<f64>],
    before: &[Vec<f64>],
    after: &[Vec<f64>],
) -> Result<Figure> {
    let (x0, x1) = range(workspace.iter().chain(points).map(|p| p[0]), 0.04);
    let biggest = before
        .iter()
        .map(|e| e[0].hypot(e[1]))
        .fold(0.0, f64::max)
        .max(1e-9);
    // Arrows: the largest error before calibration spans 10 % of the width.
    let scale = 0.10 * (x1 - x0) / biggest;
    let tips = || {
        points
            .iter()
            .zip(before.iter().chain(after))
            .map(move |(p, e)| vec![p[0] + scale * e[0], p[1] + scale * e[1]])
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
    let bar_mm = nice(biggest / 2.0);
    let w = 900u32;
    let h = ((w as f64) * (y1 - y0) / (x1 - x0)).clamp(400.0, 1400.0) as u32;
    render!(
        "workspace",
        "Errors over the workspace",
        format!(
            "Measured poses (black) over the usable workspace (grey), with each error vector before (red) and after (blue) calibration, magnified {scale:.0}×; the bar is {bar_mm} mm of error."
        ),
        (w, h),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let mut chart = ChartBuilder::on(root)
                .margin(12)
                .x_label_area_size(36)
                .y_label_area_size(55)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("x (mm)")
                .y_desc("y (mm)")
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .light_line_style(WHITE)
                .draw()
                .map_err(err)?;
            chart
                .draw_series(
                    workspace
                        .iter()
                        .map(|p| Circle::new((p[0], p[1]), 1, GREY.filled())),
                )
                .map_err(err)?;
            for (errors, color, name) in [
                (before, BEFORE, "error before"),
                (after, AFTER, "error after"),
            ] {
                chart
                    .draw_series(points.iter().zip(errors).map(|(p, e)| {
                        PathElement::new(
                            vec![(p[0], p[1]), (p[0] + scale * e[0], p[1] + scale * e[1])],
                            color.stroke_width(2),
                        )
                    }))
                    .map_err(err)?
                    .label(name)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                    });
            }
            chart
                .draw_series(
                    points
                        .iter()
                        .map(|p| Circle::new((p[0], p[1]), 3, BLACK.filled())),
                )
                .map_err(err)?;
            // Scale bar in the lower left corner.
            let sx = x0 + 0.05 * (x1 - x0);
            let sy = y0 + 0.05 * (y1 - y0);
            chart
                .draw_series([PathElement::new(
                    vec![(sx, sy), (sx + scale * bar_mm, sy)],
                    BLACK.stroke_width(3),
                )])
                .map_err(err)?;
            chart
                .draw_series([Text::new(
                    format!("{bar_mm} mm error"),
                    (sx, sy + 0.025 * (y1 - y0)),
                    (FONT, 13).into_font(),
                )])
                .map_err(err)?;
            chart
                .configure_series_labels()
                .label_font((FONT, 13))
                .border_style(BLACK.mix(0.3))
                .background_style(WHITE.mix(0.9))
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(err)?;
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

/// Maps over the usable workspace of a per-point value (one panel each):
/// e.g. the predicted error magnitude and its uncertainty.
pub fn workspace_maps(
    points: &[Vec<f64>],
    spacing: f64,
    panels: &[(String, Vec<f64>)],
) -> Result<Figure> {
    let (x0, x1) = range(points.iter().map(|p| p[0]), 0.04);
    let (y0, y1) = range(points.iter().map(|p| p[1]), 0.04);
    let pw = 560u32;
    let ph = ((pw as f64 - 120.0) * (y1 - y0) / (x1 - x0) + 90.0).clamp(300.0, 1100.0) as u32;
    let w = pw * panels.len() as u32;
    render!(
        "maps",
        "Predicted error over the workspace",
        "Left: how far the tool would miss each target without compensation under the identified parameters (nominal commands), mm. Right: standard deviation of the predicted position from the parameters' covariance, mm.",
        (w, ph),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let areas = root.split_evenly((1, panels.len()));
            for (area, (label, values)) in areas.iter().zip(panels) {
                let (_, vmax) = range(values.iter().copied().chain([0.0]), 0.0);
                let (plot, legend) = area.split_horizontally(pw - 110);
                let mut chart = ChartBuilder::on(&plot)
                    .margin(10)
                    .caption(label.as_str(), (FONT, 14))
                    .x_label_area_size(34)
                    .y_label_area_size(50)
                    .build_cartesian_2d(x0..x1, y0..y1)
                    .map_err(err)?;
                chart
                    .configure_mesh()
                    .x_desc("x (mm)")
                    .y_desc("y (mm)")
                    .x_label_formatter(&tick)
                    .y_label_formatter(&tick)
                    .label_style((FONT, 12))
                    .axis_desc_style((FONT, 13))
                    .light_line_style(WHITE)
                    .draw()
                    .map_err(err)?;
                let hs = spacing / 2.0;
                chart
                    .draw_series(points.iter().zip(values).map(|(p, v)| {
                        Rectangle::new(
                            [(p[0] - hs, p[1] - hs), (p[0] + hs, p[1] + hs)],
                            heat(v / vmax).filled(),
                        )
                    }))
                    .map_err(err)?;
                let mut bar = ChartBuilder::on(&legend)
                    .margin_top(40)
                    .margin_bottom(44)
                    .margin_left(10)
                    .right_y_label_area_size(70)
                    .build_cartesian_2d(0.0..1.0, 0.0..vmax.max(1e-12))
                    .map_err(err)?;
                bar.configure_mesh()
                    .disable_x_axis()
                    .disable_mesh()
                    .y_labels(5)
                    .y_label_formatter(&tick)
                    .label_style((FONT, 12))
                    .draw()
                    .map_err(err)?;
                let steps = 60;
                bar.draw_series((0..steps).map(|i| {
                    let a = vmax * i as f64 / steps as f64;
                    let b = vmax * (i + 1) as f64 / steps as f64;
                    Rectangle::new([(0.0, a), (1.0, b)], heat(i as f64 / steps as f64).filled())
                }))
                .map_err(err)?;
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
    render!(
        "residuals",
        "Residuals after calibration",
        format!(
            "The {n} residuals (predicted minus measured coordinates) divided by the residual standard deviation: histogram with the standard normal density, and quantiles against the normal ones (on the line if the noise is Gaussian)."
        ),
        (1000u32, 420u32),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let (l, r) = root.split_horizontally(500);
            let mut hist = ChartBuilder::on(&l)
                .margin(10)
                .caption("residual histogram", (FONT, 14))
                .x_label_area_size(34)
                .y_label_area_size(50)
                .build_cartesian_2d(-lim..lim, 0.0..top)
                .map_err(err)?;
            hist.configure_mesh()
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .x_desc("residual / σ")
                .y_desc("density")
                .label_style((FONT, 12))
                .axis_desc_style((FONT, 13))
                .light_line_style(WHITE)
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
                .caption("normal Q–Q plot", (FONT, 14))
                .x_label_area_size(34)
                .y_label_area_size(50)
                .build_cartesian_2d(-lim..lim, -lim..lim)
                .map_err(err)?;
            qq.configure_mesh()
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .x_desc("normal quantile")
                .y_desc("residual / σ")
                .label_style((FONT, 12))
                .axis_desc_style((FONT, 13))
                .light_line_style(WHITE)
                .draw()
                .map_err(err)?;
            qq.draw_series(LineSeries::new([(-lim, -lim), (lim, lim)], BLACK.mix(0.5)))
                .map_err(err)?;
            qq.draw_series(sorted.iter().enumerate().map(|(i, v)| {
                let p = (i as f64 + 0.5) / n as f64;
                Circle::new((normal_quantile(p), *v), 3, AFTER.filled())
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
        (800u32, 380u32),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let mut chart = ChartBuilder::on(root)
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
                .label_style((FONT, 12))
                .axis_desc_style((FONT, 13))
                .light_line_style(WHITE)
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
                .map_err(err)?
                .label("rank threshold")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], BEFORE.stroke_width(2))
                });
            chart
                .configure_series_labels()
                .label_font((FONT, 12))
                .border_style(BLACK.mix(0.3))
                .background_style(WHITE.mix(0.9))
                .draw()
                .map_err(err)?;
            Ok(())
        }
    )
}
