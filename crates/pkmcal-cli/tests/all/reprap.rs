//! `pkmcal reprap` against RepRapFirmware's own delta formulas, written
//! here independently (its `LinearDeltaKinematics`): probe heights made for a
//! known printer give that printer's M665/M666 back.

use crate::common::{fails, ok, real_configs, run};

/// The identified values equal the truth (mm, degrees, percent): the probe
/// heights are written to 1 nm.
const RECOVERED: f64 = 1e-4;

/// What M665/M666 set.
#[derive(Clone, Copy, Debug)]
struct Rrf {
    l: [f64; 3],
    r: f64,
    h: f64,
    corr: [f64; 3],
    e: [f64; 3],
    /// Tilts as fractions (M666 A B / 100).
    tilt: [f64; 2],
}

impl Rrf {
    fn towers(&self) -> [[f64; 2]; 3] {
        // RepRapFirmware's Recalc().
        let (r, c) = (self.r, self.corr.map(f64::to_radians));
        let d30 = 30f64.to_radians();
        [
            [-r * (d30 + c[0]).cos(), -r * (d30 + c[0]).sin()],
            [r * (d30 - c[1]).cos(), -r * (d30 - c[1]).sin()],
            [-r * c[2].sin(), r * c[2].cos()],
        ]
    }
    fn homed(&self) -> [f64; 3] {
        std::array::from_fn(|i| self.h + (self.l[i].powi(2) - self.r.powi(2)).sqrt() + self.e[i])
    }
    /// Transform(): carriage heights of a machine position.
    fn carriages(&self, p: [f64; 3]) -> [f64; 3] {
        let t = self.towers();
        std::array::from_fn(|i| {
            (self.l[i].powi(2) - (p[0] - t[i][0]).powi(2) - (p[1] - t[i][1]).powi(2)).sqrt()
                + p[2]
                + p[0] * self.tilt[0]
                + p[1] * self.tilt[1]
        })
    }
    /// The machine position of carriage heights (the nozzle below the three
    /// spheres, its z in the tilted frame).
    fn position(&self, h: [f64; 3]) -> [f64; 3] {
        let t = self.towers();
        let c: [[f64; 3]; 3] = std::array::from_fn(|i| [t[i][0], t[i][1], h[i]]);
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let scale = |a: [f64; 3], s: f64| [a[0] * s, a[1] * s, a[2] * s];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let (s21, s31) = (sub(c[1], c[0]), sub(c[2], c[0]));
        let d = dot(s21, s21).sqrt();
        let ex = scale(s21, 1.0 / d);
        let i = dot(ex, s31);
        let v = sub(s31, scale(ex, i));
        let ey = scale(v, 1.0 / dot(v, v).sqrt());
        let ez = cross(ex, ey);
        let j = dot(ey, s31);
        let [r1, r2, r3] = self.l.map(|a| a * a);
        let x = (r1 - r2 + d * d) / (2.0 * d);
        let y = (r1 - r3 - 2.0 * i * x + i * i + j * j) / (2.0 * j);
        let z = -(r1 - x * x - y * y).sqrt();
        let p: [f64; 3] = std::array::from_fn(|k| c[0][k] + ex[k] * x + ey[k] * y + ez[k] * z);
        [
            p[0],
            p[1],
            p[2] - (p[0] * self.tilt[0] + p[1] * self.tilt[1]),
        ]
    }
}

const NOMINAL: Rrf = Rrf {
    l: [360.0; 3],
    r: 190.0,
    h: 420.0,
    corr: [0.0; 3],
    e: [0.0; 3],
    tilt: [0.0, 0.0],
};

const TRUTH: Rrf = Rrf {
    l: [360.0; 3],
    r: 190.6,
    h: 420.3,
    corr: [0.35, -0.2, 0.0],
    e: [0.25, -0.4, 0.15],
    tilt: [0.002, -0.0015],
};

/// G30 S-1 at (x, y): the firmware (nominal values) lowers the nozzle until
/// the probe touches the true bed; the z it reports.
fn probe(x: f64, y: f64) -> f64 {
    probe_of(&TRUTH, x, y)
}

/// [`probe`] on the printer `truth`.
fn probe_of(truth: &Rrf, x: f64, y: f64) -> f64 {
    let (hn, ht) = (NOMINAL.homed(), truth.homed());
    let true_z = |zp: f64| {
        let c = NOMINAL.carriages([x, y, zp]);
        truth.position(std::array::from_fn(|i| c[i] - hn[i] + ht[i]))[2]
    };
    let mut z = 0.0;
    for _ in 0..50 {
        let h = 1e-6;
        let f = true_z(z);
        let slope = (true_z(z + h) - true_z(z - h)) / (2.0 * h);
        z -= f / slope;
    }
    assert!(true_z(z).abs() < 1e-10);
    z
}

fn points() -> Vec<[f64; 2]> {
    let mut p = vec![[0.0, 0.0]];
    for ring in [60.0, 120.0] {
        for k in 0..8 {
            let a = (45.0 * k as f64 + ring / 10.0).to_radians();
            p.push([ring * a.cos(), ring * a.sin()]);
        }
    }
    p
}

