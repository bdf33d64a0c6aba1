//! Marlin's own delta calibration, `G33`, as its `G33.cpp` runs it: probe
//! the centre, the towers and the points opposite them on the calibration
//! circle (`P2`, `P3`; with intermediate points averaged onto them for `P4`
//! to `P10`), adjust the endstops, the radius and the tower angle trims by
//! its hand-derived matrices scaled by factors it computes from the
//! kinematics, normalise, probe again, until the standard deviation of the
//! heights stops falling; then roll back to the best iteration.
//!
//! The probing is a function the caller gives (the firmware's settings and
//! a point give the height the probe reports), so that `G33` can run on a
//! printer a calibration identified and be compared with it. The arithmetic
//! is Marlin's, in double precision (Marlin's single-precision floats differ
//! from it by about 1e-5 mm).

use super::marlin::{LetterB, MarlinDelta, MarlinPrinter};
use super::{PrinterCalibration, Spread};
use crate::error::{Error, Result};
use pkmcal::Mechanism as _;

/// The points of G33's calibration circle, and the centre.
const NPP: usize = 6;
const CEN: usize = 0;
const A: usize = 1;
const AB: usize = 2;
const B: usize = 3;
const BC: usize = 4;
const C: usize = 5;
const CA: usize = 6;

/// The most iterations G33 runs.
const MAX_ITERATIONS: usize = 31;

/// G33's probe points where none are asked for (Marlin's
/// `DELTA_CALIBRATION_DEFAULT_POINTS`).
pub const DEFAULT_POINTS: u8 = 4;

/// The fewest probe points a comparison runs G33 with (`P1`: the height
/// alone; `P0` probes nothing).
pub const FEWEST_POINTS: u8 = 1;

/// The most probe points G33 takes (its `P`).
pub const MOST_POINTS: u8 = 10;

/// What `G33` is asked for: its parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct G33Options {
    /// `P`: the probe points (0 to 10).
    pub points: u8,
    /// Calibrate the tower angles (`T` absent).
    pub towers: bool,
    /// The calibration radius (mm) it probes at, as it prints it
    /// (`Checking... AC at radius:…`).
    pub radius: f64,
    /// `C`: stop at this standard deviation (mm); 0: at the best.
    pub precision: f64,
    /// `F`: at least this many iterations.
    pub force: u8,
}

impl G33Options {
    /// What this calibration adjusts, in words, and how many independent
    /// settings that is (the three angle trims are normalised to sum 0, so
    /// count two).
    pub fn factors(&self) -> (usize, &'static str) {
        match self.points {
            0 => (0, "nothing (normalises the endstops and angle trims)"),
            1 => (1, "the height"),
            2 => (4, "the height, the endstops and the radius"),
            _ if !self.towers => (4, "the height, the endstops and the radius"),
            _ => (
                6,
                "the height, the endstops, the radius and the tower angles",
            ),
        }
    }
}

/// How `G33` ended.
#[derive(Debug, Clone, PartialEq)]
pub struct G33Run {
    /// The settings it leaves.
    pub settings: MarlinDelta,
    /// The standard deviation of each iteration's heights (mm), as it
    /// prints them.
    pub std_devs: Vec<f64>,
    /// Whether it rolled back to an earlier iteration.
    pub rolled_back: bool,
    /// Points probed per iteration.
    pub probes: usize,
}

/// Marlin's `LROUND`.
fn lround(x: f64) -> i64 {
    x.round() as i64
}

/// The calibration points' carriage positions at the heights `z`
/// (`reverse_kinematics_probe_points`).
fn reverse(d: &MarlinDelta, z: &[f64; 7], dcr: f64) -> [[f64; 3]; 7] {
    std::array::from_fn(|rad| {
        let a = (210.0 + (360 / NPP) as f64 * (rad as f64 - 1.0)).to_radians();
        let r = if rad == CEN { 0.0 } else { dcr };
        d.carriages([a.cos() * r, a.sin() * r, z[rad]])
    })
}

