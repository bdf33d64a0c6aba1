//! Marlin's delta as pkmcal reads it, against Marlin's own formulas written
//! here independently from its `delta.cpp` (tower positions, `DELTA_IK`,
//! the trilateration of `forward_kinematics`, homing with the endstop
//! adjustments), `G30`'s report and `G33.cpp`'s calibration: the
//! description pkmcal builds predicts Marlin's positions to 1e-9 mm over
//! the build volume, probes simulated for a known printer give its
//! M665/M666 back, every settings and probe format of Marlin 1.1 to 2.1 is
//! read, bad input is refused by name, and the real files collected
//! (`../shared/data/real-configs/marlin`, when present) are read.

use pkmcal::{Mechanism, Params, Request};
use pkmcal_io::firmware::g33::{self, G33Options};
use pkmcal_io::firmware::marlin::{
    G33Settings, LetterB, MarlinDelta, MarlinPrinter, ProbeKind, ProbeLog, parse_settings,
    probes_from_text, settings_from_text,
};
use pkmcal_io::firmware::{self, Firmware};
use std::path::{Path, PathBuf};

/// Agreement of pkmcal's model with Marlin's formulas (mm).
const SAME_MM: f64 = 1e-9;
/// Settings identified from noise-free heights against the truth (mm, °).
const RECOVERED: f64 = 1e-6;
/// A simulated probe has met the bed (mm).
const PROBE_MM: f64 = 1e-12;

/// Marlin's delta settings, as `delta.cpp` keeps them.
#[derive(Clone, Copy, Debug)]
struct M {
    /// `delta_diagonal_rod`, `delta_diagonal_rod_trim`.
    l: f64,
    rod_trims: [f64; 3],
    /// `delta_radius`, `delta_height`.
    r: f64,
    h: f64,
    /// `delta_tower_angle_trim` (°), `delta_endstop_adj`.
    t: [f64; 3],
    e: [f64; 3],
}

impl M {
    /// `recalc_delta_settings`: the towers at 210°, 330°, 90° plus trims.
    fn towers(&self) -> [[f64; 2]; 3] {
        let base = [210.0_f64, 330.0, 90.0];
        std::array::from_fn(|i| {
            let a = (base[i] + self.t[i]).to_radians();
            [a.cos() * self.r, a.sin() * self.r]
        })
    }
    /// `delta_diagonal_rod_2_tower`.
    fn rod2(&self) -> [f64; 3] {
        self.rod_trims.map(|t| (self.l + t) * (self.l + t))
    }
    /// `DELTA_IK`.
    fn ik(&self, p: [f64; 3]) -> [f64; 3] {
        let (t, r2) = (self.towers(), self.rod2());
        std::array::from_fn(|i| {
            p[2] + (r2[i] - ((t[i][0] - p[0]).powi(2) + (t[i][1] - p[1]).powi(2))).sqrt()
        })
    }
    /// `forward_kinematics` (Hardtung's trilateration, in Marlin's steps).
    fn fk(&self, z: [f64; 3]) -> [f64; 3] {
        let (t, r2) = (self.towers(), self.rod2());
        let p12 = [t[1][0] - t[0][0], t[1][1] - t[0][1], z[1] - z[0]];
        let d2 = p12.iter().map(|v| v * v).sum::<f64>();
        let inv_d = 1.0 / d2.sqrt();
        let ex = p12.map(|v| v * inv_d);
        let p13 = [t[2][0] - t[0][0], t[2][1] - t[0][1], z[2] - z[0]];
        let i = ex[0] * p13[0] + ex[1] * p13[1] + ex[2] * p13[2];
        let mut ey = [p13[0] - ex[0] * i, p13[1] - ex[1] * i, p13[2] - ex[2] * i];
        let j2 = ey.iter().map(|v| v * v).sum::<f64>();
        let inv_j = 1.0 / j2.sqrt();
        ey = ey.map(|v| v * inv_j);
        let ez = [
            ex[1] * ey[2] - ex[2] * ey[1],
            ex[2] * ey[0] - ex[0] * ey[2],
            ex[0] * ey[1] - ex[1] * ey[0],
        ];
        let xn = (r2[0] - r2[1] + d2) * inv_d * 0.5;
        let yn = ((r2[0] - r2[2] + i * i + j2) * 0.5 - i * xn) * inv_j;
        let zn = (r2[0] - xn * xn - yn * yn).sqrt();
        [
            t[0][0] + ex[0] * xn + ey[0] * yn - ez[0] * zn,
            t[0][1] + ex[1] * xn + ey[1] * yn - ez[1] * zn,
            z[0] + ex[2] * xn + ey[2] * yn - ez[2] * zn,
        ]
    }
    /// The carriages after `G28`: the nozzle at (0, 0, H).
    fn homed(&self) -> [f64; 3] {
        self.ik([0.0, 0.0, self.h])
    }
    /// A carriage's distance below its endstop's trigger for the
    /// firmware's position `c`: homing leaves it `delta_endstop_adj` (≤ 0)
    /// from the trigger and calls that `homed`.
    fn below_trigger(&self, c: [f64; 3]) -> [f64; 3] {
        let h = self.homed();
        std::array::from_fn(|i| c[i] - h[i] + self.e[i])
    }
    fn counted_from_trigger(&self, b: [f64; 3]) -> [f64; 3] {
        let h = self.homed();
        std::array::from_fn(|i| b[i] + h[i] - self.e[i])
    }
    /// `M665`/`M666` as Marlin 2.0 prints them (`M503`).
    fn m503(&self) -> String {
        format!(
            "echo:; Endstop adjustment:\necho:  M666 X{:.9} Y{:.9} Z{:.9}\n\
             echo:; Delta settings: L<diagonal rod> R<radius> H<height> S<segments per sec> XYZ<tower angle trim> ABC<rod trim>\n\
             echo:  M665 L{:.9} R{:.9} H{:.9} S80.0000 X{:.9} Y{:.9} Z{:.9} A{:.9} B{:.9} C{:.9}\n",
            self.e[0],
            self.e[1],
            self.e[2],
            self.l,
            self.r,
            self.h,
            self.t[0],
            self.t[1],
            self.t[2],
            self.rod_trims[0],
            self.rod_trims[1],
            self.rod_trims[2]
        )
    }
    fn from_delta(d: &MarlinDelta) -> M {
        M {
            l: d.diagonal,
            rod_trims: d.rod_trims,
            r: d.radius,
            h: d.height,
            t: d.angle_trims,
            e: d.endstops,
        }
    }
}