/// The truth's probe heights at [`points`], as `G30 S-1` reports them, in
/// `probes.csv` under `d`.
fn write_probes(d: &std::path::Path) {
    let mut csv = String::from("x,y,z\n");
    for [x, y] in points() {
        csv.push_str(&format!("{x},{y},{:.9}\n", probe(x, y)));
    }
    std::fs::write(d.join("probes.csv"), csv).unwrap();
}

/// The written printer `new` is `truth` (radius, tower corrections, homed
/// carriage heights) to [`RECOVERED`]; `what` is said on failure.
fn assert_recovered(new: &Rrf, truth: &Rrf, what: &str) {
    let close = |a: f64, b: f64| (a - b).abs() < RECOVERED;
    assert!(close(new.r, truth.r), "radius: {what}");
    for i in 0..3 {
        assert!(close(new.corr[i], truth.corr[i]), "correction {i}: {what}");
        // Homing puts the carriages where the truth's do (H and the
        // adjustments split them as RepRapFirmware does: mean 0).
        assert!(close(new.homed()[i], truth.homed()[i]), "homed {i}: {what}");
    }
}

/// `M665 L R H B X Y Z` and `M666 X Y Z A B` of a written file.
fn parse(text: &str) -> Rrf {
    let mut r = NOMINAL;
    for line in text.lines() {
        let mut w = line.split_whitespace();
        let code = w.next().unwrap_or("");
        for word in w {
            let (k, v) = word.split_at(1);
            let num = || v.parse::<f64>().unwrap();
            match (code, k) {
                ("M665", "L") => {
                    let l: Vec<f64> = v.split(':').map(|x| x.parse().unwrap()).collect();
                    r.l = if l.len() == 1 {
                        [l[0]; 3]
                    } else {
                        [l[0], l[1], l[2]]
                    };
                }
                ("M665", "R") => r.r = num(),
                ("M665", "H") => r.h = num(),
                ("M665", "X") => r.corr[0] = num(),
                ("M665", "Y") => r.corr[1] = num(),
                ("M665", "Z") => r.corr[2] = num(),
                ("M666", "X") => r.e[0] = num(),
                ("M666", "Y") => r.e[1] = num(),
                ("M666", "Z") => r.e[2] = num(),
                ("M666", "A") => r.tilt[0] = num() / 100.0,
                ("M666", "B") => r.tilt[1] = num() / 100.0,
                _ => {}
            }
        }
    }
    r
}

#[test]
fn reprap_probe_heights_give_the_printer_back() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.g"),
        "; delta\nM665 L360 R190 H420 B150 X0 Y0 Z0 ; geometry\nM666 X0 Y0 Z0 A0 B0\nM558 P5 ; probe\n",
    )
    .unwrap();
    write_probes(d);
    let out = ok(
        d,
        &[
            "reprap",
            "--config",
            "config.g",
            "--probes",
            "probes.csv",
            "--free",
            "default,bed.rx,bed.ry",
            "--out",
            "new.g",
        ],
    );
    assert!(out.contains("17 probe heights"), "{out}");
    let new = parse(&std::fs::read_to_string(d.join("new.g")).unwrap());
    assert_recovered(&new, &TRUTH, &out);
    assert!(new.e.iter().sum::<f64>().abs() < 3e-3, "{out}");
    for k in 0..2 {
        assert!(
            (new.tilt[k] - TRUTH.tilt[k]).abs() < 1e-4 / 100.0 + 1e-6,
            "tilt {k}: {out}"
        );
    }
    // With the written values every probe point is on the bed.
    for [x, y] in points() {
        let zp = probe(x, y);
        let c = NOMINAL.carriages([x, y, zp]);
        let (hn, hw) = (NOMINAL.homed(), new.homed());
        let p = new.position(std::array::from_fn(|i| c[i] - hn[i] + hw[i]));
        assert!(p[2].abs() < 1e-3, "{p:?}");
    }
    // Bad input: no M665, a bad number, a missing column; the input is
    // never overwritten.
    std::fs::write(d.join("empty.g"), "G28\n").unwrap();
    fails(
        d,
        &["reprap", "--config", "empty.g", "--probes", "probes.csv"],
        1,
        "no M665 or M666 line",
    );
    std::fs::write(d.join("bad.g"), "M665 L360 R1..0\n").unwrap();
    fails(
        d,
        &["reprap", "--config", "bad.g", "--probes", "probes.csv"],
        1,
        "bad.g:1: `R1..0`",
    );
    std::fs::write(d.join("xy.csv"), "x,y\n0,0\n").unwrap();
    fails(
        d,
        &["reprap", "--config", "config.g", "--probes", "xy.csv"],
        1,
        "missing column `z`",
    );
    fails(
        d,
        &[
            "reprap",
            "--config",
            "config.g",
            "--probes",
            "probes.csv",
            "--out",
            "config.g",
        ],
        2,
        "",
    );
}

