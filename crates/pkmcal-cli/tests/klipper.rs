//! `pkmcal klipper`: a delta printer's Klipper configuration in, Klipper's
//! values out. The probe results are made here with Klipper's own formulas
//! (carriage heights from tower positions and arm lengths, steps from the
//! endstops), and the values written back are checked with Klipper's forward
//! kinematics (three-sphere trilateration), so the round trip does not rest
//! on pkmcal's model of the printer.

mod common;
use common::{fails, ok};

/// The identified Klipper values equal the truth (mm, degrees): the saved
/// steps are rounded to 0.001 step (12.5 nm of carriage travel).
const RECOVERED: f64 = 1e-4;
/// Klipper's forward kinematics with the written values puts every probe
/// point on the bed (mm).
const ON_THE_BED: f64 = 1e-4;
/// The values identified with the arm lengths from heights and distances
/// rounded to 1 µm and 0.001 step (mm, degrees): the arms correlate with the
/// endstops, which amplifies the rounding.
const ARMS_RECOVERED: f64 = 2e-4;

/// A printer: delta_radius, tower angles (°), arm lengths, endstops, step
/// distance.
#[derive(Clone, Copy)]
struct Printer {
    radius: f64,
    angles: [f64; 3],
    arms: [f64; 3],
    endstops: [f64; 3],
    step: f64,
}

impl Printer {
    fn towers(&self) -> [[f64; 2]; 3] {
        self.angles.map(|a| {
            let a = a.to_radians();
            [a.cos() * self.radius, a.sin() * self.radius]
        })
    }
    fn abs_endstop(&self, i: usize) -> f64 {
        self.endstops[i] + (self.arms[i].powi(2) - self.radius.powi(2)).sqrt()
    }
    /// Klipper's `calc_stable_position`: steps from each endstop.
    fn steps(&self, p: [f64; 3]) -> [f64; 3] {
        let t = self.towers();
        std::array::from_fn(|i| {
            let h = (self.arms[i].powi(2) - (t[i][0] - p[0]).powi(2) - (t[i][1] - p[1]).powi(2))
                .sqrt()
                + p[2];
            (self.abs_endstop(i) - h) / self.step
        })
    }
    /// Klipper's `get_position_from_stable`: the nozzle below the three
    /// carriages' spheres.
    fn position(&self, steps: [f64; 3]) -> [f64; 3] {
        let t = self.towers();
        let c: [[f64; 3]; 3] =
            std::array::from_fn(|i| [t[i][0], t[i][1], self.abs_endstop(i) - steps[i] * self.step]);
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let scale = |a: [f64; 3], s: f64| [a[0] * s, a[1] * s, a[2] * s];
        let s21 = sub(c[1], c[0]);
        let s31 = sub(c[2], c[0]);
        let d = dot(s21, s21).sqrt();
        let ex = scale(s21, 1.0 / d);
        let i = dot(ex, s31);
        let vect_ey = sub(s31, scale(ex, i));
        let ey = scale(vect_ey, 1.0 / dot(vect_ey, vect_ey).sqrt());
        let ez = cross(ex, ey);
        let j = dot(ey, s31);
        let [r1, r2, r3] = self.arms.map(|a| a * a);
        let x = (r1 - r2 + d * d) / (2.0 * d);
        let y = (r1 - r3 - 2.0 * i * x + i * i + j * j) / (2.0 * j);
        let z = -(r1 - x * x - y * y).sqrt();
        [
            c[0][0] + ex[0] * x + ey[0] * y + ez[0] * z,
            c[0][1] + ex[1] * x + ey[1] * y + ez[1] * z,
            c[0][2] + ex[2] * x + ey[2] * y + ez[2] * z,
        ]
    }
}

const NOMINAL: Printer = Printer {
    radius: 174.75,
    angles: [210.0, 330.0, 90.0],
    arms: [333.0; 3],
    endstops: [297.05; 3],
    step: 40.0 / (200.0 * 16.0),
};

const TRUTH: Printer = Printer {
    radius: 175.1,
    angles: [210.3, 329.7, 90.0],
    arms: [333.0; 3],
    endstops: [297.4, 296.7, 297.1],
    step: 40.0 / (200.0 * 16.0),
};

