//! Klipper's rotary delta as pkmcal reads it, against Klipper's own
//! formulas written here independently from its `kin_rotary_delta.c`
//! (`rotary_two_arm_calc`), `rotary_delta.py` (the elbows, the endstops'
//! angles, stable positions), `mathutil.py` (trilateration, coordinate
//! descent) and `delta_calibrate.py` (the error Klipper minimises): the
//! description predicts Klipper's positions to 1e-9 mm over the build
//! volume, probe results of a known printer give it back, the default fit
//! is Klipper's own, and bad input is refused by name.

use pkmcal::{Mechanism, Params, Request};
use pkmcal_io::firmware::klipper::{Weighting, read_config};
use pkmcal_io::firmware::klipper_rotary::{RotaryPrinter, is_rotary};
use pkmcal_io::firmware::{self, Firmware};
use std::path::Path;

/// Agreement of pkmcal's model with Klipper's formulas (mm).
const SAME_MM: f64 = 1e-9;
/// Values identified from noise-free results against the truth (mm, °).
const RECOVERED: f64 = 1e-5;

/// A rotary delta as Klipper's `RotaryDeltaCalibration` holds it.
#[derive(Clone, Debug)]
struct K {
    shoulder_radius: f64,
    shoulder_height: f64,
    angles: [f64; 3],
    upper: [f64; 3],
    lower: [f64; 3],
    endstops: [f64; 3],
    step: f64,
}

impl K {
    /// `rotary_stepper_calc_position` with `rotary_two_arm_calc`.
    fn angle(&self, i: usize, c: [f64; 3]) -> f64 {
        let a = self.angles[i].to_radians();
        let sjz = c[1] * a.cos() - c[0] * a.sin();
        let sjx = c[0] * a.cos() + c[1] * a.sin() - self.shoulder_radius;
        let sjy = c[2] - self.shoulder_height;
        let (dx, dy) = (sjx, sjy);
        let upper2 = self.upper[i] * self.upper[i];
        let lower2 = self.lower[i] * self.lower[i] - sjz * sjz;
        let inv_dy = 1.0 / dy;
        let c1 = 0.5 * inv_dy * (dx * dx + dy * dy + upper2 - lower2);
        let c2 = dx * inv_dy;
        let scale = c2 * c2 + 1.0;
        let sx = c1 * c2 + (scale * upper2 - c1 * c1).sqrt();
        let sy = c1 * scale - c2 * sx;
        sy.atan2(sx)
    }
    /// `abs_endstops`.
    fn abs_endstops(&self) -> [f64; 3] {
        std::array::from_fn(|i| self.angle(i, [0.0, 0.0, self.endstops[i]]))
    }
    /// `elbow_coord`.
    fn elbow(&self, i: usize, spos: f64) -> [f64; 3] {
        let (x, y) = (self.upper[i] * spos.cos(), self.upper[i] * spos.sin());
        let a = self.angles[i].to_radians();
        [
            (x + self.shoulder_radius) * a.cos(),
            (x + self.shoulder_radius) * a.sin(),
            y + self.shoulder_height,
        ]
    }
    /// `actuator_to_cartesian` (`mathutil.trilateration`).
    fn cartesian(&self, spos: [f64; 3]) -> [f64; 3] {
        let s: [[f64; 3]; 3] = std::array::from_fn(|i| self.elbow(i, spos[i]));
        let r2 = self.lower.map(|l| l * l);
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let mul = |a: [f64; 3], f: f64| [a[0] * f, a[1] * f, a[2] * f];
        let (s21, s31) = (sub(s[1], s[0]), sub(s[2], s[0]));
        let d = dot(s21, s21).sqrt();
        let ex = mul(s21, 1.0 / d);
        let i = dot(ex, s31);
        let v = sub(s31, mul(ex, i));
        let ey = mul(v, 1.0 / dot(v, v).sqrt());
        let ez = [
            ex[1] * ey[2] - ex[2] * ey[1],
            ex[2] * ey[0] - ex[0] * ey[2],
            ex[0] * ey[1] - ex[1] * ey[0],
        ];
        let j = dot(ey, s31);
        let x = (r2[0] - r2[1] + d * d) / (2.0 * d);
        let y = (r2[0] - r2[2] - x * x + (x - i).powi(2) + j * j) / (2.0 * j);
        let z = -(r2[0] - x * x - y * y).sqrt();
        std::array::from_fn(|k| s[0][k] + ex[k] * x + ey[k] * y + ez[k] * z)
    }
    /// `get_position_from_stable`.
    fn position_from_stable(&self, steps: [f64; 3]) -> [f64; 3] {
        let e = self.abs_endstops();
        self.cartesian(std::array::from_fn(|i| e[i] - steps[i] * self.step))
    }
    /// `calc_stable_position`.
    fn stable(&self, c: [f64; 3]) -> [f64; 3] {
        let e = self.abs_endstops();
        std::array::from_fn(|i| (e[i] - self.angle(i, c)) / self.step)
    }
}