/// `M501` in config.g loads config-override.g, whose M665/M666 the firmware
/// runs: `reprap` reads it there, as the firmware does, so the fit starts
/// from the saved calibration (a stale config.g geometry would be written
/// back over it); without the file it refuses, naming both (issue 39, 6).
#[test]
fn reprap_reads_config_override_at_m501() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // config.g holds a stale geometry; the calibration the printer runs is
    // in config-override.g, loaded by M501; a line after M501 overrides B.
    std::fs::write(
        d.join("config.g"),
        "M665 L350 R180 H456 B140\nM666 X1 Y-1 Z0\nM501 ; load saved parameters\nM665 B150\n",
    )
    .unwrap();
    std::fs::write(
        d.join("config-override.g"),
        "; config-override.g file generated in response to M500\nM307 H0 A340.0 C140.0 D5.5\nM665 L360 R190 H420 B100 X0 Y0 Z0\nM666 X0 Y0 Z0 A0 B0\n",
    )
    .unwrap();
    write_probes(d);
    let out = ok(
        d,
        &[
            "reprap",
            "--config",
            "config.g",
            "--probes",
            "probes.csv",
            "--free",
            "default,bed.rx,bed.ry",
            "--out",
            "new.g",
        ],
    );
    let new = parse(&std::fs::read_to_string(d.join("new.g")).unwrap());
    for i in 0..3 {
        assert!(
            (new.homed()[i] - TRUTH.homed()[i]).abs() < RECOVERED,
            "homed {i}: {out}"
        );
    }
    assert!(
        out.contains("config-override.g when config.g runs M501"),
        "{out}"
    );
    // The override is an input: never an output.
    fails(
        d,
        &[
            "reprap",
            "--config",
            "config.g",
            "--probes",
            "probes.csv",
            "--out",
            "config-override.g",
        ],
        2,
        "also an input",
    );
    // Without it: refused, naming the M501 line and the missing file.
    std::fs::remove_file(d.join("config-override.g")).unwrap();
    fails(
        d,
        &["reprap", "--config", "config.g", "--probes", "probes.csv"],
        1,
        "config.g:3: M501 loads config-override.g",
    );
}

/// `reprap` never reports a fit it cannot write: only what M665/M666 hold
/// may be free (`all` means them); lines are read as the firmware reads
/// them (no spaces, line numbers, checksums, a BOM), values beyond a
/// printer's are refused with their line, and nothing is written as
/// `-0.000` (issue 39, 6).
#[test]
fn reprap_fits_only_what_the_firmware_holds() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.g"),
        "\u{feff}; delta\nN10 M665L360R190H420B150X0Y0Z0*103\nM666 X0 Y0 Z0 A0 B0\n",
    )
    .unwrap();
    write_probes(d);
    for free in ["default,bed.z", "default,a.tilt1", "ka"] {
        let o = crate::common::run(
            d,
            &[
                "reprap",
                "--config",
                "config.g",
                "--probes",
                "probes.csv",
                "--free",
                free,
            ],
        );
        assert_eq!(o.status.code(), Some(2), "{free}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("has no place in M665/M666"), "{free}: {err}");
    }
    let out = ok(
        d,
        &[
            "reprap",
            "--config",
            "config.g",
            "--probes",
            "probes.csv",
            "--free",
            "all",
            "--out",
            "new.g",
        ],
    );
    assert!(out.contains("12 parameters free"), "{out}");
    let new = std::fs::read_to_string(d.join("new.g")).unwrap();
    assert!(
        !new.contains("-0.000 ") && !new.contains("-0.00\n"),
        "{new}"
    );
    let got = parse(&new);
    for i in 0..3 {
        assert!(
            (got.homed()[i] - TRUTH.homed()[i]).abs() < RECOVERED,
            "homed {i}: {out}"
        );
    }
    for (text, needle) in [
        ("M665 L360 R190 H1e300 B150\n", "config.g:1: `H1e300`"),
        (
            "M665 L360 R190 H420 B150\nM666 A1e10\n",
            "config.g:2: `A1e10`",
        ),
    ] {
        std::fs::write(d.join("config.g"), text).unwrap();
        fails(
            d,
            &["reprap", "--config", "config.g", "--probes", "probes.csv"],
            1,
            needle,
        );
    }
    // Only M666: RepRapFirmware's default geometry, and a probe point it
    // cannot reach is named with it, not as a command of NaN.
    std::fs::write(d.join("config.g"), "M666 X0.1 Y0 Z-0.1\n").unwrap();
    std::fs::write(d.join("far.csv"), "x,y,z\n0,0,0\n150,0,0\n").unwrap();
    fails(
        d,
        &["reprap", "--config", "config.g", "--probes", "far.csv"],
        1,
        "far.csv:3: the probe point (150, 0) is out of reach",
    );
}

/// As many probe points as factors: RepRapFirmware solves the six factors
/// exactly from six points, and so does `reprap` (it used to refuse, asking
/// for seven); five points for six factors are refused, asking for six.
#[test]
fn reprap_solves_as_many_points_as_factors_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.g"),
        "M665 L360 R190 H420 B150
M666 X0 Y0 Z0
",
    )
    .unwrap();
    // A printer that differs from the file in the six factors only.
    let truth = Rrf {
        tilt: [0.0, 0.0],
        corr: [0.35, -0.2, 0.0],
        ..TRUTH
    };
    let mut pts = vec![[0.0, 0.0]];
    for k in 0..5 {
        let a = (72.0 * k as f64 + 10.0).to_radians();
        pts.push([120.0 * a.cos(), 120.0 * a.sin()]);
    }
    let csv = |pts: &[[f64; 2]]| {
        let mut csv = String::from("x,y,z\n");
        for [x, y] in pts {
            csv.push_str(&format!("{x},{y},{:.9}\n", probe_of(&truth, *x, *y)));
        }
        csv
    };
    std::fs::write(d.join("six.csv"), csv(&pts)).unwrap();
    let out = ok(
        d,
        &[
            "reprap", "--config", "config.g", "--probes", "six.csv", "--out", "new.g",
        ],
    );
    assert!(out.contains("6 probe heights"), "{out}");
    let new = parse(&std::fs::read_to_string(d.join("new.g")).unwrap());
    assert_recovered(&new, &truth, &out);
    std::fs::write(d.join("five.csv"), csv(&pts[..5])).unwrap();
    fails(
        d,
        &["reprap", "--config", "config.g", "--probes", "five.csv"],
        1,
        "at least 6",
    );
}