/// The firmware `fw` moves the nozzle to `(x, y)` and down until the probe,
/// `o` from the nozzle, touches the bed of the printer `truth` is: the
/// firmware's nozzle height then.
fn touch(fw: &M, truth: &M, nozzle: [f64; 2], oz: f64) -> f64 {
    let true_z = |z: f64| {
        let b = fw.below_trigger(fw.ik([nozzle[0], nozzle[1], z]));
        truth.fk(truth.counted_from_trigger(b))[2]
    };
    // The nozzle's height follows the firmware's at a slope of 1.
    let mut z = 0.0;
    for _ in 0..20 {
        let step = true_z(z) + oz;
        z -= step;
        if step.abs() < PROBE_MM {
            break;
        }
    }
    z
}

/// What `G30 X Y` reports: the probe at `(x, y)`, the nozzle `M851 X Y`
/// away, `Z` the probe's trigger point.
fn g30(fw: &M, truth: &M, xy: [f64; 2], o: [f64; 3]) -> f64 {
    touch(fw, truth, [xy[0] - o[0], xy[1] - o[1]], o[2]) + o[2]
}

const NOMINAL: M = M {
    l: 267.0,
    rod_trims: [0.0; 3],
    r: 133.6,
    h: 270.6,
    t: [0.0; 3],
    e: [-0.3, 0.0, -0.2],
};

const TRUTH: M = M {
    l: 267.0,
    rod_trims: [0.0; 3],
    r: 134.1,
    h: 270.85,
    t: [0.3, -0.25, 0.0],
    e: [-0.45, 0.0, -0.1],
};

/// Probe points on rings to `radius` (mm).
fn points(radius: f64) -> Vec<[f64; 2]> {
    let mut out = vec![[0.0, 0.0]];
    for (r, n) in [(radius / 3.0, 6), (2.0 * radius / 3.0, 12), (radius, 18)] {
        for k in 0..n {
            let a = (90.0 + 360.0 * k as f64 / n as f64).to_radians();
            out.push([r * a.cos(), r * a.sin()]);
        }
    }
    out
}

/// A G30 log in Marlin 2.1's words (`Bed X:… Y:… Z:…`, no spaces) as a
/// host shows it.
fn g30_log(fw: &M, truth: &M, pts: &[[f64; 2]], o: [f64; 3]) -> String {
    let mut s = String::from("Send: G28\nRecv: ok\n");
    for p in pts {
        let z = g30(fw, truth, *p, o);
        s.push_str(&format!(
            "Send: G30 X{:.9} Y{:.9}\nRecv: Bed X:{:.9} Y:{:.9} Z:{z:.12}\nRecv: ok\n",
            p[0], p[1], p[0], p[1]
        ));
    }
    s
}

fn path(name: &str) -> PathBuf {
    PathBuf::from(name)
}

/// A printer of settings text and a probe log.
fn printer(settings: &str, log: &str, free: Option<&[String]>) -> MarlinPrinter {
    let s = settings_from_text(settings, &path("M503.txt"), None).expect("settings");
    let l = probes_from_text(log, &path("G30.log"), None).expect("probes");
    MarlinPrinter::new(&path("M503.txt"), s, &path("G30.log"), l, None, free).expect("printer")
}

/// Fit a printer as `pkmcal marlin` does; its new settings.
fn fit(p: &MarlinPrinter, free: Option<&str>) -> MarlinDelta {
    let mut request = Request::new(pkmcal::Model::Exact);
    request.free = free.map(Request::names);
    let cal = firmware::calibrate(p, request).expect("fit");
    p.delta()
        .identified(cal.mech.spec(), &cal.calibration().params)
        .expect("Marlin's values")
}