/// The heights of carriage positions by G33's approximate forward
/// kinematics (`forward_kinematics_probe_points`).
fn forward(mm: &[[f64; 3]; 7], dcr: f64, radius: f64) -> [f64; 7] {
    let r_quot = dcr / radius;
    let zpp = |n: f64, i: usize, a: usize| ((1.0 + r_quot * n) / 3.0) * mm[i][a];
    let mut z = [0.0; 7];
    z[CEN] = zpp(0.0, CEN, 0) + zpp(0.0, CEN, 1) + zpp(0.0, CEN, 2);
    z[A] = zpp(2.0, A, 0) + zpp(-1.0, A, 1) + zpp(-1.0, A, 2);
    z[B] = zpp(-1.0, B, 0) + zpp(2.0, B, 1) + zpp(-1.0, B, 2);
    z[C] = zpp(-1.0, C, 0) + zpp(-1.0, C, 1) + zpp(2.0, C, 2);
    z[BC] = zpp(-2.0, BC, 0) + zpp(1.0, BC, 1) + zpp(1.0, BC, 2);
    z[CA] = zpp(1.0, CA, 0) + zpp(-2.0, CA, 1) + zpp(1.0, CA, 2);
    z[AB] = zpp(1.0, AB, 0) + zpp(1.0, AB, 1) + zpp(-2.0, AB, 2);
    z
}

/// `calc_kinematics_diff_probe_points`: the heights at the calibration
/// points after the endstops, the radius and the trims change by `e`, `r`,
/// `t`, as G33's approximate kinematics give them.
fn diff(d: &MarlinDelta, z: &mut [f64; 7], dcr: f64, e: [f64; 3], r: f64, t: [f64; 3]) {
    let z_center = z[CEN];
    let mut diff = reverse(d, z, dcr);
    let mut moved = d.clone();
    moved.radius += r;
    for (trim, dt) in moved.angle_trims.iter_mut().zip(t) {
        *trim += dt;
    }
    let new = reverse(&moved, z, dcr);
    for rad in 0..=NPP {
        for a in 0..3 {
            diff[rad][a] -= new[rad][a] + e[a];
        }
    }
    *z = forward(&diff, dcr, moved.radius);
    for rad in A..=NPP {
        z[rad] -= z[CEN] - z_center;
    }
    z[CEN] = z_center;
}

/// `auto_tune_h`.
fn tune_h(d: &MarlinDelta, dcr: f64) -> f64 {
    let r_quot = dcr / d.radius;
    1.0 / (r_quot / (2.0 / 3.0))
}

/// `auto_tune_r`.
fn tune_r(d: &MarlinDelta, dcr: f64) -> f64 {
    let diff_r = 0.01;
    let mut z = [0.0; 7];
    diff(d, &mut z, dcr, [0.0; 3], diff_r, [0.0; 3]);
    let r_fac = -(z[A] + z[B] + z[C] + z[BC] + z[CA] + z[AB]) / 6.0;
    diff_r / r_fac / 3.0
}

/// `auto_tune_a` (its heights carried from one tower to the next, as
/// Marlin's are).
fn tune_a(d: &MarlinDelta, dcr: f64) -> f64 {
    let diff_t = 0.01;
    let mut a_fac = 0.0;
    let mut z = [0.0; 7];
    for axis in 0..3 {
        let mut t = [0.0; 3];
        t[axis] = diff_t;
        diff(d, &mut z, dcr, [0.0; 3], 0.0, t);
        a_fac += z[(axis * 2 + NPP - 1) % NPP + 1] / 6.0;
        a_fac -= z[axis * 2 + 2] / 6.0;
    }
    diff_t / a_fac / 3.0
}