/// The 7- and 9-factor calibrations users' bed.g files ask for: one
/// diagonal shared by the three towers (`--free default,diagonal`, plus the
/// bed tilts for 9), written back as one `M665 L`; a file with three
/// different diagonals, or `diagonal` with `arm_a`, is refused.
#[test]
fn reprap_fits_one_shared_diagonal() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.g"),
        "M665 L360 R190 H420 B150\nM666 X0 Y0 Z0\n",
    )
    .unwrap();
    for (free, tilt) in [
        ("default,diagonal", [0.0, 0.0]),
        ("default,diagonal,bed.rx,bed.ry", TRUTH.tilt),
    ] {
        let truth = Rrf {
            l: [360.6; 3],
            tilt,
            ..TRUTH
        };
        let mut csv = String::from("x,y,z\n");
        for [x, y] in points() {
            csv.push_str(&format!("{x},{y},{:.9}\n", probe_of(&truth, x, y)));
        }
        std::fs::write(d.join("probes.csv"), csv).unwrap();
        let out = ok(
            d,
            &[
                "reprap",
                "--config",
                "config.g",
                "--probes",
                "probes.csv",
                "--free",
                free,
                "--out",
                "new.g",
            ],
        );
        let text = std::fs::read_to_string(d.join("new.g")).unwrap();
        assert!(text.contains("M665 L360.600 "), "{free}: {text}");
        let new = parse(&text);
        assert_recovered(&new, &truth, &format!("{free}: {out}"));
    }
    fails(
        d,
        &[
            "reprap",
            "--config",
            "config.g",
            "--probes",
            "probes.csv",
            "--free",
            "default,diagonal,arm_a",
        ],
        2,
        "exclude each other",
    );
    std::fs::write(d.join("three.g"), "M665 L360:360.2:359.9 R190 H420 B150\n").unwrap();
    fails(
        d,
        &[
            "reprap",
            "--config",
            "three.g",
            "--probes",
            "probes.csv",
            "--free",
            "default,diagonal",
        ],
        2,
        "free arm_a, arm_b, arm_c instead",
    );
}

/// RepRapFirmware 3's variables, as SeeMeCNC's vendor files use them:
/// `global name = …`, `set global.name = …` and `{global.name}` in M665,
/// with arithmetic; the firmware's object model or an unset variable is
/// refused, naming it and the line.
#[test]
fn reprap_evaluates_global_variables() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_probes(d);
    std::fs::write(
        d.join("config.g"),
        "global deltaRadius = 190            ; R\nglobal armLength = 350 ; L\nglobal name = \"Unknown\"\nset global.armLength = global.armLength + 2 * (6 - 1)\nM665 R{global.deltaRadius} L{global.armLength} B150 H{400 + 20}\nM666 X0 Y0 Z0\n",
    )
    .unwrap();
    let out = ok(
        d,
        &["reprap", "--config", "config.g", "--probes", "probes.csv"],
    );
    assert!(
        out.contains("before:\nM665 L360.000 R190.000 H420.000 B150.0"),
        "{out}"
    );
    for (text, needle) in [
        (
            "M665 L{move.axes[0].max} R190\n",
            "config.g:1: `move.axes[0].max`",
        ),
        (
            "M665 L{global.nope} R190\n",
            "config.g:1: `global.nope` is used before",
        ),
        (
            "global name = \"x\"\nM665 L{global.name} R190\n",
            "config.g:2: `{global.name}` gives a string, not a number",
        ),
        (
            "M665 L{360 R190\n",
            "config.g:1: `L{360 R190`: a `{` is not closed",
        ),
    ] {
        std::fs::write(d.join("config.g"), text).unwrap();
        fails(
            d,
            &["reprap", "--config", "config.g", "--probes", "probes.csv"],
            1,
            needle,
        );
    }
}

