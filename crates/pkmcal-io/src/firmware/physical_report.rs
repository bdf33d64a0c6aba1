//! The `--physical` report (`--report-dir`, issue 54): one self-contained
//! `report.html` for the printer's owner, with its figures beside it as
//! SVG and PNG. The verdict first, in words (what the probe pattern cannot
//! see, whether to load the height map, the drift); then the values to
//! write with their σ beside the firmware's own fit; the nozzle's error
//! over the bed after each (Z and XY) with its σ; the predicted cubes; the
//! next measurements in the firmware's commands; the height map's nodes.
//!
//! The page's data ([`Page`]) is built here from the fit; the command line
//! only says where it goes.

use super::height_map::{self, HeightMap};
use super::physical::{self, CubeError, ErrorSummary, PhysicalFit, Projection};
use super::physical_plan::{Extra, Suggestion};
use super::{Firmware, FirmwareValue, Flavour, PrinterCalibration, Sigma};
use crate::description::Mech;
use crate::error::Result;
use crate::figures::{self, Figure, err, range, register_font, render, tick};
use crate::report::{PAGE_END, escape, page_start};
use crate::text::Wording;
use pkmcal::Field;
use pkmcal::Params;
use pkmcal::identify::Drift;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// Every file the report writes (checked against the inputs first).
pub const FILES: &[&str] = &[
    "report.html",
    "nozzle-z.svg",
    "nozzle-z.png",
    "nozzle-xy.svg",
    "nozzle-xy.png",
    "nozzle-sigma.svg",
    "nozzle-sigma.png",
];

/// A parameter whose uncertainty the readings reduce by less than this
/// share (of its variance) is one the probe pattern cannot see.
pub const UNSEEN_FROM_DATA: f64 = 0.1;

/// A height map whose largest value is below this (mm) is not worth
/// loading: a tenth of a typical 0.2 mm first layer.
pub const MAP_WORTH_MM: f64 = 0.02;

/// Points across the bed's diameter of the report's error maps (those
/// within the build volume's radius are kept).
pub const MAP_POINTS: usize = 21;

/// The parts of the physical model, by the start of their parameters'
/// names, and what not seeing them means to the printer's owner.
const PARTS: [(&str, &[&str], &str); 6] = [
    (
        "tower radii",
        &["radius_"],
        "how far each tower stands from the centre: on the bed it moves with the arm lengths and the endstops, so heights alone do not separate them",
    ),
    (
        "tower angles",
        &["angle_"],
        "where each tower stands around the circle: it skews and scales X and Y, which probe heights see only weakly",
    ),
    (
        "tower lean",
        &["a.tilt", "b.tilt", "c.tilt"],
        "tower lean is not seen by heights at one level: it shifts and scales what is printed higher up",
    ),
    (
        "rod lengths",
        &["rod_"],
        "each arm length moves with its endstop: the heights see them together, not each rod; a rod pair's difference tilts the effector",
    ),
    (
        "ball joints",
        &["a1.", "a2.", "b1.", "b2.", "c1.", "c2."],
        "where the ball joints sit on the carriages and the effector: they tilt the effector, which the offset probe reads as height",
    ),
    (
        "bed tilt",
        &["bed."],
        "the bed's tilt: the probe sees it together with the towers' endstops",
    ),
];

/// A part of the printer the probe pattern cannot see.
#[derive(Debug, Clone, PartialEq)]
pub struct Unseen {
    /// The part (`tower lean`).
    pub part: &'static str,
    /// How many of its free parameters the readings do not see.
    pub blind: usize,
    /// Of how many.
    pub of: usize,
    /// What that means, in the printer's terms.
    pub meaning: &'static str,
}

/// The parts of the printer whose parameters the readings reduce by less
/// than [`UNSEEN_FROM_DATA`] of their uncertainty.
pub fn unseen(fit: &PhysicalFit) -> Vec<Unseen> {
    let cal = &fit.study.calibration;
    PARTS
        .iter()
        .filter_map(|(part, prefixes, meaning)| {
            let of_part: Vec<_> = cal
                .parameters
                .iter()
                .filter(|p| p.free && prefixes.iter().any(|x| p.name.starts_with(x)))
                .collect();
            let blind = of_part
                .iter()
                .filter(|p| p.from_data.is_some_and(|f| f < UNSEEN_FROM_DATA))
                .count();
            (blind > 0).then_some(Unseen {
                part,
                blind,
                of: of_part.len(),
                meaning,
            })
        })
        .collect()
}

/// Whether to load a height map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MapAdvice {
    /// Its uncertainty exceeds its values: what it corrects is not known.
    Uncertain {
        /// The largest value's size (mm).
        largest: f64,
        /// The largest σ (mm).
        sd: f64,
    },
    /// Its values are below [`MAP_WORTH_MM`]: not needed.
    Small {
        /// The largest value's size (mm).
        largest: f64,
    },
    /// Worth loading.
    Load {
        /// The largest value's size (mm).
        largest: f64,
        /// The largest σ (mm).
        sd: f64,
    },
}

/// Whether `map` is worth loading.
pub fn map_advice(map: &HeightMap) -> MapAdvice {
    let largest = map.values().iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    let sd = map.largest_sd().unwrap_or(0.0);
    if sd > largest {
        MapAdvice::Uncertain { largest, sd }
    } else if largest < MAP_WORTH_MM {
        MapAdvice::Small { largest }
    } else {
        MapAdvice::Load { largest, sd }
    }
}