fn close(a: &MarlinDelta, b: &M, tol: f64) {
    let got = M::from_delta(a);
    let pairs = [
        ("L", got.l, b.l),
        ("R", got.r, b.r),
        ("H", got.h, b.h),
        ("X", got.t[0], b.t[0]),
        ("Y", got.t[1], b.t[1]),
        ("Z", got.t[2], b.t[2]),
        ("A", got.rod_trims[0], b.rod_trims[0]),
        ("B", got.rod_trims[1], b.rod_trims[1]),
        ("C", got.rod_trims[2], b.rod_trims[2]),
        ("EX", got.e[0], b.e[0]),
        ("EY", got.e[1], b.e[1]),
        ("EZ", got.e[2], b.e[2]),
    ];
    for (n, x, y) in pairs {
        assert!((x - y).abs() < tol, "{n}: {x} against {y}\n{a:?}");
    }
}

#[test]
fn marlins_kinematics_are_pkmcals_over_the_build_volume() {
    let odd = M {
        l: 215.3,
        rod_trims: [0.4, -0.25, 0.1],
        r: 105.2,
        h: 300.0,
        t: [0.7, -0.45, 0.2],
        e: [-1.1, 0.0, -0.35],
    };
    for m in [NOMINAL, TRUTH, odd] {
        let log = "Bed X:0.00 Y:0.00 Z:0.000\n";
        let p = printer(&format!("{}M851 X0 Y0 Z0\n", m.m503()), log, None);
        let mech = p.mechanism().expect("mechanism");
        let nominal = Params::nominal(mech.spec());
        let reach = 0.75 * m.r;
        let mut worst: f64 = 0.0;
        for z in [0.0, 40.0, 120.0] {
            for k in -6..=6 {
                for j in -6..=6 {
                    let (x, y) = (reach * k as f64 / 6.0, reach * j as f64 / 6.0);
                    if x.hypot(y) > reach {
                        continue;
                    }
                    let c = m.ik([x, y, z]);
                    let pr = pkmcal::predict(&mech, &nominal, &c, pkmcal::Model::Exact, &[])
                        .expect("predict");
                    // Marlin's forward kinematics of the same carriages.
                    let f = m.fk(c);
                    for a in 0..3 {
                        worst = worst.max((pr.x[a] - [x, y, z][a]).abs());
                        worst = worst.max((pr.x[a] - f[a]).abs());
                    }
                }
            }
        }
        assert!(worst < SAME_MM, "{m:?}: {worst:e} mm");
    }
}

#[test]
fn g30_heights_of_a_known_printer_give_its_settings_back() {
    // A probe 12 mm right of and 8 mm in front of the nozzle, 1.4 mm below.
    let o = [12.0, -8.0, -1.4];
    let settings = format!(
        "{}echo:; Z-Probe Offset:\necho:  M851 X{} Y{} Z{} ; (mm)\n",
        NOMINAL.m503(),
        o[0],
        o[1],
        o[2]
    );
    let log = g30_log(&NOMINAL, &TRUTH, &points(80.0), o);
    let p = printer(&settings, &log, None);
    assert_eq!(p.probe_offset, o);
    let new = fit(&p, None);
    close(&new, &TRUTH, RECOVERED);
    // With the written values every point the probe can reach is on the bed.
    let written = M::from_delta(&new);
    for q in points(95.0) {
        let z = g30(&written, &TRUTH, q, o);
        assert!(z.abs() < RECOVERED, "{q:?}: {z}");
    }
}

#[test]
fn every_rod_comes_back_with_all_of_m665_free() {
    let truth = M {
        l: 267.4,
        rod_trims: [0.35, -0.2, 0.05],
        ..TRUTH
    };
    // Rods and endstops are nearly alike to a probe (r = 0.997): many
    // noise-free points separate them.
    let log = g30_log(&NOMINAL, &truth, &points(110.0), [0.0; 3]);
    let settings = format!("{}M851 X0 Y0 Z0\n", NOMINAL.m503());
    let p = printer(&settings, &log, Some(&["all".to_string()]));
    let new = fit(&p, Some("all"));
    // Each tower's rod (L and its trim: their split is Marlin's convention,
    // L moved by the rods' common change), R, H, the endstops; the three
    // angles turning together turn the frame, which probes do not see: their
    // differences.
    let got = M::from_delta(&new);
    let rods = |m: &M| m.rod_trims.map(|t| m.l + t);
    for i in 0..3 {
        assert!((rods(&got)[i] - rods(&truth)[i]).abs() < 1e-4, "{new:?}");
        assert!((got.e[i] - truth.e[i]).abs() < 1e-4, "{new:?}");
        let turn = |m: &M| m.t[i] - m.t[2];
        assert!((turn(&got) - turn(&truth)).abs() < 1e-4, "{new:?}");
    }
    assert!(
        (got.r - truth.r).abs() < 1e-4 && (got.h - truth.h).abs() < 1e-4,
        "{new:?}"
    );
    assert!(
        (got.l - (NOMINAL.l + (0..3).map(|i| rods(&got)[i] - NOMINAL.l).sum::<f64>() / 3.0)).abs()
            < 1e-12
    );
}