/// Every real RepRapFirmware configuration collected (25 printers, with
/// their sources, in `../shared/data/real-configs/reprap`) is read as the
/// firmware runs it, and written back unchanged when the bed probes flat:
/// the same diagonals, radius and tower corrections, and the same homed
/// carriage heights (H and the endstop adjustments split as the firmware
/// splits them) to the 3 decimals it keeps. A configuration that runs a
/// macro the case does not hold (M501 without its config-override.g, M98 of
/// a file of the card's) is refused, naming both; it is read again as if the
/// file were empty. A macro's name without quotes (RepRapFirmware 2) is
/// refused, then quoted.
#[test]
fn real_reprap_configurations_are_read_and_written_back() {
    let Some(root) = real_configs("reprap") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("flat.csv"),
        "x,y,z\n0,0,0\n30,0,0\n-15,26,0\n-15,-26,0\n0,30,0\n26,-15,0\n-26,-15,0\n",
    )
    .unwrap();
    let mut cases: Vec<_> = std::fs::read_dir(root.join("cases"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("config.g").exists())
        .collect();
    cases.sort();
    assert!(cases.len() >= 25, "{} cases", cases.len());
    let (mut written, mut refused) = (0, 0);
    for case in &cases {
        // The case's files as the card holds them, in sys/.
        let card = d.join("card");
        let _ = std::fs::remove_dir_all(&card);
        let sys = card.join("sys");
        std::fs::create_dir_all(&sys).unwrap();
        for f in std::fs::read_dir(case).unwrap() {
            let f = f.unwrap().path();
            std::fs::copy(&f, sys.join(f.file_name().unwrap())).unwrap();
        }
        let config = sys.join("config.g");
        let mut o;
        let mut tries = 0;
        let mut stand_ins: Vec<std::path::PathBuf> = vec![];
        loop {
            o = run(
                d,
                &[
                    "reprap",
                    "--config",
                    config.to_str().unwrap(),
                    "--probes",
                    "flat.csv",
                ],
            );
            if o.status.success() {
                break;
            }
            tries += 1;
            assert!(tries < 10, "{}", case.display());
            let err = String::from_utf8_lossy(&o.stderr).into_owned();
            refused += usize::from(tries == 1);
            // A macro the case does not hold (config-override.g of a
            // printer that saved nothing yet, a macro of the card's):
            // refused, naming the file; as if it were empty.
            let missing = if err.contains("M501 loads config-override.g") {
                assert!(!case.join("config-override.g").exists(), "{err}");
                Some(sys.join("config-override.g"))
            } else if let Some(i) = err.find("` runs ") {
                let rest = &err[i + "` runs ".len()..];
                rest.find(", whose commands")
                    .map(|j| std::path::PathBuf::from(&rest[..j]))
            } else {
                None
            };
            if let Some(m) = missing {
                std::fs::create_dir_all(m.parent().unwrap()).unwrap();
                std::fs::write(&m, "").unwrap();
                stand_ins.push(m);
                continue;
            }
            // A global the missing macro declared: declared in its stand-in.
            if let Some(i) = err.find("no global `") {
                let name = err[i + "no global `".len()..].split('`').next().unwrap();
                let m = stand_ins.last().expect("a stand-in declares it");
                let mut t = std::fs::read_to_string(m).unwrap();
                t.push_str(&format!("global {name} = 0\n"));
                std::fs::write(m, t).unwrap();
                continue;
            }
            // A macro's name without quotes: RepRapFirmware 3 refuses the
            // line; quoted, as version 2 read it.
            assert!(
                err.contains("takes a macro's name in quotes"),
                "{}: {err}",
                case.display()
            );
            let text = std::fs::read_to_string(&config).unwrap();
            let fixed: String = text
                .lines()
                .map(|l| match l.strip_prefix("M98 P") {
                    Some(rest) if !rest.starts_with('"') => {
                        let name = rest.split(';').next().unwrap().trim();
                        format!("M98 P\"{name}\"\n")
                    }
                    _ => format!("{l}\n"),
                })
                .collect();
            std::fs::write(&config, fixed).unwrap();
        }
        let (out, err) = (
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr),
        );
        assert!(o.status.success(), "{}: {err}", case.display());
        let block = |tag: &str| {
            let i = out
                .find(tag)
                .unwrap_or_else(|| panic!("{}: {out}", case.display()));
            parse(
                &out[i..]
                    .lines()
                    .skip(1)
                    .take(2)
                    .collect::<Vec<_>>()
                    .join("\n"),
            )
        };
        let (before, after) = (block("before:"), block("after:"));
        let same = |a: f64, b: f64| (a - b).abs() <= 1.5e-3;
        assert!(same(before.r, after.r), "{}: {out}", case.display());
        for i in 0..3 {
            assert!(same(before.l[i], after.l[i]), "{}: {out}", case.display());
            assert!(
                same(before.corr[i], after.corr[i]),
                "{}: {out}",
                case.display()
            );
            assert!(
                same(before.homed()[i], after.homed()[i]),
                "{}: {out}",
                case.display()
            );
        }
        written += 1;
    }
    eprintln!(
        "{written} written back unchanged, {refused} of them first refused (a macro not in the case: config-override.g, or one of the card's; or M98 without quotes)"
    );
    assert_eq!(written, cases.len());
    assert!(refused >= 1);
}

/// Seeded standard normal deviates (xorshift64* and Box–Muller): the probe's
/// noise of the tilt tests.
struct Normal(u64);