/// `probe_calibration_points`: the heights at the calibration points
/// (averaged for `P4` and more), probed with `probe`; the number of
/// points probed.
fn probe_points(
    z: &mut [f64; 7],
    points: u8,
    dcr: f64,
    towers_set: bool,
    probe: &mut dyn FnMut([f64; 2]) -> Result<f64>,
) -> Result<usize> {
    let p = points;
    let (p0, p1, p4) = (p == 0, p == 1, p == 2);
    let p4_opposite = p4 && !towers_set;
    let p7 = p >= 3;
    let (no_inter, one, two, four, six, eight, eleven, fourteen) = (
        p == 3,
        p == 4,
        p == 5,
        p == 6,
        p == 7,
        p == 8,
        p == 9,
        p == 10,
    );
    let inter = p >= 4;
    let six_center = (5..=7).contains(&p);
    let nine_center = p >= 8;
    *z = [0.0; 7];
    let mut count = 0;
    if p0 {
        return Ok(0);
    }
    if !no_inter && !four && !eleven {
        z[CEN] += probe([0.0, 0.0])?;
        count += 1;
    }
    if p7 {
        let start = if nine_center {
            CA as f64 + 1.0 / 3.0
        } else if six_center {
            CA as f64
        } else {
            C as f64
        };
        let steps = if nine_center {
            2.0 / 3.0
        } else if six_center {
            1.0
        } else {
            2.0
        };
        let mut rad = start;
        while rad > CEN as f64 + 0.9999 {
            let a = (210.0 + (360 / NPP) as f64 * (rad - 1.0)).to_radians();
            let r = dcr * 0.1;
            z[CEN] += probe([a.cos() * r, a.sin() * r])?;
            count += 1;
            rad -= steps;
        }
        z[CEN] /= if two { 7.0 } else { p as f64 };
    }
    if !p1 {
        let start = if p4_opposite { AB } else { A } as f64;
        let steps = if fourteen {
            1.0 / 15.0
        } else if eleven {
            1.0 / 12.0
        } else if eight {
            1.0 / 9.0
        } else if six {
            1.0 / 7.0
        } else if four {
            1.0 / 5.0
        } else if two {
            1.0 / 3.0
        } else if one {
            1.0 / 2.0
        } else if no_inter {
            1.0
        } else {
            2.0
        };
        let mut zig_zag = true;
        let mut rad = start;
        let step = if nine_center { steps * 3.0 } else { steps };
        while rad < NPP as f64 + 0.9999 {
            let offset = if nine_center { 2 } else { 0 };
            for circle in 0..=offset {
                let a = (210.0 + (360 / NPP) as f64 * (rad - 1.0)).to_radians();
                let k = if zig_zag { offset - circle } else { circle };
                let r = dcr * (1.0 - 0.1 * k as f64);
                let interpol = rad % 1.0;
                let z_temp = probe([a.cos() * r, a.sin() * r])?;
                count += 1;
                let first = (lround(rad - interpol + NPP as f64 - 1.0) as usize) % NPP + 1;
                let second = (lround(rad - interpol) as usize) % NPP + 1;
                z[first] += z_temp * (interpol * 90.0).to_radians().cos().powi(2);
                z[second] += z_temp * (interpol * 90.0).to_radians().sin().powi(2);
            }
            zig_zag = !zig_zag;
            rad += step;
        }
        if inter {
            for v in z.iter_mut().skip(A) {
                *v /= 1.0 / steps;
            }
        }
    }
    Ok(count)
}

/// `std_dev_points`: the heights' RMS about 0, rounded to 1 µm as G33
/// rounds it (plus its 0.00001).
fn std_dev(z: &[f64; 7], p0: bool, p1: bool, p4: bool, p4_opposite: bool) -> f64 {
    if !p0 && !p1 {
        let mut s2 = z[CEN] * z[CEN];
        let mut n = 1.0;
        let mut rad = if p4_opposite { AB } else { A };
        while rad <= NPP {
            s2 += z[rad] * z[rad];
            n += 1.0;
            rad += if p4 { 2 } else { 1 };
        }
        return lround((s2 / n).sqrt() * 1000.0) as f64 / 1000.0 + 0.00001;
    }
    0.00001
}