/// 16 microsteps, 200 full steps, gears 80:16 and 60:15.
const GEAR: &str = "80:16, 60:15";
fn step() -> f64 {
    std::f64::consts::TAU / (200.0 * 16.0 * (80.0 / 16.0) * (60.0 / 15.0))
}

fn nominal() -> K {
    K {
        shoulder_radius: 35.0,
        shoulder_height: 400.0,
        angles: [30.0, 150.0, 270.0],
        upper: [165.0; 3],
        lower: [315.0; 3],
        endstops: [240.0; 3],
        step: step(),
    }
}

/// `DELTA_CALIBRATE`'s probe points at `radius` (its scatter), and more on
/// rings for `extra`.
fn probe_points(radius: f64, extra: usize) -> Vec<[f64; 2]> {
    let mut out = vec![[0.0, 0.0]];
    for (i, s) in [0.95, 0.90, 0.85, 0.70, 0.75, 0.80].iter().enumerate() {
        let a = (90.0 + 60.0 * i as f64).to_radians();
        out.push([a.cos() * radius * s, a.sin() * radius * s]);
    }
    for k in 0..extra {
        let r = radius * (0.3 + 0.6 * ((k * 7) % 10) as f64 / 10.0);
        let a = (17.0 + 360.0 * k as f64 / extra as f64).to_radians();
        out.push([a.cos() * r, a.sin() * r]);
    }
    out
}

/// The stable position at which the probe of the firmware `fw`, lowered
/// over `xy`, triggers on the bed of the printer `truth` (`z_offset` above
/// it).
fn probe(fw: &K, truth: &K, xy: [f64; 2], z_offset: f64) -> [f64; 3] {
    let mut z = z_offset;
    for _ in 0..50 {
        let s = fw.stable([xy[0], xy[1], z]);
        let step = truth.position_from_stable(s)[2] - z_offset;
        z -= step;
        if step.abs() < 1e-13 {
            break;
        }
    }
    fw.stable([xy[0], xy[1], z])
}

/// A printer.cfg of `fw` with saved results (heights, distances).
fn config(fw: &K, heights: &[(f64, [f64; 3])], distances: &[(f64, [f64; 3], [f64; 3])]) -> String {
    let mut s = format!(
        "# A rotary delta (test)\n[printer]\nkinematics: rotary_delta\nmax_velocity: 300\nmax_accel: 3000\n\
         shoulder_radius: {}\nshoulder_height: {}\n\n",
        fw.shoulder_radius, fw.shoulder_height
    );
    for (i, t) in ["a", "b", "c"].iter().enumerate() {
        s.push_str(&format!(
            "[stepper_{t}]\nstep_pin: P{i}\nmicrosteps: 16\ngear_ratio: {GEAR}\nangle: {}\n\
             upper_arm_length: {}\nlower_arm_length: {}\nposition_endstop: {}\n\n",
            fw.angles[i], fw.upper[i], fw.lower[i], fw.endstops[i]
        ));
    }
    s.push_str("[delta_calibrate]\nradius: 60\n\n#*# <---------------------- SAVE_CONFIG ---------------------->\n#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n#*# [delta_calibrate]\n");
    for (k, (h, p)) in heights.iter().enumerate() {
        s.push_str(&format!(
            "#*# height{k} = {h}\n#*# height{k}_pos = {:.9},{:.9},{:.9}\n",
            p[0], p[1], p[2]
        ));
    }
    for (k, (d, a, b)) in distances.iter().enumerate() {
        s.push_str(&format!(
            "#*# distance{k} = {d:.12}\n#*# distance{k}_pos1 = {:.9},{:.9},{:.9}\n#*# distance{k}_pos2 = {:.9},{:.9},{:.9}\n",
            a[0], a[1], a[2], b[0], b[1], b[2]
        ));
    }
    s
}