impl Normal {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn next(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The probe's noise in the tilt tests (mm): a good probe's. The 6-factor
/// fit absorbs all but 0.007 mm RMS of this bed's tilt, so a noisier probe
/// sees it less often (BENCHMARKS.md: the rates at 0.005 and 0.01 mm).
const PROBE_NOISE: f64 = 0.002;

/// Seeded runs of each tilt test.
const TILT_RUNS: usize = 40;

/// Of [`TILT_RUNS`] level beds, at most this many are flagged: the test's
/// level is 1 % (`OMITTED_ALPHA`), so 40 runs flag 0.4 on average and more
/// than 4 with probability 6e-5.
const TILT_FALSE_ALARMS: usize = 4;

/// `pkmcal reprap` (its default 6 factors) on `truth`'s probe heights with
/// noise of `seed`; its output.
fn default_fit_of(d: &std::path::Path, truth: &Rrf, seed: u64) -> String {
    default_fit_with(d, truth, seed, PROBE_NOISE)
}

/// [`default_fit_of`] with the probe's noise `sd` (mm).
fn default_fit_with(d: &std::path::Path, truth: &Rrf, seed: u64, sd: f64) -> String {
    let mut noise = Normal(0x9E37_79B9_7F4A_7C15 ^ seed.wrapping_mul(0xD1B5_4A32_D192_ED03));
    let mut csv = String::from("x,y,z\n");
    for [x, y] in points() {
        let z = probe_of(truth, x, y) + sd * noise.next();
        csv.push_str(&format!("{x},{y},{z:.9}\n"));
    }
    std::fs::write(d.join("probes.csv"), csv).unwrap();
    ok(
        d,
        &["reprap", "--config", "config.g", "--probes", "probes.csv"],
    )
}

/// A tilted bed with the firmware's default 6 factors (issue 49, 5): the
/// endstop corrections absorb the tilt (X0.397 Y−0.775 against the truth's
/// 0.25/−0.40); the summary says the heights show the tilt, in M666's
/// terms, and how to write it. Flagged in every seeded run with a tilt,
/// at the test's level without one.
#[test]
fn reprap_says_when_its_endstops_absorbed_a_bed_tilt() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.g"),
        "M665 L360 R190 H420 B150 X0 Y0 Z0\nM666 X0 Y0 Z0 A0 B0\n",
    )
    .unwrap();
    write_probes(d);
    let out = ok(
        d,
        &["reprap", "--config", "config.g", "--probes", "probes.csv"],
    );
    assert!(out.contains("M666 X0.397 Y-0.775"), "{out}");
    let line = out
        .lines()
        .find(|l| l.contains("the probe heights show a bed tilt"))
        .unwrap_or_else(|| panic!("no tilt warning: {out}"));
    // The tilt the data show is the truth's (percent, to the printed
    // digits), and the endstops are named as what took it.
    assert!(line.contains("+0.200 % in x and -0.150 % in y"), "{line}");
    assert!(
        line.contains("M666 Y by") && line.contains("M666 X by"),
        "{line}"
    );
    assert!(out.contains("--free default,bed.rx,bed.ry"), "{out}");
    // With the tilt freed, nothing is left to say.
    let freed = ok(
        d,
        &[
            "reprap",
            "--config",
            "config.g",
            "--probes",
            "probes.csv",
            "--free",
            "default,bed.rx,bed.ry",
        ],
    );
    assert!(!freed.contains("bed tilt"), "{freed}");
    // Noisy heights: a tilted bed flagged every time, a level one at the
    // test's level.
    let level = Rrf {
        tilt: [0.0, 0.0],
        ..TRUTH
    };
    let mut tilted_flagged = 0;
    let mut level_flagged = 0;
    for seed in 0..TILT_RUNS as u64 {
        tilted_flagged += default_fit_of(d, &TRUTH, seed).contains("bed tilt") as usize;
        level_flagged += default_fit_of(d, &level, seed).contains("bed tilt") as usize;
    }
    assert_eq!(tilted_flagged, TILT_RUNS);
    assert!(
        level_flagged <= TILT_FALSE_ALARMS,
        "{level_flagged} of {TILT_RUNS} level beds flagged"
    );
    eprintln!(
        "tilt flagged: {tilted_flagged}/{TILT_RUNS} tilted, {level_flagged}/{TILT_RUNS} level"
    );
}

/// The tilt warning's rates over many seeded runs and probe noises, for
/// BENCHMARKS.md (`cargo test -p pkmcal-cli --test reprap -- --ignored
/// --nocapture tilt_rates`).
#[test]
#[ignore]
fn tilt_rates() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.g"),
        "M665 L360 R190 H420 B150 X0 Y0 Z0\nM666 X0 Y0 Z0 A0 B0\n",
    )
    .unwrap();
    let level = Rrf {
        tilt: [0.0, 0.0],
        ..TRUTH
    };
    let runs = 200;
    for sd in [0.002, 0.005, 0.01] {
        let (mut t, mut l) = (0, 0);
        for seed in 1000..1000 + runs as u64 {
            t += default_fit_with(d, &TRUTH, seed, sd).contains("bed tilt") as usize;
            l += default_fit_with(d, &level, seed, sd).contains("bed tilt") as usize;
        }
        eprintln!("probe noise {sd} mm: tilted flagged {t}/{runs}, level flagged {l}/{runs}");
    }
}

/// The `before:` M665 line `reprap` prints for `config` (a file under `d`,
/// with more files beside it), or its error and exit code.
fn before_m665(d: &std::path::Path, files: &[(&str, &str)]) -> Result<String, (i32, String)> {
    for (name, text) in files {
        let p = d.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }
    let o = run(
        d,
        &["reprap", "--config", files[0].0, "--probes", "probes.csv"],
    );
    if !o.status.success() {
        return Err((
            o.status.code().unwrap_or(-1),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        ));
    }
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let i = out.find("before:\n").expect("a before block");
    Ok(out[i + 8..].lines().next().unwrap().to_string())
}

