//! `pkmcal reprap` against RepRapFirmware's own delta formulas, written
//! here independently (its `LinearDeltaKinematics`): probe heights made for a
//! known printer give that printer's M665/M666 back.

mod common;
use common::{fails, ok};

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
    let (hn, ht) = (NOMINAL.homed(), TRUTH.homed());
    let true_z = |zp: f64| {
        let c = NOMINAL.carriages([x, y, zp]);
        TRUTH.position(std::array::from_fn(|i| c[i] - hn[i] + ht[i]))[2]
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
    let close = |a: f64, b: f64| (a - b).abs() < RECOVERED;
    assert!(close(new.r, TRUTH.r), "{out}");
    for i in 0..3 {
        assert!(close(new.corr[i], TRUTH.corr[i]), "correction {i}: {out}");
        // Homing puts the carriages where the truth's do (H and the
        // adjustments split them as RepRapFirmware does: mean 0).
        assert!(close(new.homed()[i], TRUTH.homed()[i]), "homed {i}: {out}");
    }
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
        "\u{feff}; delta\nN10 M665L360R190H420B150X0Y0Z0*71\nM666 X0 Y0 Z0 A0 B0\n",
    )
    .unwrap();
    write_probes(d);
    for free in ["default,bed.z", "default,a.tilt1", "ka"] {
        let o = common::run(
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