impl MapAdvice {
    /// In words.
    pub fn words(&self) -> String {
        match *self {
            MapAdvice::Uncertain { largest, sd } => format!(
                "Do not load the height map yet: its uncertainty (σ up to {sd:.4} mm) exceeds what it corrects (up to {largest:.4} mm). Measure more first (the next measurements)."
            ),
            MapAdvice::Small { largest } => format!(
                "The height map is not needed: the written values leave at most {largest:.4} mm on the bed (under {MAP_WORTH_MM} mm)."
            ),
            MapAdvice::Load { largest, sd } => format!(
                "Load the height map: it corrects up to {largest:.4} mm on the bed, known to σ {sd:.4} mm."
            ),
        }
    }
}

/// An extra measurement in the firmware's commands (`firmware` the
/// printer's, the probe at `probe_offset` from the nozzle), the inputs it
/// is read back from named as the front end names them (`wording`).
pub fn measurement_words(
    extra: &Extra,
    firmware: Flavour,
    probe_offset: [f64; 2],
    wording: &Wording,
) -> String {
    let o = probe_offset;
    let input = wording.input;
    // The nozzle over `p` (x, y on the bed, mm).
    // To a tenth of a millimetre, never "-0.0".
    let mm = |v: f64| format!("{:.1}", (v * 10.0).round() / 10.0 + 0.0);
    let nozzle_at = |p: [f64; 2]| -> String { format!("G1 X{} Y{}", mm(p[0]), mm(p[1])) };
    let probe_at = |p: [f64; 2]| -> String {
        match firmware {
            Flavour::Klipper => format!(
                "G1 X{} Y{} then PROBE (the probe at {}, {})",
                mm(p[0] - o[0]),
                mm(p[1] - o[1]),
                mm(p[0]),
                mm(p[1])
            ),
            Flavour::RepRapFirmware => {
                format!("G30 P<next> X{} Y{} Z-99999 S-1", mm(p[0]), mm(p[1]))
            }
            Flavour::Marlin => format!("G30 X{} Y{}", mm(p[0]), mm(p[1])),
        }
    };
    let list = |points: &[[f64; 2]], at: &dyn Fn([f64; 2]) -> String| {
        points.iter().map(|p| at(*p)).collect::<Vec<_>>().join("; ")
    };
    match extra {
        Extra::ProbePoint { at } => format!(
            "one more probe point: {}{}",
            probe_at(*at),
            match firmware {
                Flavour::Klipper => format!(
                    ", read back from {} as a `probe` row: the x, y, z PROBE reports, surface 0 (DELTA_CALIBRATE saves only its own pattern)",
                    input(Field::Heights)
                ),
                Flavour::RepRapFirmware => format!(
                    ", its reading added to the probe file ({})",
                    input(Field::Probes)
                ),
                Flavour::Marlin => format!(
                    ", its `Bed X: … Y: … Z: …` report added to the probe log ({})",
                    input(Field::Probes)
                ),
            }
        ),
        Extra::SecondLevel { height, points } => format!(
            "{} probe heights on a {height} mm gauge block (known height): {}; read back from {} as `probe` rows: the nozzle's x, y, z the firmware displays when the probe triggers, surface {height}",
            points.len(),
            list(points, &probe_at),
            input(Field::Heights)
        ),
        Extra::NozzleTouches { points } => format!(
            "{} nozzle touches on the bed (a paper test, σ about {} mm): {}, then lower the nozzle until it grips the paper; read back from {} as `nozzle` rows: the x, y, z the firmware displays, surface the paper's thickness (about 0.1)",
            points.len(),
            super::physical_heights::TOUCH_NOISE_MM,
            list(points, &nozzle_at),
            input(Field::Heights)
        ),
        Extra::ObjectDistances => "the 12 distances of Klipper's calibration object (docs/prints/calibrate_size.stl) printed with the written values, measured with calipers: DELTA_ANALYZE CENTER_DISTS=… OUTER_DISTS=… (and the pillar widths), then SAVE_CONFIG".to_string(),
    }
}

/// One firmware value on the page.
#[derive(Debug, Clone, PartialEq)]
pub struct ValueRow {
    /// Where the firmware keeps it.
    pub name: String,
    /// Its unit.
    pub unit: &'static str,
    /// The configuration's value.
    pub current: f64,
    /// The firmware's own fit of the probe.
    pub own: f64,
    /// Its σ.
    pub own_sd: Option<f64>,
    /// The value written (for the nozzle).
    pub written: f64,
    /// Its σ ([`physical::written_values`]: the posterior's through the
    /// projection, or the firmware's own fit's where that is written;
    /// `None` or 0 for a value the fit holds).
    pub written_sd: Option<f64>,
}

/// The nozzle's error on the bed (z = 0) over the build volume's circle.
#[derive(Debug, Clone, PartialEq)]
pub struct BedErrors {
    /// The points (mm).
    pub points: Vec<[f64; 2]>,
    /// Their spacing (mm).
    pub spacing: f64,
    /// The error (x, y, z over the bed, mm) with the firmware's own fit.
    pub own: Vec<[f64; 3]>,
    /// With the written values.
    pub written: Vec<[f64; 3]>,
    /// σ of the written values' Z error at each point (mm).
    pub written_sd_z: Vec<f64>,
    /// σ of their XY error's length (mm; the root of the x and y
    /// variances).
    pub written_sd_xy: Vec<f64>,
    /// The largest σ of the own fit's Z and XY errors (mm).
    pub own_sd_max: [f64; 2],
    /// σ of the XY error's mean over the bed (mm): a shift of the whole
    /// print, which moves no part's size; the XY σ above are of the error
    /// less it.
    pub shift_sd: f64,
}