/// Read a configuration text as `pkmcal klipper` does.
fn read(dir: &Path, text: &str) -> pkmcal_io::Result<RotaryPrinter> {
    let path = dir.join("printer.cfg");
    std::fs::write(&path, text).unwrap();
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let (text, ini) = read_config(&run, &path)?;
    assert!(is_rotary(&ini));
    RotaryPrinter::from_parsed(&path, text, ini, Weighting::Klipper)
}

/// Klipper's geometry in a configuration (re-read, as Klipper restarts).
fn geometry(dir: &Path, text: &str) -> K {
    let p = read(dir, text).expect("re-read");
    let d = &p.delta;
    K {
        shoulder_radius: d.shoulder_radius,
        shoulder_height: d.shoulder_height,
        angles: d.angles,
        upper: d.upper_arms,
        lower: d.lower_arms,
        endstops: d.endstops,
        step: d.step_angles[0],
    }
}

/// Fit as `pkmcal klipper` does; the written configuration.
fn fit(p: &RotaryPrinter, free: Option<&str>) -> String {
    let mut request = Request::new(pkmcal::Model::Exact);
    request.free = free.map(Request::names);
    let cal = firmware::calibrate(p, request).expect("fit");
    let c = cal.calibration();
    p.updated(cal.mech.spec(), &c.params, &c.measurement)
        .expect("written")
}

fn truth_within_klippers_four() -> K {
    K {
        shoulder_height: 400.6,
        endstops: [241.1, 239.3, 240.5],
        ..nominal()
    }
}

#[test]
fn klippers_kinematics_are_pkmcals_over_the_build_volume() {
    let dir = tempfile::tempdir().unwrap();
    let odd = K {
        shoulder_radius: 36.2,
        angles: [30.4, 149.1, 271.0],
        upper: [165.3, 164.8, 165.1],
        lower: [314.6, 315.5, 315.2],
        endstops: [241.0, 239.5, 240.2],
        ..nominal()
    };
    for k in [nominal(), odd] {
        let heights: Vec<(f64, [f64; 3])> = probe_points(60.0, 0)
            .iter()
            .map(|p| (0.0, k.stable([p[0], p[1], 0.0])))
            .collect();
        let p = read(dir.path(), &config(&k, &heights, &[])).unwrap();
        let mech = p.mechanism().unwrap();
        let nominal = Params::nominal(mech.spec());
        let mut worst: f64 = 0.0;
        for z in [0.0, 30.0, 80.0] {
            for i in -5..=5 {
                for j in -5..=5 {
                    let (x, y) = (12.0 * i as f64, 12.0 * j as f64);
                    if x.hypot(y) > 60.0 {
                        continue;
                    }
                    // Klipper's arm angles for the point; pkmcal's motors
                    // turn the other way.
                    let c: Vec<f64> = (0..3).map(|a| -k.angle(a, [x, y, z])).collect();
                    let pr =
                        pkmcal::predict(&mech, &nominal, &c, pkmcal::Model::Exact, &[]).unwrap();
                    let back = k.cartesian([-c[0], -c[1], -c[2]]);
                    for a in 0..3 {
                        worst = worst.max((pr.x[a] - [x, y, z][a]).abs());
                        worst = worst.max((back[a] - [x, y, z][a]).abs());
                    }
                }
            }
        }
        assert!(worst < SAME_MM, "{k:?}: {worst:e} mm");
        // The saved stable positions are the commands Klipper's own
        // positions give.
        let r = p.readings(mech.spec()).unwrap();
        for (m, (_, s)) in r.poses.iter().zip(&heights) {
            let pr =
                pkmcal::predict(&mech, &nominal, &m.commands, pkmcal::Model::Exact, &[]).unwrap();
            let q = k.position_from_stable(*s);
            for a in 0..3 {
                assert!((pr.x[a] - q[a]).abs() < SAME_MM, "{pr:?} {q:?}");
            }
        }
    }
}