#[test]
fn a_marlin_without_rod_trims_fits_one_diagonal() {
    // Marlin 1.1: M665 B is the calibration radius; no A, C.
    let truth = M { l: 266.6, ..TRUTH };
    let settings = format!(
        "echo:Endstop adjustment:\necho:  M666 X{} Y{} Z{}\n\
         echo:Delta settings: L<diagonal_rod> R<radius> H<height> S<segments_per_s> B<calibration radius> XYZ<tower angle corrections>\n\
         echo:  M665 L{} R{} H{} S200.00 B77.00 X0.00 Y0.00 Z0.00\necho:  M851 Z-1.40\n",
        NOMINAL.e[0], NOMINAL.e[1], NOMINAL.e[2], NOMINAL.l, NOMINAL.r, NOMINAL.h
    );
    let s = settings_from_text(&settings, &path("m503"), None).unwrap();
    assert_eq!(s.delta.letter_b, Some(LetterB::CalibrationRadius));
    assert_eq!(s.delta.calibration_radius, Some(77.0));
    assert_eq!(s.probe_offset, [None, None, Some(-1.4)]);
    let log = g30_log(&NOMINAL, &truth, &points(90.0), [0.0, 0.0, -1.4]);
    let l = probes_from_text(&log, &path("G30.log"), None).unwrap();
    // 1.1 has no M851 X Y: the offset is asked for, then given.
    let free = ["default".to_string(), "diagonal".to_string()];
    let e = MarlinPrinter::new(
        &path("m503"),
        s.clone(),
        &path("G30.log"),
        l.clone(),
        None,
        Some(&free),
    )
    .err()
    .expect("the probe offset is asked for");
    assert_eq!(e.field(), Some(pkmcal::Field::ProbeOffset), "{e}");
    let p = MarlinPrinter::new(
        &path("m503"),
        s.clone(),
        &path("G30.log"),
        l.clone(),
        Some([0.0, 0.0]),
        Some(&free),
    )
    .unwrap();
    let new = fit(&p, Some("default,diagonal"));
    close(&new, &truth, RECOVERED);
    // The written lines keep B as the calibration radius and have no A B C.
    let g = new.gcode();
    assert!(g.contains(" B77.0000 X") && !g.contains(" A"), "{g}");
    // Each tower's rod has no place in this Marlin.
    let arms = ["default".to_string(), "arm_a".to_string()];
    let e = MarlinPrinter::new(
        &path("m503"),
        s,
        &path("G30.log"),
        l,
        Some([0.0, 0.0]),
        Some(&arms),
    )
    .err()
    .expect("arm_a refused");
    assert!(e.to_string().contains("calibration radius"), "{e}");
}

#[test]
fn g33s_verbose_heights_are_readings_too() {
    // G33 V3 prints the heights it probed at its calibration points (the
    // centre, the towers, the points opposite) with the settings it
    // printed before; here two iterations, the second after G33 changed
    // the height and endstops, taken in the settings of M503.
    let dcr = 85.0;
    let at = |a: f64| [dcr * a.to_radians().cos(), dcr * a.to_radians().sin()];
    let block = |fw: &M| {
        let z = |xy: [f64; 2]| touch(fw, &TRUTH, xy, 0.0);
        format!(
            ".Height:{:.9}  Ex:{:+.9}  Ey:{:+.9}  Ez:{:+.9}  Radius:{:.9}\n.               Tx:{:+.9}  Ty:{:+.9}  Tz:{:+.9}\n\
             .      c:{:+.12}     x:{:+.12}   y:{:+.12}   z:{:+.12}\n.                 yz:{:+.12}  zx:{:+.12}  xy:{:+.12}\n",
            fw.h,
            fw.e[0],
            fw.e[1],
            fw.e[2],
            fw.r,
            fw.t[0],
            fw.t[1],
            fw.t[2],
            z([0.0, 0.0]),
            z(at(210.0)),
            z(at(330.0)),
            z(at(90.0)),
            z(at(30.0)),
            z(at(150.0)),
            z(at(270.0))
        )
    };
    let later = M {
        h: 270.9,
        e: [-0.1, 0.0, -0.4],
        ..NOMINAL
    };
    let log = format!(
        "Send: G33 P3 V3\nRecv: G33 Auto Calibrate\nRecv: Checking... AC at radius:{dcr}\n{}Recv: Iteration : 01                                std dev:0.100\n{}",
        block(&NOMINAL)
            .lines()
            .map(|l| format!("Recv: {l}\n"))
            .collect::<String>(),
        block(&later)
    );
    let l = probes_from_text(&log, &path("g33.log"), None).unwrap();
    assert_eq!(l.g33_radius, Some(dcr));
    assert_eq!(l.points.len(), 14);
    assert_eq!(l.g33_settings.len(), 2);
    let s = settings_from_text(&NOMINAL.m503(), &path("M503.txt"), None).unwrap();
    let p = MarlinPrinter::new(&path("M503.txt"), s, &path("g33.log"), l, None, None).unwrap();
    assert!(matches!(p.log.points[7].kind, ProbeKind::G33 { .. }));
    let new = fit(&p, None);
    close(&new, &TRUTH, RECOVERED);
}