/// The mean XY error over the bed's points.
fn common_shift(e: &[[f64; 3]]) -> [f64; 2] {
    let n = e.len().max(1) as f64;
    [
        e.iter().map(|v| v[0]).sum::<f64>() / n,
        e.iter().map(|v| v[1]).sum::<f64>() / n,
    ]
}

/// One draw's error at a point, its XY less the draw's common shift.
fn add_relative(m: &mut [Moments; 3], e: &[f64; 3], shift: [f64; 2]) {
    m[0].add(e[0] - shift[0]);
    m[1].add(e[1] - shift[1]);
    m[2].add(e[2]);
}

/// The height map on the page.
#[derive(Debug, Clone, PartialEq)]
pub struct MapPart {
    /// The map.
    pub map: HeightMap,
    /// Whether to load it.
    pub advice: MapAdvice,
    /// Where it was written, if it was.
    pub written_to: Option<String>,
    /// How the front end is told to write it (its option or keyword).
    pub give: String,
}

/// An extra measurement on the page.
#[derive(Debug, Clone, PartialEq)]
pub struct NextMeasurement {
    /// What, in the firmware's commands.
    pub words: String,
    /// The cube's largest σ now and after it (mm).
    pub largest: (f64, f64),
    /// The share of the cube errors' variance it removes.
    pub share: f64,
}

/// Everything the page shows.
pub struct Page {
    /// The firmware's name.
    pub firmware: &'static str,
    /// Where the readings came from.
    pub source: String,
    /// Probe heights and distances read.
    pub readings: (usize, usize),
    /// Free parameters of the physical model.
    pub free: usize,
    /// What the probe pattern cannot see.
    pub unseen: Vec<Unseen>,
    /// The nozzle's error over the build volume: the current values, the
    /// firmware's own fit, the written values.
    pub errors: [ErrorSummary; 3],
    /// The same with the values for the nozzle (the projection), written
    /// or not.
    pub projected: ErrorSummary,
    /// Whether the values for the nozzle are the written ones (else the
    /// firmware's own fit is: [`physical::Choice::projection_written`]).
    pub projection_written: bool,
    /// Points and heights of the build-volume grid.
    pub grid: (usize, f64),
    /// The values.
    pub values: Vec<ValueRow>,
    /// The predicted cubes.
    pub cubes: Vec<CubeError>,
    /// The error maps on the bed.
    pub bed: BedErrors,
    /// The height map, where the firmware keeps one.
    pub map: Option<MapPart>,
    /// The next measurements, best first.
    pub next: Vec<NextMeasurement>,
    /// The drift against `--previous` (where from, and the test).
    pub drift: Option<(String, Drift)>,
    /// The probe's σ the fit weighed the heights with.
    pub probe_noise: physical::ProbeNoise,
    /// The tolerances the fit held the parts by.
    pub tolerances: Vec<physical::ToleranceGroup>,
    /// How many of the readings are touches measured by hand, nozzle
    /// touches of them.
    pub touches: (usize, usize),
}

/// What [`Page::build`] takes: the fit and what the command computed of it.
pub struct Inputs<'a> {
    /// The printer.
    pub printer: &'a dyn Firmware,
    /// Where its readings came from.
    pub source: &'a str,
    /// The firmware's own fit of its probe.
    pub own: &'a PrinterCalibration,
    /// The physical fit.
    pub fit: &'a PhysicalFit,
    /// The firmware's description.
    pub fw_mech: &'a Mech,
    /// The written values.
    pub projection: &'a Projection,
    /// The values for the nozzle's errors (the projection's), and whether
    /// they are written ([`physical::Choice`]).
    pub projected: (ErrorSummary, bool),
    /// The values written, each with its σ ([`physical::written_values`]).
    pub values: &'a [FirmwareValue],
    /// The nozzle's error summaries: the current values, the own fit.
    pub before: [ErrorSummary; 2],
    /// The predicted cubes ([`physical::cube_errors`]).
    pub cubes: &'a [CubeError],
    /// The next measurements ([`super::physical_plan::suggest`]).
    pub suggestions: &'a [Suggestion],
    /// How many of them are shown ([`super::physical_plan::SHOWN`]).
    pub shown: usize,
    /// The drift against a previous calibration.
    pub drift: Option<(String, Drift)>,
    /// The height map's nodes across (`--mesh-points`).
    pub mesh_points: Option<usize>,
    /// Where the height map is written, if it is.
    pub height_map: Option<&'a Path>,
    /// The front end's names of its inputs.
    pub wording: &'a Wording,
}

/// Mean and standard deviation accumulator.
#[derive(Default, Clone, Copy)]
struct Moments {
    sum: f64,
    sq: f64,
    n: f64,
}

impl Moments {
    fn add(&mut self, v: f64) {
        self.sum += v;
        self.sq += v * v;
        self.n += 1.0;
    }
    fn sd(&self) -> f64 {
        let n = self.n.max(2.0);
        ((self.sq - self.sum * self.sum / n) / (n - 1.0))
            .max(0.0)
            .sqrt()
    }
}