/// Klipper's default probe points on a circle of 50 mm, and an inner ring.
fn probe_points() -> Vec<[f64; 3]> {
    let mut p = vec![[0.0, 0.0, 0.0]];
    let scatter = [0.95, 0.90, 0.85, 0.70, 0.75, 0.80];
    for (i, s) in scatter.iter().enumerate() {
        let a = (90.0 + 60.0 * i as f64).to_radians();
        p.push([a.cos() * 50.0 * s, a.sin() * 50.0 * s, 0.0]);
    }
    for i in 0..6 {
        let a = (60.0 * i as f64).to_radians();
        p.push([a.cos() * 25.0, a.sin() * 25.0, 0.0]);
    }
    p
}

/// A printer.cfg with the nominal values (stepper b and c taking a's
/// defaults, comments, an include) and the truth's probe results in its
/// SAVE_CONFIG block.
fn config(dir: &std::path::Path) -> String {
    std::fs::write(
        dir.join("steppers.cfg"),
        "[stepper_b]\nmicrosteps: 16\nrotation_distance: 40\n\n[stepper_c]\nmicrosteps: 16 ; inline\nrotation_distance = 40\n",
    )
    .unwrap();
    let mut s = String::from(
        "# test printer\n[stepper_a]\nstep_pin: PF0\nmicrosteps: 16\nrotation_distance: 40\n\
         position_endstop: 297.05   # at the top\narm_length: 333.0\n\n[include steppers.cfg]\n\n\
         [printer]\nkinematics: delta\ndelta_radius: 174.75\n\n[gcode_macro START]\ngcode:\n  G28\n  G1 Z5\n\n\
         [delta_calibrate]\nradius: 50\n\n\
         #*# <---------------------- SAVE_CONFIG ---------------------->\n\
         #*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n#*# [delta_calibrate]\n",
    );
    for (n, p) in probe_points().into_iter().enumerate() {
        let st = TRUTH.steps(p);
        s.push_str(&format!(
            "#*# height{n} = 0.0\n#*# height{n}_pos = {:.3},{:.3},{:.3}\n",
            st[0], st[1], st[2]
        ));
    }
    s
}

/// Klipper's values from the SAVE_CONFIG block of a written configuration.
fn saved(text: &str) -> Printer {
    let block = &text[text.find("SAVE_CONFIG").unwrap()..];
    let mut section = String::new();
    let mut p = NOMINAL;
    for l in block.lines() {
        let l = l.trim_start_matches("#*#").trim();
        if let Some(s) = l.strip_prefix('[') {
            section = s.trim_end_matches(']').to_string();
            continue;
        }
        let Some((k, v)) = l.split_once('=') else {
            continue;
        };
        let (k, v) = (k.trim(), v.trim());
        let Ok(v) = v.parse::<f64>() else { continue };
        let i = ["stepper_a", "stepper_b", "stepper_c"]
            .iter()
            .position(|s| *s == section);
        match (i, k) {
            (None, "delta_radius") => p.radius = v,
            (Some(i), "angle") => p.angles[i] = v,
            (Some(i), "arm_length") => p.arms[i] = v,
            (Some(i), "position_endstop") => p.endstops[i] = v,
            _ => {}
        }
    }
    p
}