#[test]
fn every_version_of_the_settings_is_read() {
    let p = path("m503.txt");
    // Marlin 2.1: the heading `Delta (…)`, comments after the values.
    let v21 = "echo:; Endstop adjustment:\necho:  M666 X-0.50 Y0.00 Z-0.25\n\
               echo:; Delta (L<diagonal rod> R<radius> H<height> S<segments per sec> XYZ<tower angle trim> ABC<rod trim>):\n\
               echo:  M665 L250.00 R124.00 H300.00 S200.00 X0.10 Y-0.20 Z0.00 A0.00 B0.30 C0.00\n\
               echo:; Z-Probe Offset:\necho:  M851 X0.00 Y-20.00 Z-1.25 ; (mm)\n";
    let s = settings_from_text(v21, &p, None).unwrap();
    assert_eq!(s.delta.letter_b, Some(LetterB::RodTrim));
    assert_eq!(s.delta.rod_trims, [0.0, 0.3, 0.0]);
    assert_eq!(s.delta.endstops, [-0.5, 0.0, -0.25]);
    assert_eq!(s.probe_offset, [Some(0.0), Some(-20.0), Some(-1.25)]);
    assert_eq!((s.m665_line, s.m666_line), (Some(4), Some(2)));
    // Typed lines, no spaces, line numbers and checksums, later ones
    // overriding; A or C say that B is a rod trim.
    let typed = "N10 M665L250R124H300*71\nM666 X-0.5 Y0 Z0\nM665 H301.5 C0.2 B-0.1\nG28\n";
    let s = settings_from_text(typed, &p, None).unwrap();
    assert_eq!(s.delta.height, 301.5);
    assert_eq!(s.delta.rod_trims, [0.0, -0.1, 0.2]);
    assert_eq!(s.delta.diagonal, 250.0);
    // B alone is asked about, and read as told.
    let b = "M665 L250 R124 H300 B90\nM666 X0 Y0 Z0\n";
    let e = settings_from_text(b, &p, None).unwrap_err();
    assert_eq!(e.field(), Some(pkmcal::Field::FirmwareLetters), "{e}");
    assert!(e.to_string().contains("line 1"), "{e}");
    let s = settings_from_text(b, &p, Some(LetterB::CalibrationRadius)).unwrap();
    assert_eq!(s.delta.calibration_radius, Some(90.0));
    let s = settings_from_text(b, &p, Some(LetterB::RodTrim)).unwrap();
    assert_eq!(s.delta.rod_trims[1], 90.0);
    // A meaning given against the heading's is refused.
    assert!(settings_from_text(v21, &p, Some(LetterB::CalibrationRadius)).is_err());
}

#[test]
fn bad_settings_are_refused_by_name() {
    let p = path("m503.txt");
    let ok = "M665 L250 R124 H300\nM666 X0 Y0 Z0\n";
    assert!(settings_from_text(ok, &p, None).is_ok());
    for (text, needle) in [
        ("M665 L250 R124 H300\n", "no M666"),
        ("M666 X0 Y0 Z0\n", "no M665"),
        ("M665 L250 H300\nM666 X0 Y0 Z0\n", "no M665 R"),
        ("M665 L250 R124 HNaN\nM666 X0 Y0 Z0\n", "`HNaN`"),
        ("M665 L250 R124 H300 Q2\nM666 X0 Y0 Z0\n", "no letter Q"),
        (
            "M665 L250 R124 H1e300\nM666 X0 Y0 Z0\n",
            "beyond what a printer holds",
        ),
        ("M665 L250 R124 H300\nM666 X0.3 Y0 Z0\n", "at most 0"),
        (
            "M665 L100 R124 H300\nM666 X0 Y0 Z0\n",
            "not longer than the delta radius",
        ),
        ("M665 L250 R-124 H300\nM666 X0 Y0 Z0\n", "must be positive"),
        (
            "M665 L250 R124 H300 X75\nM666 X0 Y0 Z0\n",
            "beyond what a printer holds",
        ),
        (
            "M665 L250 R124 H300 X\nM666 X0 Y0 Z0\n",
            "must be a finite number",
        ),
        ("#define DELTA_RADIUS 124.0\n", "Configuration.h"),
    ] {
        let e = settings_from_text(text, &p, None)
            .err()
            .unwrap_or_else(|| panic!("{text} read"));
        assert!(e.to_string().contains(needle), "{text}: {e}");
    }
    // A letter of another version, against its heading.
    let old = "echo:Delta settings: L<diagonal_rod> R<radius> H<height> S<segments_per_s> B<calibration radius> XYZ<tower angle corrections>\nM665 L250 R124 H300 A0.2\nM666 X0 Y0 Z0\n";
    let e = settings_from_text(old, &p, None).unwrap_err();
    assert!(e.to_string().contains("no rod trims"), "{e}");
}