impl Page {
    /// The page's data: the bed maps and the written values' σ from the
    /// fit's posterior draws ([`physical::posterior_draws`]), the height
    /// map on the firmware's mesh.
    pub fn build(i: &Inputs<'_>) -> Result<Page> {
        let fit = i.fit;
        let ld = &fit.delta;
        let cal = &fit.study.calibration;
        let own_cal = i.own.calibration();
        let proj = i.projection;
        let nozzle = ld.nozzle();
        let fw_bed = ld.corrects_bed_tilt.then_some(proj.bed.as_slice());
        let own_bed = ld
            .corrects_bed_tilt
            .then_some(own_cal.measurement.as_slice());
        // The bed's grid.
        let r = ld.print_radius();
        let n = MAP_POINTS;
        let spacing = 2.0 * r / (n - 1) as f64;
        let mut grid = vec![];
        for a in 0..n {
            for b in 0..n {
                let (x, y) = (-r + a as f64 * spacing, -r + b as f64 * spacing);
                if x.hypot(y) <= r * (1.0 + 1e-9) {
                    grid.push([x, y, 0.0]);
                }
            }
        }
        let errs =
            |fw_p: &Params, fw_b: Option<&[f64]>, p: &Params, bed: &[f64], t: &[[f64; 3]]| {
                physical::nozzle_errors(i.fw_mech, fw_p, fw_b, &fit.mech, p, bed, nozzle, t)
            };
        // In the bed's frame, as the summary's errors: XY less the one shift
        // and turn of the whole print that no part shows.
        let own = physical::in_bed_frame(
            &grid,
            &errs(
                &own_cal.params,
                own_bed,
                &cal.params,
                &cal.measurement,
                &grid,
            )?,
        );
        let written = physical::in_bed_frame(
            &grid,
            &errs(&proj.params, fw_bed, &cal.params, &cal.measurement, &grid)?,
        );
        let own_values: Vec<FirmwareValue> = super::written(i.printer, i.own)?.values;
        let mut sd_map = vec![[Moments::default(); 3]; grid.len()];
        let mut own_sd = vec![[Moments::default(); 3]; grid.len()];
        let mut shift = [Moments::default(); 2];
        for (p, bed) in &physical::posterior_draws(fit, physical::CUBE_DRAWS, physical::CUBE_SEED)?
        {
            let e = errs(&proj.params, fw_bed, p, bed, &grid)?;
            let mean = common_shift(&e);
            (0..2).for_each(|k| shift[k].add(mean[k]));
            for (m, e) in sd_map.iter_mut().zip(&e) {
                add_relative(m, e, mean);
            }
            let e = errs(&own_cal.params, own_bed, p, bed, &grid)?;
            let mean = common_shift(&e);
            for (m, e) in own_sd.iter_mut().zip(&e) {
                add_relative(m, e, mean);
            }
        }
        let values = i
            .values
            .iter()
            .zip(&own_values)
            .map(|(v, o)| ValueRow {
                name: v.name.clone(),
                unit: v.unit,
                current: v.before,
                own: o.after,
                own_sd: o.sigma,
                written: v.after,
                written_sd: v.sigma,
            })
            .collect();
        let xy_sd = |m: &[Moments; 3]| m[0].sd().hypot(m[1].sd());
        let own_sd_max = own_sd.iter().fold([0.0_f64; 2], |a, m| {
            [a[0].max(m[2].sd()), a[1].max(xy_sd(m))]
        });
        let bed = BedErrors {
            points: grid.iter().map(|p| [p[0], p[1]]).collect(),
            spacing,
            own,
            written,
            written_sd_z: sd_map.iter().map(|m| m[2].sd()).collect(),
            written_sd_xy: sd_map.iter().map(xy_sd).collect(),
            own_sd_max,
            shift_sd: shift[0].sd().hypot(shift[1].sd()),
        };
        let map = match i.printer.mesh_layout(r, i.mesh_points)? {
            Some(layout) => {
                let map = height_map::residual_map(fit, i.fw_mech, &proj.params, fw_bed, &layout)?;
                Some(MapPart {
                    advice: map_advice(&map),
                    map,
                    written_to: i.height_map.map(|p| p.display().to_string()),
                    give: (i.wording.input)(Field::HeightMap),
                })
            }
            None => None,
        };
        let next = i
            .suggestions
            .iter()
            .take(i.shown)
            .map(|s| NextMeasurement {
                words: measurement_words(&s.extra, ld.firmware, ld.probe_offset, i.wording),
                largest: s.largest(),
                share: s.variance_removed(),
            })
            .collect();
        Ok(Page {
            firmware: i.printer.name(),
            source: i.source.to_string(),
            readings: (fit.readings.poses.len(), fit.readings.distances.len()),
            free: fit.free_names.len(),
            unseen: unseen(fit),
            errors: [i.before[0], i.before[1], proj.summary],
            projected: i.projected.0,
            projection_written: i.projected.1,
            grid: (proj.targets.len(), r),
            values,
            cubes: i.cubes.to_vec(),
            bed,
            map,
            next,
            drift: i.drift.clone(),
            probe_noise: i.fit.probe_noise,
            tolerances: physical::tolerance_groups(i.fit),
            touches: i.fit.touches,
        })
    }
}