/// Run G33 from the settings `start` on the printer that `probe` measures:
/// `probe(settings, nozzle_xy)` is the height the probe reports with the
/// nozzle over `nozzle_xy` under `settings`.
pub fn run(
    start: &MarlinDelta,
    opts: &G33Options,
    probe: &mut dyn FnMut(&MarlinDelta, [f64; 2]) -> Result<f64>,
) -> Result<G33Run> {
    let p = opts.points;
    let towers_set = opts.towers;
    let dcr = opts.radius;
    let (p0, p1, p4) = (p == 0, p == 1, p == 2);
    let p4_opposite = p4 && !towers_set;
    let nine_center = p >= 8;
    let angle_results = p >= 3 && towers_set;
    let precision = opts.precision;
    let force = opts.force as usize;
    let mut d = start.clone();
    let mut iterations = 0;
    let mut zero_std_dev = 999.0;
    let mut zero_std_dev_min = zero_std_dev;
    let mut zero_std_dev_old = 999.0;
    let (mut r_old, mut h_old, mut e_old, mut a_old) =
        (d.radius, d.height, d.endstops, d.angle_trims);
    let mut std_devs = vec![];
    let mut rolled_back = false;
    let mut probes;
    loop {
        let mut z = [0.0; 7];
        let mut test_precision = if zero_std_dev_old != 999.0 {
            (zero_std_dev + zero_std_dev_old) / 2.0
        } else {
            zero_std_dev
        };
        iterations += 1;
        zero_std_dev_old = zero_std_dev;
        let settings = d.clone();
        probes = probe_points(&mut z, p, dcr, towers_set, &mut |xy| probe(&settings, xy))?;
        zero_std_dev = std_dev(&z, p0, p1, p4, p4_opposite);
        std_devs.push(zero_std_dev);
        if (zero_std_dev < test_precision || iterations <= force) && zero_std_dev > precision {
            if zero_std_dev < zero_std_dev_min {
                e_old = d.endstops;
                r_old = d.radius;
                h_old = d.height;
                a_old = d.angle_trims;
            }
            let zp = |n: f64, i: usize| n * z[i] / 4.0;
            let factor_dcr = if nine_center { dcr * 0.9 } else { dcr };
            let h = tune_h(&d, factor_dcr);
            let r = tune_r(&d, factor_dcr);
            let a = tune_a(&d, factor_dcr);
            let mut e_delta = [0.0; 3];
            let mut r_delta = 0.0;
            let mut t_delta = [0.0; 3];
            match p {
                0 => test_precision = 0.0,
                1 => {
                    test_precision = 0.0;
                    e_delta = [zp(4.0, CEN); 3];
                }
                2 => {
                    if towers_set {
                        e_delta = [
                            (zp(4.0, A) - zp(2.0, B) - zp(2.0, C)) * h + zp(4.0, CEN),
                            (-zp(2.0, A) + zp(4.0, B) - zp(2.0, C)) * h + zp(4.0, CEN),
                            (-zp(2.0, A) - zp(2.0, B) + zp(4.0, C)) * h + zp(4.0, CEN),
                        ];
                        r_delta = (zp(4.0, A) + zp(4.0, B) + zp(4.0, C) - zp(12.0, CEN)) * r;
                    } else {
                        e_delta = [
                            (-zp(4.0, BC) + zp(2.0, CA) + zp(2.0, AB)) * h + zp(4.0, CEN),
                            (zp(2.0, BC) - zp(4.0, CA) + zp(2.0, AB)) * h + zp(4.0, CEN),
                            (zp(2.0, BC) + zp(2.0, CA) - zp(4.0, AB)) * h + zp(4.0, CEN),
                        ];
                        r_delta = (zp(4.0, BC) + zp(4.0, CA) + zp(4.0, AB) - zp(12.0, CEN)) * r;
                    }
                }
                _ => {
                    e_delta = [
                        (zp(2.0, A) - zp(1.0, B) - zp(1.0, C) - zp(2.0, BC)
                            + zp(1.0, CA)
                            + zp(1.0, AB))
                            * h
                            + zp(4.0, CEN),
                        (-zp(1.0, A) + zp(2.0, B) - zp(1.0, C) + zp(1.0, BC) - zp(2.0, CA)
                            + zp(1.0, AB))
                            * h
                            + zp(4.0, CEN),
                        (-zp(1.0, A) - zp(1.0, B) + zp(2.0, C) + zp(1.0, BC) + zp(1.0, CA)
                            - zp(2.0, AB))
                            * h
                            + zp(4.0, CEN),
                    ];
                    r_delta = (zp(2.0, A)
                        + zp(2.0, B)
                        + zp(2.0, C)
                        + zp(2.0, BC)
                        + zp(2.0, CA)
                        + zp(2.0, AB)
                        - zp(12.0, CEN))
                        * r;
                    if towers_set {
                        t_delta = [
                            (zp(0.0, A) - zp(4.0, B) + zp(4.0, C) + zp(0.0, BC) - zp(4.0, CA)
                                + zp(4.0, AB)
                                + zp(0.0, CEN))
                                * a,
                            (zp(4.0, A) + zp(0.0, B) - zp(4.0, C) + zp(4.0, BC) + zp(0.0, CA)
                                - zp(4.0, AB)
                                + zp(0.0, CEN))
                                * a,
                            (-zp(4.0, A) + zp(4.0, B) + zp(0.0, C) - zp(4.0, BC)
                                + zp(4.0, CA)
                                + zp(0.0, AB)
                                + zp(0.0, CEN))
                                * a,
                        ];
                    }
                }
            }
            for i in 0..3 {
                d.endstops[i] += e_delta[i];
                d.angle_trims[i] += t_delta[i];
            }
            d.radius += r_delta;
        } else if zero_std_dev >= test_precision {
            d.endstops = e_old;
            d.radius = r_old;
            d.height = h_old;
            d.angle_trims = a_old;
        }
        // Normalise the angles to sum 0, and the endstops to a largest of 0
        // with the height.
        if angle_results {
            let sum: f64 = d.angle_trims.iter().sum();
            for t in &mut d.angle_trims {
                *t -= sum / 3.0;
            }
        }
        let top = d.endstops.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        d.height -= top;
        for e in &mut d.endstops {
            *e -= top;
        }
        zero_std_dev_min = f64::min(zero_std_dev_min, zero_std_dev);
        if (zero_std_dev >= test_precision && iterations > force) || zero_std_dev <= precision {
            rolled_back = zero_std_dev >= test_precision && !p1 && !p0;
        }
        let again = ((zero_std_dev < test_precision && iterations < MAX_ITERATIONS)
            || iterations <= force)
            && zero_std_dev > precision;
        if !again {
            break;
        }
    }
    Ok(G33Run {
        settings: d,
        std_devs,
        rolled_back,
        probes,
    })
}