#[test]
fn every_probe_report_is_read() {
    let p = path("probes.log");
    // Marlin 1.1 and 2.0 (spaces after the colons, 2 decimals), 2.1 (none,
    // 3 decimals), G29 V3's per-point reports, hosts' prefixes and
    // timestamps, and what follows a report.
    let log = "Bed X: 10.00 Y: -20.00 Z: 0.12\n\
               Recv: Bed X:10.00 Y:-20.00 Z:0.123\n\
               08:33:00.013 : Bed X: 0.00 Y: 0.00 Z: -0.05 (avg of 2)\n\
               SENDING:G30\nX:10.00 Y:-20.00 Z:5.12 E:0.00 Count A:1 B:2 C:3\n";
    let l = probes_from_text(log, &p, None).unwrap();
    let got: Vec<([f64; 2], f64, usize)> = l.points.iter().map(|q| (q.xy, q.z, q.line)).collect();
    assert_eq!(
        got,
        vec![
            ([10.0, -20.0], 0.12, 1),
            ([10.0, -20.0], 0.123, 2),
            ([0.0, 0.0], -0.05, 3)
        ]
    );
    for (text, needle) in [
        ("Bed X: 1.00 Y: nan Z: 0.1\n", "`Y:nan`"),
        ("Bed X: 1.00 Z: 0.1\n", "has no Y"),
        ("Bed X: 1e9 Y: 0 Z: 0.1\n", "beyond what a printer reaches"),
        (".      c:+0.82\n", "follow no `.Height:` line"),
        ("Checking... AC at radius:-5\n", "radius"),
    ] {
        let e = probes_from_text(text, &p, None).unwrap_err();
        assert!(e.to_string().contains(needle), "{text}: {e}");
        assert!(e.to_string().starts_with("probes.log:1"), "{e}");
    }
    // G33's settings as Marlin 1.1 prints them (`.Tower angle :` on a line
    // of its own) and as Marlin 2 does.
    let v11 = ">>> G33\nSENDING:G33\nChecking... AC\n.Height:318.83    Ex:-0.67  Ey:-0.45  Ez:+0.00    Radius:98.07\n.Tower angle :    Tx:-0.73  Ty:-0.13  Tz:+0.00\n";
    let v2 = "Recv: Checking... AC at radius:155.00\nRecv: .Height:450.00  Ex:-0.25  Ey:0.00  Ez:-0.84  Radius:227.40\nRecv: .               Tx:+0.13  Ty:-0.18  Tz:+0.05\n";
    for (text, want) in [
        (
            v11,
            G33Settings {
                height: Some(318.83),
                endstops: [Some(-0.67), Some(-0.45), Some(0.0)],
                radius: Some(98.07),
                angle_trims: [Some(-0.73), Some(-0.13), Some(0.0)],
                line: 4,
            },
        ),
        (
            v2,
            G33Settings {
                height: Some(450.0),
                endstops: [Some(-0.25), Some(0.0), Some(-0.84)],
                radius: Some(227.4),
                angle_trims: [Some(0.13), Some(-0.18), Some(0.05)],
                line: 2,
            },
        ),
    ] {
        let l = probes_from_text(text, &p, None).unwrap();
        assert_eq!(l.g33_settings, vec![want]);
        assert!(l.points.is_empty());
    }
    // G33's heights off the centre need its radius, asked for by name.
    let l = probes_from_text(".Height:300.00\n.      c:+0.10 x:+0.20\n", &p, None).unwrap();
    assert_eq!(l.g33_unplaced, Some(2));
    let s = settings_from_text(&NOMINAL.m503(), &path("m503"), None).unwrap();
    let e = MarlinPrinter::new(&path("m503"), s.clone(), &p, l, None, None)
        .err()
        .unwrap();
    assert_eq!(e.field(), Some(pkmcal::Field::G33Radius), "{e}");
    // An empty log, and a point out of reach, are refused by name.
    let e = MarlinPrinter::new(
        &path("m503"),
        s.clone(),
        &p,
        ProbeLog::default(),
        None,
        None,
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("no probed heights"), "{e}");
    let far = probes_from_text("Bed X: 400.00 Y: 0.00 Z: 0.1\n", &p, None).unwrap();
    let e = MarlinPrinter::new(&path("m503"), s, &p, far, Some([0.0; 2]), None)
        .err()
        .unwrap();
    assert!(
        e.to_string().starts_with("probes.log:1") && e.to_string().contains("out of reach"),
        "{e}"
    );
}

#[test]
fn a_fit_marlin_cannot_hold_is_refused_by_name() {
    let log = g30_log(&NOMINAL, &TRUTH, &points(80.0), [0.0; 3]);
    let p = printer(&format!("{}M851 X0 Y0 Z0\n", NOMINAL.m503()), &log, None);
    for (free, needle) in [
        ("default,bed.rx", "bed levelling"),
        ("default,bed.z", "common shift"),
        ("default,a.tilt1", "`a.tilt1` has no place in M665/M666"),
    ] {
        let mut request = Request::new(pkmcal::Model::Exact);
        request.free = Some(Request::names(free));
        let e = firmware::calibrate(&p, request).err().expect(free);
        assert_eq!(e.field(), Some(pkmcal::Field::Free), "{free}: {e}");
        assert!(e.to_string().contains(needle), "{free}: {e}");
    }
}