/// A σ as the values' table shows it ([`Sigma::of`]): "fixed" for a
/// value the fit holds; none, an empty cell.
fn sigma_cell(sigma: Option<f64>) -> String {
    match sigma.map(Sigma::of) {
        Some(Sigma::Known(s)) => format!("{s:.4}"),
        Some(Sigma::Unknown) => "unknown".to_string(),
        Some(Sigma::Fixed) => "fixed".to_string(),
        None => String::new(),
    }
}

/// Blue (negative) through white to red (positive), `t` in −1..1.
fn diverging(t: f64) -> RGBColor {
    let t = t.clamp(-1.0, 1.0);
    let (end, u) = if t < 0.0 {
        ((33.0, 102.0, 172.0), -t)
    } else {
        ((178.0, 24.0, 43.0), t)
    };
    let mix = |a: f64| (255.0 + u * (a - 255.0)) as u8;
    RGBColor(mix(end.0), mix(end.1), mix(end.2))
}

/// The XY figure's arrows stand at every this many points of the maps'
/// grid, each way.
const ARROW_STRIDE: i64 = 2;

/// Height of a map panel (px): square plots beside their colour bars.
const MAP_HEIGHT: u32 = 470;

/// A signed map (mm) on the bed, coloured on −`limit`…`limit`.
fn signed_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    bed: &BedErrors,
    values: &[f64],
    limit: f64,
    title: &str,
) -> Result<()> {
    let (x0, x1) = range(bed.points.iter().map(|p| p[0]), 0.06);
    let (y0, y1) = range(bed.points.iter().map(|p| p[1]), 0.06);
    let limit = limit.max(1e-12);
    let (f, unit) = pkmcal::Unit::Millimetre.readable(limit);
    let (plot, legend) = area.split_horizontally(figures::MAP_PANEL_WIDTH - 110);
    let mut chart = ChartBuilder::on(&plot)
        .margin(10)
        .caption(
            format!("{title} ({unit})"),
            (figures::FONT, figures::TITLE_PX),
        )
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("x (mm)")
        .y_desc("y (mm)")
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style((figures::FONT, figures::LABEL_PX))
        .axis_desc_style((figures::FONT, figures::LABEL_PX))
        .max_light_lines(0)
        .draw()
        .map_err(err)?;
    let h = bed.spacing / 2.0;
    chart
        .draw_series(bed.points.iter().zip(values).map(|(p, v)| {
            Rectangle::new(
                [(p[0] - h, p[1] - h), (p[0] + h, p[1] + h)],
                diverging(v / limit).filled(),
            )
        }))
        .map_err(err)?;
    let top = limit * f;
    let mut bar = ChartBuilder::on(&legend)
        .margin_top(44)
        .margin_bottom(50)
        .margin_left(10)
        .right_y_label_area_size(70)
        .build_cartesian_2d(0.0..1.0, -top..top)
        .map_err(err)?;
    bar.configure_mesh()
        .disable_x_axis()
        .disable_mesh()
        .set_tick_mark_size(plotters::chart::LabelAreaPosition::Right, 7)
        .y_labels(5)
        .y_label_formatter(&tick)
        .label_style((figures::FONT, figures::LABEL_PX))
        .draw()
        .map_err(err)?;
    let steps = 60;
    bar.draw_series((0..steps).map(|k| {
        let a = -top + 2.0 * top * k as f64 / steps as f64;
        let b = -top + 2.0 * top * (k + 1) as f64 / steps as f64;
        Rectangle::new(
            [(0.0, a), (1.0, b)],
            diverging(-1.0 + 2.0 * (k as f64 + 0.5) / steps as f64).filled(),
        )
    }))
    .map_err(err)?;
    legend
        .draw(&Text::new(
            unit.to_string(),
            (12, 22),
            (figures::FONT, figures::LABEL_PX).into_font(),
        ))
        .map_err(err)?;
    Ok(())
}