#[test]
fn probe_results_of_a_known_printer_give_it_back() {
    let dir = tempfile::tempdir().unwrap();
    let (fw, truth) = (nominal(), truth_within_klippers_four());
    let z_offset = 1.25;
    let pts = probe_points(60.0, 0);
    let heights: Vec<(f64, [f64; 3])> = pts
        .iter()
        .map(|p| (z_offset, probe(&fw, &truth, *p, z_offset)))
        .collect();
    let text = config(&fw, &heights, &[]);
    let p = read(dir.path(), &text).unwrap();
    let written = fit(&p, None);
    let new = geometry(dir.path(), &written);
    assert!(
        (new.shoulder_height - truth.shoulder_height).abs() < RECOVERED,
        "{new:?}"
    );
    for i in 0..3 {
        assert!(
            (new.endstops[i] - truth.endstops[i]).abs() < RECOVERED,
            "{new:?}"
        );
    }
    // With the written values Klipper puts every probe result at its height.
    for (h, s) in &heights {
        let z = new.position_from_stable(*s)[2];
        assert!((z - h).abs() < RECOVERED, "{z} against {h}");
    }
    // Klipper's keys in its SAVE_CONFIG block, the regular part's
    // definitions commented out, nothing else touched.
    assert!(written.contains("\n#shoulder_height: 400\n"), "{written}");
    assert!(
        written.contains(
            "#*# [printer]\n#*# shoulder_radius = 35.000000\n#*# shoulder_height = 400.6"
        )
    );
    assert!(!written.contains("upper_arm_length = "), "{written}");
    let kept: Vec<&str> = text
        .lines()
        .filter(|l| {
            !l.contains("shoulder_") && !l.contains("position_endstop") && !l.starts_with("angle")
        })
        .collect();
    for l in kept {
        assert!(written.lines().any(|w| w == l), "`{l}` lost");
    }
}

/// Klipper's `delta_errorfunc` (its `z_weight` for `probed` probe
/// results).
fn klippers_error(
    k: &K,
    heights: &[(f64, [f64; 3])],
    distances: &[(f64, [f64; 3], [f64; 3])],
    probed: usize,
) -> f64 {
    let z_weight = if distances.is_empty() {
        1.0
    } else {
        distances.len() as f64 / (0.5 * probed as f64)
    };
    let mut total = 0.0;
    for (h, s) in heights {
        total += (k.position_from_stable(*s)[2] - h).powi(2);
    }
    total *= z_weight;
    for (d, a, b) in distances {
        let (p, q) = (k.position_from_stable(*a), k.position_from_stable(*b));
        let dist = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
        total += (dist - d).powi(2);
    }
    if total.is_nan() {
        9999999999999.9
    } else {
        total
    }
}

/// Klipper's `coordinate_descent` from `start` on the parameters `adj`
/// (`mathutil.py`): the parameters it ends at, their error, its rounds.
fn klippers_fit(start: &K, adj: &[&str], error: &dyn Fn(&K) -> f64) -> (K, f64, usize) {
    fn slot<'a>(k: &'a mut K, n: &str) -> &'a mut f64 {
        match n {
            "shoulder_height" => &mut k.shoulder_height,
            "shoulder_radius" => &mut k.shoulder_radius,
            "endstop_a" => &mut k.endstops[0],
            "endstop_b" => &mut k.endstops[1],
            "endstop_c" => &mut k.endstops[2],
            "angle_a" => &mut k.angles[0],
            "angle_b" => &mut k.angles[1],
            _ => unreachable!(),
        }
    }
    let mut k = start.clone();
    let mut dp = vec![1.0; adj.len()];
    let mut best = error(&k);
    let mut rounds = 0;
    while dp.iter().sum::<f64>() > 0.00001 && rounds < 10000 {
        rounds += 1;
        for (n, name) in adj.iter().enumerate() {
            let orig = *slot(&mut k, name);
            for v in [orig + dp[n], orig - dp[n]] {
                *slot(&mut k, name) = v;
                let e = error(&k);
                if e < best {
                    best = e;
                    break;
                }
                *slot(&mut k, name) = orig;
            }
            if *slot(&mut k, name) != orig {
                dp[n] *= 1.1;
            } else {
                dp[n] *= 0.9;
            }
        }
    }
    (k, best, rounds)
}