#[test]
fn klipper_probe_heights_give_klippers_values_back() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("printer.cfg"), config(d)).unwrap();
    let out = ok(
        d,
        &[
            "klipper",
            "--config",
            "printer.cfg",
            "--out",
            "new.cfg",
            "--out-dir",
            "kd",
        ],
    );
    assert!(out.contains("13 probe heights"), "{out}");
    let text = std::fs::read_to_string(d.join("new.cfg")).unwrap();
    let new = saved(&text);
    let close = |a: f64, b: f64| (a - b).abs() < RECOVERED;
    assert!(close(new.radius, TRUTH.radius), "{out}");
    for i in 0..3 {
        assert!(close(new.angles[i], TRUTH.angles[i]), "angle {i}: {out}");
        assert!(
            close(new.endstops[i], TRUTH.endstops[i]),
            "endstop {i}: {out}"
        );
        assert!(close(new.arms[i], TRUTH.arms[i]), "arm {i}");
    }
    // Klipper's kinematics with the written values: every probe point on the
    // bed; with the old ones, not.
    for p in probe_points() {
        let st = TRUTH.steps(p);
        let st = st.map(|s| (s * 1000.0).round() / 1000.0);
        assert!(
            new.position(st)[2].abs() < ON_THE_BED,
            "{:?}",
            new.position(st)
        );
    }
    let worst_before = probe_points()
        .iter()
        .map(|p| NOMINAL.position(TRUTH.steps(*p))[2].abs())
        .fold(0.0, f64::max);
    assert!(worst_before > 0.1, "{worst_before}");
    // The regular part keeps its text, the saved options commented out; the
    // probe results stay in the block.
    assert!(
        text.contains("#position_endstop: 297.05   # at the top"),
        "{text}"
    );
    assert!(text.contains("#delta_radius: 174.75"));
    assert!(text.contains("  G1 Z5"));
    assert!(text.contains("#*# height12_pos = "));
    // The written mechanism and data calibrate alike with the other commands.
    let cal = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            "kd/mechanism.toml",
            "--data",
            "kd/probes.csv",
            "--out",
            "again.toml",
        ],
    );
    assert!(cal.contains("delta_radius"), "{cal}");
    // The written file reads back: calibrating it again changes nothing.
    let again = ok(d, &["klipper", "--config", "new.cfg", "--out", "new2.cfg"]);
    let new2 = saved(&std::fs::read_to_string(d.join("new2.cfg")).unwrap());
    assert!(close(new2.radius, new.radius), "{again}");
    for i in 0..3 {
        assert!(close(new2.endstops[i], new.endstops[i]), "{again}");
    }
}

/// A printer whose arms differ from the configuration's: only distances
/// measured on a printed object see them.
const TRUTH_ARMS: Printer = Printer {
    arms: [333.4, 332.7, 333.2],
    ..TRUTH
};

/// The pairs of points Klipper's calibration object (`calibrate_size.stl`,
/// `DELTA_ANALYZE`) is measured between: from the centre's ridge to each
/// outer pillar, and between neighbouring outer pillars.
fn object_pairs() -> Vec<([f64; 3], [f64; 3])> {
    let angles = [210.0_f64, 270.0, 330.0, 30.0, 90.0, 150.0];
    let xy: Vec<[f64; 2]> = angles
        .iter()
        .map(|a| [a.to_radians().cos(), a.to_radians().sin()])
        .collect();
    let (ridge, outer) = (4.5, 65.0);
    let mut pairs: Vec<([f64; 3], [f64; 3])> = xy
        .iter()
        .map(|[x, y]| {
            (
                [x * ridge, y * ridge, 0.0],
                [x * (outer + ridge), y * (outer + ridge), 0.0],
            )
        })
        .collect();
    for k in 0..6 {
        let [sx, sy] = [xy[k][0] * outer, xy[k][1] * outer];
        let [ax, ay] = xy[(k + 2) % 6];
        pairs.push((
            [ax * ridge + sx, ay * ridge + sy, 0.0],
            [ax * (outer + ridge) + sx, ay * (outer + ridge) + sy, 0.0],
        ));
    }
    pairs
}