/// The page's figures: the Z error on the bed with the firmware's own fit
/// and with the written values; their XY errors as arrows; the σ of the
/// written values' Z and XY errors.
pub fn figures(page: &Page) -> Result<Vec<Figure>> {
    let bed = &page.bed;
    let w = figures::MAP_PANEL_WIDTH;
    let z = |v: &[[f64; 3]]| -> Vec<f64> { v.iter().map(|e| e[2]).collect() };
    let (own_z, written_z) = (z(&bed.own), z(&bed.written));
    let limit = own_z
        .iter()
        .chain(&written_z)
        .fold(0.0_f64, |m, v| m.max(v.abs()));
    let fw = page.firmware;
    let z_fig: Result<Figure> = render!(
        "nozzle-z",
        "The nozzle's height error on the bed",
        format!(
            "The nozzle's height above the bed minus its commanded height, on the bed (z = 0) within {:.0} mm of the centre, on the fitted printer: left with {fw}'s own fit of the probe, right with the written values; one colour scale (red: the nozzle too high, blue: too low). The σ of the right map is in the last figure; the left map's is up to {:.4} mm.",
            page.grid.1, bed.own_sd_max[0]
        ),
        (2 * w, MAP_HEIGHT),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let (l, r) = root.split_horizontally(w);
            signed_panel(&l, bed, &own_z, limit, &format!("{fw}'s own fit"))?;
            signed_panel(&r, bed, &written_z, limit, "the written values")?;
            Ok(())
        }
    );
    let z_fig = z_fig?;
    // Every other point each way: arrows apart enough to read.
    let r = page.grid.1;
    let keep: Vec<usize> = (0..bed.points.len())
        .filter(|&k| {
            bed.points[k]
                .iter()
                .all(|c| ((c + r) / bed.spacing).round() as i64 % ARROW_STRIDE == 0)
        })
        .collect();
    let pts: Vec<Vec<f64>> = keep.iter().map(|&k| bed.points[k].to_vec()).collect();
    let xy = |v: &[[f64; 3]]| -> Vec<Vec<f64>> {
        keep.iter().map(|&k| vec![v[k][0], v[k][1]]).collect()
    };
    let (own_xy, written_xy) = (xy(&bed.own), xy(&bed.written));
    let largest_sd_xy = bed.written_sd_xy.iter().copied().fold(0.0, f64::max);
    let xy_fig: Result<Figure> = render!(
        "nozzle-xy",
        "The nozzle's XY error on the bed",
        format!(
            "Where the nozzle lands minus where it was sent, on the bed (z = 0), as arrows from each point, less the one shift and turn of the whole print that no part shows (the bed's frame, as the summary's errors): left with {fw}'s own fit of the probe (red), right with the written values (blue); each panel magnifies its arrows for their size, its scale bar in the bottom-left corner. σ of the written values' XY error, less the whole print's common shift (σ {:.4} mm): up to {largest_sd_xy:.4} mm (last figure); of the own fit's: up to {:.4} mm.",
            bed.shift_sd, bed.own_sd_max[1]
        ),
        (2 * w, MAP_HEIGHT + 40),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let (l, r) = root.split_horizontally(w);
            figures::arrow_panel(
                &l,
                &pts,
                &pts,
                &own_xy,
                figures::BEFORE,
                &format!("{fw}'s own fit"),
                ["x", "y"],
            )?;
            figures::arrow_panel(
                &r,
                &pts,
                &pts,
                &written_xy,
                figures::AFTER,
                "the written values",
                ["x", "y"],
            )?;
            Ok(())
        }
    );
    let xy_fig = xy_fig?;
    let slice = |v: &[f64]| figures::MapSlice {
        axes: ["x".into(), "y".into()],
        held: String::new(),
        points: bed.points.clone(),
        spacing: bed.spacing,
        miss: v.to_vec(),
        sigma: v.to_vec(),
    };
    let (sz, sxy) = (slice(&bed.written_sd_z), slice(&bed.written_sd_xy));
    let sigma_fig: Result<Figure> = render!(
        "nozzle-sigma",
        "Uncertainty of the written values' error maps",
        format!(
            "The standard deviation of the nozzle's error with the written values, from {} draws of the fitted printer from the fit's uncertainty (the values held): left its height error, right its XY error less the whole print's common shift (σ of that shift: {:.4} mm; it moves where a part stands, not its size). Where a σ exceeds the maps' values, the maps say little yet.",
            physical::CUBE_DRAWS,
            bed.shift_sd
        ),
        (2 * w, MAP_HEIGHT),
        |root| {
            root.fill(&WHITE).map_err(err)?;
            let (l, r) = root.split_horizontally(w);
            figures::heat_panel(&l, &sz, "σ of the height error", &sz.miss)?;
            figures::heat_panel(&r, &sxy, "σ of the XY error less the shift", &sxy.miss)?;
            Ok(())
        }
    );
    let sigma_fig = sigma_fig?;
    Ok(vec![z_fig, xy_fig, sigma_fig])
}

fn summary_cells(e: &ErrorSummary) -> String {
    format!(
        "<td>{:.4}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td>",
        e.xy_rms, e.xy_max, e.z_rms, e.z_max
    )
}