#[test]
fn the_default_fit_is_klippers_own() {
    let dir = tempfile::tempdir().unwrap();
    // A printer whose radius and arm angles are off too: Klipper's four
    // parameters cannot explain its heights; both fits look for the best
    // four.
    let fw = nominal();
    let truth = K {
        shoulder_radius: 35.5,
        angles: [30.3, 149.8, 270.0],
        ..truth_within_klippers_four()
    };
    let heights: Vec<(f64, [f64; 3])> = probe_points(60.0, 0)
        .iter()
        .map(|p| (0.5, probe(&fw, &truth, *p, 0.5)))
        .collect();
    let p = read(dir.path(), &config(&fw, &heights, &[])).unwrap();
    let ours = geometry(dir.path(), &fit(&p, None));
    let adj = ["shoulder_height", "endstop_a", "endstop_b", "endstop_c"];
    let error = |k: &K| klippers_error(k, &heights, &[], heights.len());
    // Klipper's own descent, started where pkmcal ended, finds nothing
    // better: pkmcal's values are its answer (to the 6 decimals written).
    let (kept, kept_error, _) = klippers_fit(&ours, &adj, &error);
    assert!(
        kept_error >= error(&ours) - 1e-12,
        "{kept_error} {}",
        error(&ours)
    );
    assert!(
        (kept.shoulder_height - ours.shoulder_height).abs() < 1e-5,
        "{kept:?}\n{ours:?}"
    );
    for i in 0..3 {
        assert!(
            (kept.endstops[i] - ours.endstops[i]).abs() < 1e-5,
            "{kept:?}\n{ours:?}"
        );
    }
    // Started from the configuration, as Klipper runs it, it crawls along
    // the valley where the shoulder height and the endstops trade, and
    // stops no lower.
    let (_, klipper_error, _) = klippers_fit(&fw, &adj, &error);
    assert!(
        error(&ours) <= klipper_error + 1e-12,
        "{} {klipper_error}",
        error(&ours)
    );
}

/// Distances between pairs of bed points, as `DELTA_ANALYZE` saves them:
/// the true distance and both stable positions.
fn distances(fw: &K, truth: &K) -> Vec<(f64, [f64; 3], [f64; 3])> {
    (0..12)
        .map(|k| {
            let a = (30.0 * k as f64).to_radians();
            let (r1, r2) = (4.5, if k % 2 == 0 { 69.5 } else { 40.0 });
            let (p, q) = (
                [r1 * a.cos(), r1 * a.sin(), 0.0],
                [r2 * a.cos(), r2 * a.sin(), 0.0],
            );
            let (s1, s2) = (fw.stable(p), fw.stable(q));
            let (t1, t2) = (
                truth.position_from_stable(s1),
                truth.position_from_stable(s2),
            );
            let d = ((t1[0] - t2[0]).powi(2) + (t1[1] - t2[1]).powi(2) + (t1[2] - t2[2]).powi(2))
                .sqrt();
            (d, s1, s2)
        })
        .collect()
}

#[test]
fn distances_free_the_radius_and_two_angles_as_klipper_does() {
    let dir = tempfile::tempdir().unwrap();
    let fw = nominal();
    let truth = K {
        shoulder_radius: 35.4,
        angles: [30.25, 149.85, 270.0],
        ..truth_within_klippers_four()
    };
    let heights: Vec<(f64, [f64; 3])> = probe_points(60.0, 0)
        .iter()
        .map(|p| (0.5, probe(&fw, &truth, *p, 0.5)))
        .collect();
    let d = distances(&fw, &truth);
    let p = read(dir.path(), &config(&fw, &heights, &d)).unwrap();
    let written = fit(&p, None);
    let new = geometry(dir.path(), &written);
    assert!(
        (new.shoulder_radius - truth.shoulder_radius).abs() < RECOVERED,
        "{new:?}"
    );
    assert!(
        (new.shoulder_height - truth.shoulder_height).abs() < RECOVERED,
        "{new:?}"
    );
    for i in 0..3 {
        assert!(
            (new.angles[i] - truth.angles[i]).abs() < RECOVERED,
            "{new:?}"
        );
        assert!(
            (new.endstops[i] - truth.endstops[i]).abs() < RECOVERED,
            "{new:?}"
        );
    }
}