/// Probe heights and the calibration object's distances (Klipper's extended
/// calibration): the arm lengths come back with the rest, by default, and
/// the distances are reported before and after.
#[test]
fn klipper_distances_identify_the_arm_lengths() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("steppers.cfg"), "").unwrap();
    let mut s = config(d);
    // The probe heights of the printer with the other arms.
    let mut lines: Vec<String> = s.lines().map(String::from).collect();
    lines.retain(|l| !l.starts_with("#*# height"));
    s = lines.join("\n") + "\n";
    for (n, p) in probe_points().into_iter().enumerate() {
        let st = TRUTH_ARMS.steps(p);
        s.push_str(&format!(
            "#*# height{n} = 0.0\n#*# height{n}_pos = {:.3},{:.3},{:.3}\n",
            st[0], st[1], st[2]
        ));
    }
    // The object printed with the configured geometry, where the nozzle
    // really went measured with calipers.
    for (n, (a, b)) in object_pairs().into_iter().enumerate() {
        let (sa, sb) = (NOMINAL.steps(a), NOMINAL.steps(b));
        let round = |v: [f64; 3]| v.map(|x| (x * 1000.0).round() / 1000.0);
        let (sa, sb) = (round(sa), round(sb));
        let (pa, pb) = (TRUTH_ARMS.position(sa), TRUTH_ARMS.position(sb));
        let dist = (0..3).map(|k| (pa[k] - pb[k]).powi(2)).sum::<f64>().sqrt();
        s.push_str(&format!(
            "#*# distance{n} = {dist:.6}\n#*# distance{n}_pos1 = {:.3},{:.3},{:.3}\n#*# distance{n}_pos2 = {:.3},{:.3},{:.3}\n",
            sa[0], sa[1], sa[2], sb[0], sb[1], sb[2]
        ));
    }
    std::fs::write(d.join("printer.cfg"), &s).unwrap();
    let out = ok(
        d,
        &[
            "klipper",
            "--config",
            "printer.cfg",
            "--out",
            "new.cfg",
            "--out-dir",
            "kd",
        ],
    );
    assert!(
        out.contains("13 probe heights and 12 distances measured on the calibration object"),
        "{out}"
    );
    assert!(out.contains("arm_a arm_b arm_c"), "{out}");
    assert!(out.contains("distance errors: before max"), "{out}");
    let new = saved(&std::fs::read_to_string(d.join("new.cfg")).unwrap());
    let close = |a: f64, b: f64| (a - b).abs() < ARMS_RECOVERED;
    assert!(close(new.radius, TRUTH_ARMS.radius), "{out}");
    for i in 0..3 {
        assert!(close(new.arms[i], TRUTH_ARMS.arms[i]), "arm {i}: {out}");
        assert!(
            close(new.angles[i], TRUTH_ARMS.angles[i]),
            "angle {i}: {out}"
        );
        assert!(
            close(new.endstops[i], TRUTH_ARMS.endstops[i]),
            "endstop {i}: {out}"
        );
    }
    // The distances go to the other commands too.
    assert!(d.join("kd/distances.csv").exists());
    let cal = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            "kd/mechanism.toml",
            "--data",
            "kd/probes.csv",
            "--distances",
            "kd/distances.csv",
            "--free",
            "delta_radius,angle_a,angle_b,da,db,dc,arm_a,arm_b,arm_c",
            "--out",
            "again.toml",
        ],
    );
    assert!(cal.contains("13 poses and 12 distances"), "{cal}");
}

#[test]
fn klipper_refuses_what_it_cannot_use() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good = config(d);
    // Never over its input.
    std::fs::write(d.join("printer.cfg"), &good).unwrap();
    fails(
        d,
        &["klipper", "--config", "printer.cfg", "--out", "printer.cfg"],
        2,
        "printer.cfg",
    );
    assert_eq!(
        std::fs::read_to_string(d.join("printer.cfg")).unwrap(),
        good
    );
    // Not a delta.
    std::fs::write(
        d.join("corexy.cfg"),
        good.replace("kinematics: delta", "kinematics: corexy"),
    )
    .unwrap();
    fails(
        d,
        &["klipper", "--config", "corexy.cfg"],
        1,
        "kinematics is `corexy`",
    );
    // No probe results.
    let bare = &good[..good.find("#*# <---").unwrap()];
    std::fs::write(d.join("bare.cfg"), bare).unwrap();
    fails(
        d,
        &["klipper", "--config", "bare.cfg"],
        1,
        "run DELTA_CALIBRATE",
    );
    // A malformed stable position names its line.
    std::fs::write(
        d.join("bad.cfg"),
        good.replacen("height3_pos = ", "height3_pos = x", 1),
    )
    .unwrap();
    fails(d, &["klipper", "--config", "bad.cfg"], 1, "height3_pos");
    // An unknown parameter name.
    fails(
        d,
        &["klipper", "--config", "printer.cfg", "--free", "radius"],
        2,
        "unknown parameter `radius`",
    );
    // A missing file.
    fails(d, &["klipper", "--config", "nope.cfg"], 1, "nope.cfg");
    assert!(!d.join("new.cfg").exists());
}