/// The report page.
pub fn html(page: &Page, figs: &[Figure]) -> String {
    let fw = page.firmware;
    let mut h = page_start(&format!(
        "pkmcal physical calibration — {fw} ({})",
        page.source
    ));
    h.push_str("<style>.verdict li { margin: 0.4em 0; } .verdict { font-size: 1.05em; } td.l, th.l { text-align: left; }</style>");
    let [current, own, written] = &page.errors;
    // The verdict, in words.
    h.push_str("<h2>Verdict</h2><ul class=\"verdict\">");
    let _ = write!(
        h,
        "<li>With the written values the nozzle misses by <b>{:.4} mm</b> RMS in XY and <b>{:.4} mm</b> RMS in Z over the build volume; with {fw}'s own fit of the probe by {:.4} mm and {:.4} mm; with the current values by {:.4} mm and {:.4} mm.</li>",
        written.xy_rms, written.z_rms, own.xy_rms, own.z_rms, current.xy_rms, current.z_rms
    );
    let _ = write!(
        h,
        "<li>{}</li>",
        if page.projection_written {
            format!(
                "The values for the nozzle are written: over the fit's uncertainty they lower the nozzle's error beyond one standard deviation ({fw}'s own fit: {:.4} mm XY, {:.4} mm Z RMS).",
                own.xy_rms, own.z_rms
            )
        } else {
            format!(
                "{fw}'s own fit is written: the values for the nozzle ({:.4} mm XY, {:.4} mm Z RMS on the fitted printer) would not lower the error beyond one standard deviation of the fit's uncertainty; the readings cannot show them better.",
                page.projected.xy_rms, page.projected.z_rms
            )
        }
    );
    if page.unseen.is_empty() {
        h.push_str("<li>The probe pattern sees every part of the printer's model.</li>");
    } else {
        let _ = write!(
            h,
            "<li>What the probe pattern cannot see (the readings take less than {:.0} % of their uncertainty; the tolerances hold them):<ul>",
            100.0 * UNSEEN_FROM_DATA
        );
        for u in &page.unseen {
            let _ = write!(
                h,
                "<li><b>{}</b> ({} of {}): {}</li>",
                u.part, u.blind, u.of, u.meaning
            );
        }
        h.push_str("</ul></li>");
    }
    for (c, where_) in page.cubes.iter().zip(["at the centre", "at the edge"]) {
        let _ = write!(
            h,
            "<li>A {} mm cube {where_} ({:.0}, {:.0}) would print {:+.3} ± {:.3} mm in X, {:+.3} ± {:.3} mm in Y, its top flat to {:.3} ± {:.3} mm.</li>",
            physical::CUBE_MM,
            c.centre[0],
            c.centre[1],
            c.size[0],
            c.size_sd[0],
            c.size[1],
            c.size_sd[1],
            c.flatness,
            c.flatness_sd
        );
    }
    if let Some(m) = &page.map {
        let _ = write!(h, "<li>{}</li>", escape(&m.advice.words()));
    }
    if let Some(n) = page.next.first() {
        let _ = write!(
            h,
            "<li>The measurement that would shrink the cube's uncertainty most: {} (largest σ {:.3} → {:.3} mm).</li>",
            escape(&n.words),
            n.largest.0,
            n.largest.1
        );
    }
    if let Some((from, d)) = &page.drift {
        let _ = write!(
            h,
            "<li>Since {}: <b>{}</b> (χ² {:.1} over {} directions, p {:.3}).</li>",
            escape(from),
            if d.joint_drift {
                "the printer changed"
            } else {
                "no change beyond the two calibrations' uncertainty"
            },
            d.chi2,
            d.dof,
            d.p_joint
        );
    }
    h.push_str("</ul>");
    // The values.
    let _ = write!(
        h,
        "<h2>Values to write</h2><p>{}</p><div class=\"wide\"><table><tr><th>{fw} value</th><th>unit</th><th>current</th><th>{fw}'s own fit</th><th>σ</th><th>written</th><th>σ</th></tr>",
        if page.projection_written {
            format!(
                "The written values are the values for the nozzle: they minimise the nozzle's error over the build volume ({} points within {:.0} mm of the centre, z {} mm), not the probe's at the probed points, and over the fit's uncertainty they do so by more than one standard deviation. σ: for {fw}'s own fit from its covariance (<i>fixed</i>: a value its fit leaves as it was); for the written values from {} draws of the fitted printer through the projection (linearised).",
                page.grid.0,
                page.grid.1,
                physical::GRID_HEIGHTS_MM.map(|z| format!("{z}")).join(", "),
                physical::CHOICE_DRAWS
            )
        } else {
            format!(
                "The written values are {fw}'s own fit: the values for the nozzle (which minimise the nozzle's error over the build volume, {} points within {:.0} mm of the centre, z {} mm) would not lower it by more than one standard deviation over the fit's uncertainty: the readings cannot show them better. σ: from {fw}'s fit's covariance (<i>fixed</i>: a value its fit leaves as it was).",
                page.grid.0,
                page.grid.1,
                physical::GRID_HEIGHTS_MM.map(|z| format!("{z}")).join(", "),
            )
        }
    );
    for v in &page.values {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{:.6}</td><td>{:.6}</td><td>{}</td><td><b>{:.6}</b></td><td>{}</td></tr>",
            escape(&v.name),
            v.unit,
            v.current,
            v.own,
            sigma_cell(v.own_sd),
            v.written,
            sigma_cell(v.written_sd)
        );
    }
    h.push_str("</table></div>");
    // The errors.
    h.push_str("<h2>The nozzle's error over the build volume</h2><table><tr><th rowspan=\"2\">values</th><th colspan=\"2\">XY error, mm</th><th colspan=\"2\">Z error, mm</th></tr><tr><th>RMS</th><th>max</th><th>RMS</th><th>max</th></tr>");
    let mark = |written: bool| if written { " (written)" } else { "" };
    for (label, e) in [
        ("the current values".to_string(), current),
        (
            format!(
                "{fw}'s own fit of the probe{}",
                mark(!page.projection_written)
            ),
            own,
        ),
        (
            format!("the values for the nozzle{}", mark(page.projection_written)),
            &page.projected,
        ),
    ] {
        let _ = write!(
            h,
            "<tr><td>{}</td>{}</tr>",
            escape(&label),
            summary_cells(e)
        );
    }
    h.push_str("</table>");
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
    // The cubes.
    let _ = write!(
        h,
        "<h2>Predicted {} mm cube</h2><p>Printed with the written values; ± one standard deviation from the fit's uncertainty ({} draws).</p><table><tr><th>where</th><th>centre (x, y), mm</th><th>X size error, mm</th><th>Y size error, mm</th><th>top flatness, mm</th></tr>",
        physical::CUBE_MM,
        physical::CUBE_DRAWS
    );
    for (c, where_) in page.cubes.iter().zip(["centre", "edge"]) {
        let _ = write!(
            h,
            "<tr><td>{where_}</td><td>{:.0}, {:.0}</td><td>{:+.3} ± {:.3}</td><td>{:+.3} ± {:.3}</td><td>{:.3} ± {:.3}</td></tr>",
            c.centre[0],
            c.centre[1],
            c.size[0],
            c.size_sd[0],
            c.size[1],
            c.size_sd[1],
            c.flatness,
            c.flatness_sd
        );
    }
    h.push_str("</table>");
    // The next measurements.
    if !page.next.is_empty() {
        h.push_str("<h2>Next measurements</h2><p>Ranked by how much of the cube errors' variance each would remove (linearised, the fit's noise for each reading).</p><table><tr><th>#</th><th class=\"l\">measurement, in the firmware's commands</th><th>cube's largest σ, mm</th><th>variance removed</th></tr>");
        for (k, n) in page.next.iter().enumerate() {
            let _ = write!(
                h,
                "<tr><td>{}</td><td class=\"l\">{}</td><td>{:.3} → {:.3}</td><td>{:.0} %</td></tr>",
                k + 1,
                escape(&n.words),
                n.largest.0,
                n.largest.1,
                100.0 * n.share
            );
        }
        h.push_str("</table>");
    }
    // The height map.
    if let Some(m) = &page.map {
        let _ = write!(
            h,
            "<h2>Height map</h2><p>{} {}</p>",
            escape(&m.advice.words()),
            match &m.written_to {
                Some(p) => format!(
                    "Written to <code>{}</code>; its nodes (mm; ± σ), the value {fw} adds to Z:",
                    escape(p)
                ),
                None => format!(
                    "Not written (give {} to write it); its nodes would be (mm; ± σ), the value the firmware adds to Z:",
                    m.give
                ),
            }
        );
        h.push_str("<div class=\"wide\"><table><tr><th>y \\ x, mm</th>");
        for x in &m.map.xs {
            let _ = write!(h, "<th>{x:.1}</th>");
        }
        h.push_str("</tr>");
        for (j, y) in m.map.ys.iter().enumerate().rev() {
            let _ = write!(h, "<tr><th>{y:.1}</th>");
            for (v, s) in m.map.z[j].iter().zip(&m.map.sd[j]) {
                match (v, s) {
                    (Some(v), Some(s)) => {
                        let _ = write!(h, "<td>{v:+.4} ± {s:.4}</td>");
                    }
                    (Some(v), None) => {
                        let _ = write!(h, "<td>{v:+.4}</td>");
                    }
                    _ => h.push_str("<td></td>"),
                }
            }
            h.push_str("</tr>");
        }
        h.push_str("</table></div>");
    }
    // The drift.
    if let Some((from, d)) = &page.drift {
        let _ = write!(
            h,
            "<h2>Since {}</h2><p>{}: the joint test over the {} directions both calibrations' data see gives χ² {:.1}, p {:.3}; {} parameters held by the tolerances are not compared.</p>",
            escape(from),
            if d.joint_drift {
                "The printer changed"
            } else {
                "No change beyond the two calibrations' uncertainty"
            },
            d.dof,
            d.chi2,
            d.p_joint,
            d.untested.len()
        );
        if !d.parameters.is_empty() {
            h.push_str("<table><tr><th>parameter</th><th>change</th><th>σ</th><th>p</th><th>changed</th></tr>");
            for p in &d.parameters {
                let _ = write!(
                    h,
                    "<tr><td>{}</td><td>{:+.4}</td><td>{:.4}</td><td>{:.3}</td><td>{}</td></tr>",
                    escape(&p.name),
                    p.change,
                    p.sigma,
                    p.p_value,
                    if p.drifted { "yes" } else { "no" }
                );
            }
            h.push_str("</table>");
        }
    }
    // The fit.
    let _ = write!(
        h,
        "<h2>The fit</h2><table class=\"kv\"><tr><td>readings</td><td>{} probe heights{} from {}{}</td></tr><tr><td>model</td><td>the physical delta: {} parameters within their tolerances ({}; probe σ {} mm{})</td></tr><tr><td>pkmcal</td><td>{}</td></tr></table>",
        page.readings.0 - page.touches.0,
        if page.readings.1 > 0 {
            format!(" and {} distances", page.readings.1)
        } else {
            String::new()
        },
        escape(&page.source),
        if page.touches.0 > 0 {
            format!(
                "; {} touches measured by hand ({} of the nozzle)",
                page.touches.0, page.touches.1
            )
        } else {
            String::new()
        },
        page.free,
        escape(
            &page
                .tolerances
                .iter()
                .map(physical::ToleranceGroup::words)
                .collect::<Vec<_>>()
                .join(", ")
        ),
        page.probe_noise.mm(),
        stated_words(page.probe_noise),
        env!("CARGO_PKG_VERSION")
    );
    h.push_str(PAGE_END);
    h
}

/// What follows the probe's σ where it is said: nothing for pkmcal's
/// assumption (the text before a user could state it), ` as stated` for a
/// user's.
pub fn stated_words(noise: physical::ProbeNoise) -> &'static str {
    if noise.assumed() { "" } else { " as stated" }
}

/// Write the figures and `report.html` into `dir` (staged: all or nothing).
pub fn write_report_dir(run: &crate::Run<'_>, dir: &Path, page: &Page) -> Result<()> {
    register_font();
    run.files.create_dir(dir)?;
    let figs = figures(page)?;
    for f in &figs {
        run.files
            .stage(&dir.join(format!("{}.svg", f.name)), f.svg.as_bytes())?;
        run.files
            .stage(&dir.join(format!("{}.png", f.name)), &f.png)?;
    }
    run.files
        .stage(&dir.join("report.html"), html(page, &figs).as_bytes())?;
    Ok(())
}