/// Where the calibration radius of a comparison comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RadiusFrom {
    /// Given by the user.
    Given,
    /// The radius a G33 log printed.
    Log,
    /// `M665 B` (Marlin 1.1 to 2.0.x, where it is the calibration radius).
    M665B,
    /// The farthest point probed (no radius known otherwise).
    FarthestProbe,
}

/// What Marlin's G33 is run with in a comparison: its `P`, its tower
/// angles or not (`T` absent), and the radius the user gave, if any.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct G33Ask {
    /// Probe points ([`FEWEST_POINTS`] to [`MOST_POINTS`]).
    pub points: u8,
    /// Calibrate the tower angles.
    pub towers: bool,
    /// The calibration radius given (mm).
    pub radius: Option<f64>,
}

/// Marlin's own G33 on the printer a calibration found, against the
/// calibration's values ([`compare`]).
#[derive(Debug)]
pub struct G33Comparison {
    /// What G33 was run with.
    pub options: G33Options,
    /// Where its radius came from.
    pub radius_from: RadiusFrom,
    /// How many independent settings it adjusts, and which
    /// ([`G33Options::factors`]).
    pub factors: (usize, &'static str),
    /// How it ran, or why it could not (a point beyond the reach of the
    /// settings it tried, a pose the fitted printer cannot take): the
    /// file side's typed error, which each front end words.
    pub outcome: std::result::Result<G33Compared, Error>,
}

/// A G33 that ran, and the probe's height errors at the points probed
/// with its settings and with the calibration's.
#[derive(Debug, Clone, PartialEq)]
pub struct G33Compared {
    /// How G33 ended.
    pub run: G33Run,
    /// The points the heights are compared at (the log's probed points).
    pub points: usize,
    /// The height errors with G33's settings (mm).
    pub with_g33: Spread,
    /// The height errors with the calibration's values (mm).
    pub with_calibration: Spread,
}

/// The radius G33 is run at: the one asked, else the log's, else `M665 B`
/// where it is the calibration radius, else the farthest probed point.
pub fn radius(printer: &MarlinPrinter, asked: Option<f64>) -> (f64, RadiusFrom) {
    match (asked, printer.log.g33_radius, printer.delta()) {
        (Some(r), _, _) => (r, RadiusFrom::Given),
        (None, Some(r), _) => (r, RadiusFrom::Log),
        (
            None,
            None,
            MarlinDelta {
                calibration_radius: Some(r),
                letter_b: Some(LetterB::CalibrationRadius),
                ..
            },
        ) => (*r, RadiusFrom::M665B),
        _ => (printer.probe_radius(), RadiusFrom::FarthestProbe),
    }
}

/// Run Marlin's G33, as its G33.cpp runs it, on the printer `calibrated`
/// found (its probe lowered as Marlin lowers it, [`MarlinPrinter::probe_as`]),
/// from the printer's settings, and compare the heights the probe would
/// report at the points probed with G33's settings and with the
/// calibration's: the fitted printer's, plus what the fit left unexplained
/// there (its residuals). A G33 that cannot run is the comparison's
/// `outcome`; an error of the calibration's own values is returned.
pub fn compare(
    printer: &MarlinPrinter,
    calibrated: &PrinterCalibration,
    ask: &G33Ask,
) -> Result<G33Comparison> {
    let cal = calibrated.calibration();
    let mech = &calibrated.mech;
    let measurement = &calibrated.readings.measurement;
    let new = printer.delta().identified(mech.spec(), &cal.params)?;
    let (radius, radius_from) = radius(printer, ask.radius);
    let options = G33Options {
        points: ask.points,
        towers: ask.towers,
        radius,
        precision: 0.0,
        force: 0,
    };
    let probe = |s: &MarlinDelta, xy: [f64; 2]| {
        printer.probe_as(s, xy, mech, measurement, &cal.params, &cal.measurement)
    };
    let g33 = run(printer.delta(), &options, &mut |s, xy| probe(s, xy));
    let residuals = super::probe_errors(
        mech,
        measurement,
        &cal.params,
        &cal.measurement,
        &calibrated.readings.poses,
    )?;
    let outcome = g33.and_then(|g| {
        let at = |s: &MarlinDelta| -> Result<Vec<f64>> {
            printer
                .log
                .points
                .iter()
                .zip(&residuals)
                .map(|(p, e)| {
                    let n = printer.nozzle(p);
                    Ok(probe(s, [n[0], n[1]])? + e)
                })
                .collect()
        };
        let (with_g33, with_new) = (at(&g.settings)?, at(&new)?);
        Ok(G33Compared {
            run: g,
            points: with_g33.len(),
            with_g33: Spread::of(&with_g33),
            with_calibration: Spread::of(&with_new),
        })
    });
    Ok(G33Comparison {
        factors: options.factors(),
        options,
        radius_from,
        outcome,
    })
}