/// `probe` for G33 on the printer `truth`: the nozzle over `xy`, the
/// height the probe (at the nozzle) reports.
fn g33_probe(truth: &M) -> impl FnMut(&MarlinDelta, [f64; 2]) -> pkmcal_io::Result<f64> + '_ {
    move |s, xy| Ok(touch(&M::from_delta(s), truth, xy, 0.0))
}

fn start() -> MarlinDelta {
    settings_from_text(&NOMINAL.m503(), &path("m503"), None)
        .unwrap()
        .delta
}

#[test]
fn g33_p1_sets_the_height_from_the_centre() {
    // A printer whose only error is its height: G33 P1 probes the centre
    // and moves H by what it reads, in one iteration.
    let truth = M {
        h: NOMINAL.h + 0.37,
        ..NOMINAL
    };
    let opts = G33Options {
        points: 1,
        towers: true,
        radius: 80.0,
        precision: 0.0,
        force: 0,
    };
    let run = g33::run(&start(), &opts, &mut g33_probe(&truth)).unwrap();
    assert_eq!(run.std_devs.len(), 1);
    assert!((run.settings.height - truth.h).abs() < 1e-9, "{run:?}");
    for i in 0..3 {
        assert!(
            (run.settings.endstops[i] - NOMINAL.e[i]).abs() < 1e-12,
            "{run:?}"
        );
    }
    assert_eq!(opts.factors().0, 1);
}

#[test]
fn g33_leaves_a_true_printer_as_it_is() {
    let opts = G33Options {
        points: 4,
        towers: true,
        radius: 80.0,
        precision: 0.0,
        force: 0,
    };
    let run = g33::run(&start(), &opts, &mut g33_probe(&NOMINAL)).unwrap();
    assert_eq!(run.std_devs, vec![0.00001, 0.00001]);
    close(&run.settings, &NOMINAL, 1e-12);
    assert_eq!(run.probes, 16);
}

#[test]
fn g33_brings_a_printer_within_its_factors_to_its_points() {
    // Errors G33 models (height, endstops, radius, tower angles): each
    // probe pattern converges, and its points come out flat.
    let truth = M {
        r: 133.9,
        h: 270.5,
        t: [0.15, -0.1, -0.05],
        e: [-0.4, 0.0, -0.1],
        ..NOMINAL
    };
    for (points, towers, count) in [
        (2, true, 4),
        (3, true, 9),
        (4, true, 16),
        (5, true, 25),
        (7, true, 49),
        (8, true, 64),
        (10, true, 100),
        (4, false, 16),
    ] {
        let opts = G33Options {
            points,
            towers,
            radius: 85.0,
            precision: 0.0,
            force: 0,
        };
        let run = g33::run(&start(), &opts, &mut g33_probe(&truth)).unwrap();
        assert_eq!(run.probes, count, "P{points}");
        let first = run.std_devs[0];
        let best = run.std_devs.iter().copied().fold(f64::INFINITY, f64::min);
        // Without the tower angles (T) their error stays.
        let gain = if towers { 0.1 } else { 0.5 };
        assert!(first > 0.05 && best < gain * first, "P{points}: {run:?}");
        // Endstops normalised to a largest of 0, angle trims to a sum of 0.
        let top = run
            .settings
            .endstops
            .iter()
            .copied()
            .fold(f64::MIN, f64::max);
        assert!(top.abs() < 1e-12, "P{points}: {run:?}");
        if points >= 3 && towers {
            assert!(run.settings.angle_trims.iter().sum::<f64>().abs() < 1e-12);
        }
    }
}

#[test]
fn g33_rolls_back_as_marlins_documentation_shows() {
    // `G33 V2` on Marlin's documentation page (G033.md): settings, heights
    // (std dev 0.028), an iteration whose heights are worse (0.039), then
    // "rolling back" to the settings it started from.
    let first = [0.01, 0.06, 0.04, 0.01, -0.02, -0.01, 0.01];
    let second = [-0.03, -0.01, -0.02, -0.03, -0.05, -0.05, -0.06];
    let mut start = start();
    start.height = 297.80;
    start.radius = 100.79;
    start.endstops = [-0.14, -0.07, 0.0];
    start.angle_trims = [-0.10, 0.22, -0.12];
    let mut calls = 0;
    let mut probe = |_: &MarlinDelta, xy: [f64; 2]| -> pkmcal_io::Result<f64> {
        calls += 1;
        // The height of the calibration point in xy's direction (the
        // centre: within 10 % of the radius).
        let heights = if calls <= 9 { first } else { second };
        if xy[0].hypot(xy[1]) < 20.0 {
            return Ok(heights[0]);
        }
        let a = xy[1].atan2(xy[0]).to_degrees().rem_euclid(360.0);
        let k = [210.0, 330.0, 90.0, 30.0, 150.0, 270.0]
            .iter()
            .position(|p| (p - a).abs() < 1.0)
            .expect("a calibration point");
        Ok(heights[k + 1])
    };
    let opts = G33Options {
        points: 3,
        towers: true,
        radius: 80.0,
        precision: 0.0,
        force: 0,
    };
    let run = g33::run(&start, &opts, &mut probe).unwrap();
    assert_eq!(run.std_devs, vec![0.029 + 0.00001, 0.039 + 0.00001]);
    assert!(run.rolled_back);
    assert_eq!(run.settings.height, 297.80);
    assert_eq!(run.settings.endstops, [-0.14, -0.07, 0.0]);
    assert_eq!(run.settings.radius, 100.79);
}