/// Issue 50, 5 and 3: a parameter given twice is read as RepRapFirmware's
/// `Seen` reads it (the first), and `if`/`elif`/`else` and `while` blocks are
/// followed as the firmware follows them where the file tells their
/// conditions (constants, globals, locals, `iterations`), so that no value
/// comes from a branch the printer does not run. Before, `M665 R195 R196`
/// read R196, and every branch's M665 was applied in turn (the last won).
#[test]
fn reprap_follows_the_configurations_blocks_as_the_firmware_does() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_probes(d);
    let cases: &[(&str, &str)] = &[
        ("M665 L360 R195 R196 H420 B150\n", "R195.000"),
        ("M665 L360 r195 H420 B150 R196\n", "R195.000"),
        (
            "global big = true\nif global.big\n  M665 L360 R190 H420 B150\nelse\n  M665 L300 R150 H400 B120\n",
            "L360.000 R190.000",
        ),
        (
            "global big = false\nif global.big\n  M665 L360 R190 H420 B150\nelse\n  M665 L300 R150 H400 B120\n",
            "L300.000 R150.000",
        ),
        (
            "var size = 2\nif var.size == 1\n  M665 L300 R150 H400 B120\nelif var.size == 2 && true\n  M665 L350 R185 H410 B140\nelse\n  M665 L360 R190 H420 B150\n",
            "L350.000 R185.000",
        ),
        // Nested blocks; a block closed by its indentation.
        (
            "M665 L360 R190 H420 B150\nif 1 < 2\n  if 2 > 3\n    M665 R100\n  M665 R191\nM665 B151\n",
            "L360.000 R191.000 H420.000 B151.0",
        ),
        // A loop with `iterations`, `break` and a local variable.
        (
            "var r = 180\nwhile true\n  if iterations >= 10\n    break\n  set var.r = var.r + 1\nM665 L360 R{var.r} H420 B150\n",
            "R190.000",
        ),
        // A loop that runs to the end of the file closes there.
        (
            "global r = 185\nM665 L360 R185 H420 B150\nwhile global.r < 190\n  set global.r = global.r + 1\n  M665 R{global.r}",
            "R190.000",
        ),
        // A condition on the firmware's state around what pkmcal does not
        // read: followed (its variables are unknown afterwards).
        (
            "if boards[0].shortName == \"2WiFi\"\n  M569 P0 S1\n  global x = 5\nM665 L360 R190 H420 B150\n",
            "R190.000",
        ),
        // A comment at the start of a line closes the blocks, as in the
        // firmware: the indented line after it runs.
        (
            "M665 L360 R190 H420 B150\nif false\n  M665 R100\n; a comment\n  M665 R192\n",
            "R192.000",
        ),
    ];
    for (text, want) in cases {
        let got = before_m665(d, &[("config.g", text)]).unwrap_or_else(|e| panic!("{text}: {e:?}"));
        assert!(got.contains(want), "{text}: {got}");
    }
    // What the file cannot tell, where the geometry depends on it: refused
    // by name, with the line, saying what to do.
    let refused: &[(&str, &str)] = &[
        (
            "if move.axes[0].max > 100\n  M665 L360 R190 H420 B150\nelse\n  M665 L300 R150 H400 B120\n",
            "config.g:1: `if move.axes[0].max > 100`: `move.axes[0].max` is the firmware's own state",
        ),
        (
            "M665 L360 R190 H420 B150\nif boards[0].shortName == \"x\"\n  M666 X1\n",
            "its block sets what pkmcal reads (`M666 X1` at line 3)",
        ),
        (
            "if sensors.probes[0].value[0] > 0\n  global r = 185\nM665 L360 R{global.r} H420 B150\n",
            "config.g:3: `global.r` is not known: it is set in the block of `if` at line 1",
        ),
        ("if exists(global.r)\n  M665 L360 R190 H420 B150\n", ""),
        (
            "M665 L360 R190 H420 B150\nelse\n  M665 R100\n",
            "config.g:2: `else` does not follow an `if` block",
        ),
        (
            "M665 L360 R190 H420 B150\nwhile true\n  M666 X0\n",
            "the loops run more than 100000 times",
        ),
        (
            "global r = 1\nglobal r = 2\nM665 L360 R190\n",
            "the variable already exists",
        ),
    ];
    for (text, needle) in refused {
        match before_m665(d, &[("config.g", text)]) {
            Err((1, e)) => assert!(e.contains(needle), "{text}: {e}"),
            other if needle.is_empty() => {
                // `exists` of a global not declared is false: no M665 runs.
                let (_, e) = other.unwrap_err();
                assert!(e.contains("no M665 or M666"), "{text}: {e}");
            }
            other => panic!("{text}: {other:?}"),
        }
    }
}

/// Issue 50, 2: 50,000 nested parentheses (a 100 kB config.g), in a
/// parameter or through `global r = ((…))`, are refused by name: before,
/// the reader overflowed its stack and aborted (exit 134).
#[test]
fn reprap_refuses_deep_expressions_without_overflowing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_probes(d);
    let deep = format!("{}190{}", "(".repeat(50_000), ")".repeat(50_000));
    for text in [
        format!("M665 L360 R{{{deep}}} H420 B150\n"),
        format!("global r = {deep}\nM665 L360 R{{global.r}} H420 B150\n"),
        format!("if {deep} > 1\n  M665 L360 R190 H420 B150\n"),
        format!("M665 L360 R{{{}190}} H420 B150\n", "-".repeat(50_000)),
    ] {
        match before_m665(d, &[("config.g", &text)]) {
            Err((1, e)) => assert!(e.contains("nests more than 64"), "{e}"),
            other => panic!("{other:?}"),
        }
    }
}