#[test]
fn arm_lengths_and_the_third_angle_come_back_from_enough_heights() {
    let dir = tempfile::tempdir().unwrap();
    let fw = nominal();
    let truth = K {
        upper: [165.4, 164.7, 165.0],
        lower: [315.3, 314.8, 315.0],
        ..truth_within_klippers_four()
    };
    let heights: Vec<(f64, [f64; 3])> = probe_points(60.0, 40)
        .iter()
        .map(|p| (0.5, probe(&fw, &truth, *p, 0.5)))
        .collect();
    let text = config(&fw, &heights, &[]);
    let p = read(dir.path(), &text).unwrap();
    let written = fit(&p, Some("default,la1,la2,la3,lf1,lf2,lf3"));
    let new = geometry(dir.path(), &written);
    // Every height put back on the bed; the arm lengths written, all three
    // of each.
    for (h, s) in &heights {
        let z = new.position_from_stable(*s)[2];
        assert!((z - h).abs() < 1e-4, "{z} against {h}: {new:?}");
    }
    assert_eq!(
        written.matches("upper_arm_length = ").count(),
        3,
        "{written}"
    );
    assert_eq!(
        written.matches("lower_arm_length = ").count(),
        3,
        "{written}"
    );
}

#[test]
fn a_fit_klipper_cannot_hold_is_not_written() {
    let dir = tempfile::tempdir().unwrap();
    let (fw, truth) = (nominal(), truth_within_klippers_four());
    let heights: Vec<(f64, [f64; 3])> = probe_points(60.0, 20)
        .iter()
        .map(|p| (0.5, probe(&fw, &truth, *p, 0.5)))
        .collect();
    let p = read(dir.path(), &config(&fw, &heights, &[])).unwrap();
    let mut request = Request::new(pkmcal::Model::Exact);
    request.free = Some(Request::names("default,arm1.px"));
    let cal = firmware::calibrate(&p, request).expect("fit");
    let c = cal.calibration();
    let e = p
        .updated(cal.mech.spec(), &c.params, &c.measurement)
        .unwrap_err();
    assert!(e.to_string().contains("`arm1.px`"), "{e}");
}

#[test]
fn bad_configurations_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let fw = nominal();
    let heights: Vec<(f64, [f64; 3])> = probe_points(60.0, 0)
        .iter()
        .map(|p| (0.0, fw.stable([p[0], p[1], 0.0])))
        .collect();
    let good = config(&fw, &heights, &[]);
    assert!(read(dir.path(), &good).is_ok());
    for (from, to, needle) in [
        (
            "gear_ratio: 80:16, 60:15\nangle: 30",
            "angle: 30",
            "[stepper_a] needs `gear_ratio`",
        ),
        (
            "gear_ratio: 80:16, 60:15\nangle: 150",
            "rotation_distance: 40\ngear_ratio: 80:16, 60:15\nangle: 150",
            "printer.cfg:21: [stepper_b] rotation_distance",
        ),
        (
            "shoulder_radius: 35\n",
            "",
            "[printer] needs a positive `shoulder_radius`",
        ),
        (
            "shoulder_height: 400\n",
            "shoulder_height: -400\n",
            "[printer] shoulder_height = -400 mm must be positive",
        ),
        (
            "position_endstop: 240\n\n[stepper_b]",
            "position_endstop: 900\n\n[stepper_b]",
            "cannot put the effector at the centre at position_endstop = 900",
        ),
        (
            "#*# height3_pos = ",
            "#*# height3_pos = 9e9,",
            "must be three numbers",
        ),
        ("#*# height4 = 0", "#*# height4 = nan", "must be finite"),
        (
            "gear_ratio: 80:16, 60:15\nangle: 270",
            "gear_ratio: 80:0\nangle: 270",
            "gear_ratio = `80:0`",
        ),
    ] {
        assert!(good.contains(from), "{from}");
        let bad = good.replacen(from, to, 1);
        let e = read(dir.path(), &bad)
            .err()
            .unwrap_or_else(|| panic!("{to} read"));
        assert!(e.to_string().contains(needle), "{to}: {e}");
    }
    // Fewer probe results than Klipper's four parameters.
    let cut = good.split("#*# height3 ").next().unwrap().to_string();
    let e = read(dir.path(), &cut).err().unwrap();
    assert!(e.to_string().contains("holds 3 probe results"), "{e}");
}