/// The real Marlin files collected (`../shared/data/real-configs/marlin`).
fn real() -> Option<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/real-configs/marlin/cases");
    if root.exists() {
        return Some(root);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{} is missing in CI",
        root.display()
    );
    use std::io::Write as _;
    let _ = writeln!(
        std::io::stderr().lock(),
        "SKIPPED: no real configurations at {}",
        root.display()
    );
    None
}

#[test]
fn every_real_marlin_file_is_read() {
    let Some(root) = real() else {
        return;
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .flatten()
        .flat_map(|c| {
            std::fs::read_dir(c.path())
                .unwrap()
                .flatten()
                .map(|f| f.path())
        })
        .filter(|f| !f.ends_with("SOURCE.txt"))
        .collect();
    files.sort();
    assert!(files.len() >= 20, "{} files", files.len());
    let mut settings_read = 0;
    let mut g33_settings = 0;
    let mut heights = 0;
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        // Every file gives its settings, or says by name why not.
        match parse_settings(&text, f, None) {
            Ok(s) if s.m665_line.is_some() => settings_read += 1,
            Ok(_) => {
                let e = settings_from_text(&text, f, None).unwrap_err();
                assert!(
                    e.to_string().contains("M665") || e.to_string().contains("Configuration.h"),
                    "{e}"
                );
            }
            Err(e) => assert!(e.to_string().starts_with(&f.display().to_string()), "{e}"),
        }
        let log = probes_from_text(&text, f, None).unwrap_or_else(|e| panic!("{e}"));
        g33_settings += log.g33_settings.len();
        heights += log.points.len();
    }
    assert!(settings_read >= 1 && g33_settings >= 30 && heights >= 4);
    // The one M503 dump: Marlin 2.0.7.2's rod-trim letters, and no M666
    // line in the post, which is asked for.
    let m503 = root.join("octoprint-eeprom-issue-26-kossel-linear-plus-skr/m503.txt");
    let text = std::fs::read_to_string(&m503).unwrap();
    let s = parse_settings(&text, &m503, None).unwrap();
    assert_eq!(s.delta.letter_b, Some(LetterB::RodTrim));
    assert_eq!(
        (s.delta.diagonal, s.delta.radius, s.delta.height),
        (267.0, 133.5951, 270.6)
    );
    assert_eq!(s.delta.angle_trims, [0.2631, -0.0122, -0.2509]);
    let e = settings_from_text(&text, &m503, None).unwrap_err();
    assert!(e.to_string().contains("no M666"), "{e}");
    // The owner's notes: M503 lines among typed commands; the typed `M666
    // Z1.6`, which Marlin 2 refuses, is refused with its line.
    let notes = root.join("geeetech-g2s-pro-edicsonm/g33_notes_README.md");
    let text = std::fs::read_to_string(&notes).unwrap();
    let e = parse_settings(&text, &notes, None).unwrap_err();
    assert!(e.to_string().contains(":11: `Z1.6`"), "{e}");
    // G33 P1 V2 four times (Marlin 1.1): each centre height moves H by
    // itself, as G33's P1 rule does, to the height printed next.
    let log7132 = root.join("marlin-issue-7132-g33-p1-center-probe/g33.log");
    let l = probes_from_text(&std::fs::read_to_string(&log7132).unwrap(), &log7132, None).unwrap();
    let c: Vec<f64> = l.points.iter().map(|p| p.z).collect();
    assert_eq!(c, vec![0.82, 0.81, 0.81, 0.79]);
    let h: Vec<f64> = l.g33_settings.iter().filter_map(|s| s.height).collect();
    assert_eq!(h.len(), 8);
    for (k, p) in l.points.iter().enumerate() {
        let ProbeKind::G33 { settings } = &p.kind else {
            panic!("a G33 height");
        };
        let mut d = start();
        d.endstops = [0.0; 3];
        d.height = settings.height.unwrap();
        let opts = G33Options {
            points: 1,
            towers: true,
            radius: 80.0,
            precision: 0.0,
            force: 0,
        };
        let run = g33::run(&d, &opts, &mut |_, _| Ok(p.z)).unwrap();
        assert!(
            (run.settings.height - h[2 * k + 1]).abs() < 0.005 + 1e-9,
            "{run:?} against {}",
            h[2 * k + 1]
        );
    }
    // The G33 author's sample run: settings each iteration, tower angles.
    let sample = root.join("marlindocs-pr-70-g33-sample-lvd-ac/g33.log");
    let l = probes_from_text(&std::fs::read_to_string(&sample).unwrap(), &sample, None).unwrap();
    assert_eq!(l.g33_settings.len(), 5);
    assert_eq!(
        l.g33_settings[1],
        G33Settings {
            height: Some(297.85),
            endstops: [Some(-0.18), Some(-0.13), Some(0.0)],
            radius: Some(100.68),
            angle_trims: [Some(-0.05), Some(0.08), Some(0.0)],
            line: 5,
        }
    );
}