/// Issue 50, 3: `M98 P"file"` runs the file in place, as the firmware does
/// (its name relative to /sys, where the configuration is; `/sys/…` and a
/// drive prefix too), with its parameters as `param.X`; `M98
/// P"config-override.g"` as `M501`; a file that cannot be read, a cycle,
/// and a chain deeper than the firmware's 10 files are refused by name.
/// Before, every M98 was skipped without a word.
#[test]
fn reprap_runs_macros_as_the_firmware_does() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_probes(d);
    let m665 = "M665 L360 R190 H420 B150\n";
    let got = before_m665(
        d,
        &[
            (
                "sys/config.g",
                "M665 L350 R180 H400 B140\nM98 P\"delta.g\" S191\nM665 B151\n",
            ),
            ("sys/delta.g", "M665 L360 R{param.S} H420\n"),
        ],
    )
    .unwrap();
    assert!(got.contains("L360.000 R191.000 H420.000 B151.0"), "{got}");
    for call in [
        "M98 P\"config-override.g\"",
        "M98 P\"0:/sys/config-override.g\"",
        "M98 P\"/sys/config-override.g\"",
        "M501",
    ] {
        let got = before_m665(
            d,
            &[
                (
                    "sys/config.g",
                    &format!("M665 L350 R180 H400 B140\n{call}\n"),
                ),
                ("sys/config-override.g", m665),
            ],
        )
        .unwrap();
        assert!(got.contains("L360.000 R190.000"), "{call}: {got}");
    }
    // A macro outside /sys, on the card's folders.
    let got = before_m665(
        d,
        &[
            ("sys/config.g", "M98 P\"/macros/delta.g\" M666 X0.1\n"),
            ("macros/delta.g", m665),
        ],
    )
    .unwrap();
    assert!(got.contains("L360.000 R190.000"), "{got}");
    std::fs::remove_dir_all(d.join("sys")).unwrap();
    std::fs::remove_dir_all(d.join("macros")).unwrap();
    let refused: &[(&[(&str, &str)], &str)] = &[
        (
            &[("config.g", "M665 L360 R190 H420 B150\nM98 P\"missing.g\"\n")],
            "config.g:2: `M98 P\"missing.g\"` runs ",
        ),
        (
            &[("config.g", "M665 L360 R190 H420 B150\nM98 Plocal.g\n")],
            "takes a macro's name in quotes",
        ),
        (
            &[
                ("config.g", "M98 P\"a.g\"\n"),
                ("a.g", "M98 P\"b.g\"\n"),
                ("b.g", "M98 P\"a.g\"\n"),
            ],
            "b.g:1: `M98 P\"a.g\"` runs ",
        ),
        (
            &[("config.g", "M98 P\"config.g\"\n")],
            "which is already running",
        ),
        (
            &[
                ("config.g", "M98 P\"m1.g\"\n"),
                ("m1.g", "M98 P\"m2.g\"\n"),
                ("m2.g", "M98 P\"m3.g\"\n"),
                ("m3.g", "M98 P\"m4.g\"\n"),
                ("m4.g", "M98 P\"m5.g\"\n"),
                ("m5.g", "M98 P\"m6.g\"\n"),
                ("m6.g", "M98 P\"m7.g\"\n"),
                ("m7.g", "M98 P\"m8.g\"\n"),
                ("m8.g", "M98 P\"m9.g\"\n"),
                ("m9.g", "M98 P\"m10.g\"\n"),
                ("m10.g", m665),
            ],
            "m9.g:1: `M98 P\"m10.g\"`: macros call each other more than 10 files deep",
        ),
        (
            &[("config.g", "M98 P\"/macros/x.g\"\n")],
            "copy the card's folders as they are",
        ),
    ];
    for (files, needle) in refused {
        match before_m665(d, files) {
            Err((1, e)) => assert!(e.contains(needle), "{files:?}: {e}"),
            other => panic!("{files:?}: {other:?}"),
        }
    }
    // Nine deep is within the firmware's limit.
    std::fs::write(d.join("m9.g"), m665).unwrap();
    assert!(before_m665(d, &[("config.g", "M98 P\"m1.g\"\n")]).is_ok());
}

/// Issue 50, 5: a line whose checksum does not match is skipped by the
/// firmware: refused, with the checksum its characters give.
#[test]
fn reprap_refuses_a_wrong_checksum() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_probes(d);
    match before_m665(d, &[("config.g", "N10 M665L360R190H420B150X0Y0Z0*71\n")]) {
        Err((1, e)) => assert!(
            e.contains(
                "config.g:1: the checksum *71 does not match the line (its characters give *103)"
            ),
            "{e}"
        ),
        other => panic!("{other:?}"),
    }
    // Without a line number, `*` is no checksum for the firmware.
    assert!(before_m665(d, &[("config.g", "M665 L360 R190 H420 B{150*1}\n")]).is_ok());
}
