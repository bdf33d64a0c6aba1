//! Klipper's rotary delta (`kinematics: rotary_delta`): a `printer.cfg`
//! read as Klipper reads it, the printer and its saved probe results, and
//! the values written back in Klipper's keys.
//!
//! Klipper's rotary delta (`rotary_delta.py`, `kin_rotary_delta.c`): arm
//! `i` turns in the vertical plane at `angle` (degrees; 30, 150, 270 by
//! default) about a shoulder `shoulder_radius` from the centre (the
//! effector's joint radius already taken off) and `shoulder_height` above
//! the bed; its upper arm (`upper_arm_length`) ends in an elbow, from which
//! the lower arm (`lower_arm_length`) reaches the effector. A shoulder
//! angle is measured up from the horizontal, outward. At the endstop the
//! arm's angle is the one that puts the effector at `(0, 0,
//! position_endstop)`; a stable position counts the steps from there, each
//! `2π / (full_steps_per_rotation · microsteps · gear_ratio)` (its step
//! angle). `DELTA_CALIBRATE` saves the probed heights with the stable
//! positions and fits `shoulder_height` and the three endstops
//! (`shoulder_radius` and two angles more with `DELTA_ANALYZE`'s
//! distances).
//!
//! Here that printer is the rotary delta of `examples/rotary-delta`, in its
//! names: arms `arm1 arm2 arm3` (= `[stepper_a]`, `[stepper_b]`,
//! `[stepper_c]`) at the leg angles `arm1.angle …` (rad), motors `q1 q2 q3`
//! on the circle `rb` (= `shoulder_radius`) at the height `hb`
//! (= `shoulder_height`), upper arms `la1 la2 la3`, forearms `lf1 lf2 lf3`;
//! a motor's angle is positive down (`q = −` Klipper's shoulder angle), its
//! encoder offset `dq1 …` (rad) the error of the arm's angle at the
//! endstop.

use super::klipper::{
    Distance, Ini, Probe, Weighting, saved_results, steps_per_rotation, updated_config_values,
    z_weight,
};
use super::{Firmware, FirmwareValue, Readings, Separation, TiltPlace};
use crate::error::{Error, Result};
use crate::{invalid, refuse};
use pkmcal::{Params, Request};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Klipper's default arm angles (degrees).
pub const DEFAULT_ANGLES: [f64; 3] = [30.0, 150.0, 270.0];

/// The steppers' suffixes (`[stepper_a]` …).
const STEPPERS: [&str; 3] = ["a", "b", "c"];

/// Klipper's parameter set for probe heights alone: `shoulder_height` and
/// the three endstops.
pub const ROTARY_FREE: [&str; 4] = ["hb", "dq1", "dq2", "dq3"];

/// What Klipper adds with the calibration object's distances:
/// `shoulder_radius` and two arm angles.
pub const ROTARY_EXTENDED: [&str; 3] = ["rb", "arm1.angle", "arm2.angle"];

/// The description's parameters Klipper's configuration holds; any other
/// (an arm's shoulder position, a motor shaft's tilt) has no place in it.
fn holds(name: &str) -> bool {
    matches!(
        name,
        "rb" | "hb"
            | "la1"
            | "la2"
            | "la3"
            | "lf1"
            | "lf2"
            | "lf3"
            | "arm1.angle"
            | "arm2.angle"
            | "arm3.angle"
            | "dq1"
            | "dq2"
            | "dq3"
    )
}

/// Stiffness written for the motors (N·m/rad): a rotary delta is not
/// redundant, so it changes no prediction without a load.
const MOTOR_STIFFNESS: f64 = 800.0;

/// The height (mm) of the reference pose over the bed.
const REFERENCE_HEIGHT_MM: f64 = 10.0;

/// A Klipper rotary delta: its geometry and its saved probe results.
#[derive(Debug, Clone)]
pub struct RotaryDelta {
    /// `shoulder_radius` (mm).
    pub shoulder_radius: f64,
    /// `shoulder_height` (mm).
    pub shoulder_height: f64,
    /// Arm `angle`s (degrees).
    pub angles: [f64; 3],
    /// `upper_arm_length`s (mm).
    pub upper_arms: [f64; 3],
    /// `lower_arm_length`s (mm).
    pub lower_arms: [f64; 3],
    /// `position_endstop`s (mm).
    pub endstops: [f64; 3],
    /// Step angles (rad): `2π / (full_steps · microsteps · gear ratio)`.
    pub step_angles: [f64; 3],
    /// `[delta_calibrate] radius` (mm): the probed circle.
    pub probe_radius: f64,
    /// The saved probe results.
    pub probes: Vec<Probe>,
    /// The saved distances measured on the calibration object.
    pub distances: Vec<Distance>,
}

impl RotaryDelta {
    /// The shoulder angle (rad, up from the horizontal) of arm `i` with the
    /// effector at `p`: Klipper's `rotary_stepper_calc_position` (NaN out
    /// of reach).
    pub fn arm_angle(&self, i: usize, p: [f64; 3]) -> f64 {
        let (s, c) = self.angles[i].to_radians().sin_cos();
        // The effector in the shoulder's frame: x out along the arm, y up,
        // z across.
        let sjz = p[1] * c - p[0] * s;
        let dx = p[0] * c + p[1] * s - self.shoulder_radius;
        let dy = p[2] - self.shoulder_height;
        let ua2 = self.upper_arms[i] * self.upper_arms[i];
        let la2 = self.lower_arms[i] * self.lower_arms[i] - sjz * sjz;
        // `rotary_two_arm_calc`.
        let inv_dy = 1.0 / dy;
        let c1 = 0.5 * inv_dy * (dx * dx + dy * dy + ua2 - la2);
        let c2 = dx * inv_dy;
        let scale = c2 * c2 + 1.0;
        let ex = c1 * c2 + (scale * ua2 - c1 * c1).sqrt();
        let ey = c1 * scale - c2 * ex;
        ey.atan2(ex)
    }

    /// The shoulder angle of arm `i` at its endstop (rad).
    pub fn endstop_angle(&self, i: usize) -> f64 {
        self.arm_angle(i, [0.0, 0.0, self.endstops[i]])
    }

    /// The shoulder angles (rad) of a stable position (steps from each
    /// endstop).
    pub fn shoulder_angles(&self, steps: &[f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| self.endstop_angle(i) - steps[i] * self.step_angles[i])
    }

    /// The motor angles (rad, positive down: the description's commands) of
    /// a stable position.
    pub fn commands(&self, steps: &[f64; 3]) -> [f64; 3] {
        self.shoulder_angles(steps).map(|a| -a)
    }

    /// The elbow of arm `i` at the shoulder angle `a` (Klipper's
    /// `elbow_coord`).
    pub fn elbow(&self, i: usize, a: f64) -> [f64; 3] {
        let (x, y) = (self.upper_arms[i] * a.cos(), self.upper_arms[i] * a.sin());
        let (s, c) = self.angles[i].to_radians().sin_cos();
        [
            (x + self.shoulder_radius) * c,
            (x + self.shoulder_radius) * s,
            y + self.shoulder_height,
        ]
    }

    /// The height (mm) of the effector at the centre with arm `i` at the
    /// shoulder angle `a`: the elbow's height less the lower arm's drop.
    fn centre_height(&self, i: usize, a: f64) -> f64 {
        let reach = self.upper_arms[i] * a.cos() + self.shoulder_radius;
        self.shoulder_height + self.upper_arms[i] * a.sin()
            - (self.lower_arms[i].powi(2) - reach * reach).sqrt()
    }

    /// The spatial description of this printer (TOML), in the names of
    /// `examples/rotary-delta`.
    pub fn mechanism_toml(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# A rotary delta printer read from a Klipper printer.cfg by `pkmcal klipper`\n\
             # (arms 1, 2, 3 = [stepper_a], [stepper_b], [stepper_c]; commands are the\n\
             # motors' angles in rad, positive down: minus Klipper's shoulder angles;\n\
             # dq1, dq2, dq3 are the arms' angle errors at their endstops; rb and hb\n\
             # are Klipper's shoulder_radius and shoulder_height).\n\
             type = \"spatial\"\nname = \"Rotary delta printer (from Klipper)\"\n\
             free = [{}]\n\n[platform]\nmotion = \"translation\"\n",
            ROTARY_FREE.map(|n| format!("\"{n}\"")).join(", ")
        );
        for i in 0..3 {
            let n = i + 1;
            let _ = writeln!(
                s,
                "[[leg]]\nname = \"arm{n}\"\nangle = {:?}   # {}°\n[[leg.joint]]\n\
                 name = \"q{n}\"\nkind = \"revolute\"\nat = [\"rb\", 0.0, \"hb\"]\n\
                 axis = [0.0, 1.0, 0.0]\nactuated = true\nstiffness = {MOTOR_STIFFNESS:?}   # N·m/rad\n\
                 [leg.end]\nkind = \"rod\"\nat = [\"la{n}\", 0.0, 0.0]\nlength = \"lf{n}\"\n\
                 platform = [0.0, 0.0, 0.0]\n",
                self.angles[i].to_radians(),
                self.angles[i]
            );
        }
        let _ = writeln!(
            s,
            "[parameters]\nrb = {:?}\nhb = {:?}",
            self.shoulder_radius, self.shoulder_height
        );
        for i in 0..3 {
            let _ = writeln!(s, "la{} = {:?}", i + 1, self.upper_arms[i]);
        }
        for i in 0..3 {
            let _ = writeln!(s, "lf{} = {:?}", i + 1, self.lower_arms[i]);
        }
        let reference = [0.0, 0.0, REFERENCE_HEIGHT_MM];
        let _ = writeln!(s, "\n[assembly]\npose = {reference:?}");
        for i in 0..3 {
            let _ = writeln!(s, "q{} = {:?}", i + 1, -self.arm_angle(i, reference));
        }
        let r = (1.1 * self.probe_radius).max(10.0);
        let _ = writeln!(
            s,
            "\n[workspace]   # the probed region\nx = [{:?}, {r:?}]\ny = [{:?}, {r:?}]\nz = [-10.0, 50.0]",
            -r, -r
        );
        s
    }

    /// Klipper's values for identified parameters of the description: the
    /// geometry as named, and each endstop where the arm's angle at it,
    /// corrected by its error, puts the effector with the new geometry.
    pub fn identified(&self, spec: &pkmcal::Spec, p: &Params) -> Result<RotaryDelta> {
        let mut out = self.clone();
        out.shoulder_radius = p.get(spec, "rb")?;
        out.shoulder_height = p.get(spec, "hb")?;
        for i in 0..3 {
            let n = i + 1;
            out.angles[i] = p.get(spec, &format!("arm{n}.angle"))?.to_degrees();
            out.upper_arms[i] = p.get(spec, &format!("la{n}"))?;
            out.lower_arms[i] = p.get(spec, &format!("lf{n}"))?;
        }
        for (i, stepper) in STEPPERS.iter().enumerate() {
            let n = i + 1;
            let at_endstop = self.endstop_angle(i) - p.get(spec, &format!("dq{n}"))?;
            out.endstops[i] = out.centre_height(i, at_endstop);
            let sound = out.endstops[i].is_finite()
                && out.shoulder_radius > 0.0
                && out.shoulder_height > 0.0
                && out.upper_arms[i] > 0.0
                && out.lower_arms[i] > 0.0;
            if !sound {
                invalid!(
                    "the identified geometry of arm {n} ([stepper_{stepper}]) does not reach the centre at its endstop (shoulder_radius {:.3}, shoulder_height {:.3}, upper arm {:.3}, lower arm {:.3} mm); the probe data cannot support this parameter set (use fewer free parameters)",
                    out.shoulder_radius,
                    out.shoulder_height,
                    out.upper_arms[i],
                    out.lower_arms[i]
                );
            }
        }
        Ok(out)
    }

    /// The values `klipper` writes: (section, option, value), in the order
    /// Klipper's `SAVE_CONFIG` writes them; the arm lengths only where one
    /// of them changed from `old` (then all three, so that no stepper falls
    /// back on `[stepper_a]`'s).
    fn values(&self, old: &RotaryDelta) -> Vec<(String, String, String)> {
        let v = |x: f64| format!("{x:.6}");
        let mut out: Vec<(String, String, String)> = vec![
            (
                "printer".into(),
                "shoulder_radius".into(),
                v(self.shoulder_radius),
            ),
            (
                "printer".into(),
                "shoulder_height".into(),
                v(self.shoulder_height),
            ),
        ];
        let upper = self.upper_arms != old.upper_arms;
        let lower = self.lower_arms != old.lower_arms;
        for (i, t) in STEPPERS.iter().enumerate() {
            let s = format!("stepper_{t}");
            out.push((s.clone(), "angle".into(), v(self.angles[i])));
            out.push((s.clone(), "position_endstop".into(), v(self.endstops[i])));
            if upper {
                out.push((s.clone(), "upper_arm_length".into(), v(self.upper_arms[i])));
            }
            if lower {
                out.push((s, "lower_arm_length".into(), v(self.lower_arms[i])));
            }
        }
        out
    }
}

/// Whether a configuration is a rotary delta (`[printer] kinematics:
/// rotary_delta`).
pub fn is_rotary(ini: &Ini) -> bool {
    ini.get("printer", "kinematics")
        .is_some_and(|e| e.value.trim() == "rotary_delta")
}

/// The rotary delta of a configuration, as Klipper reads it.
pub fn rotary_from_config(ini: &Ini) -> Result<RotaryDelta> {
    if !is_rotary(ini) {
        refuse!(ini.file, None, "[printer] kinematics is not `rotary_delta`");
    }
    let need = |section: &str, key: &str, what: &str| -> Result<f64> {
        match ini.length(section, key, true)? {
            Some(v) => Ok(v),
            None => refuse!(
                ini.file,
                None,
                "[{section}] needs a positive `{key}` ({what}; Klipper's own rule)"
            ),
        }
    };
    let shoulder_radius = need(
        "printer",
        "shoulder_radius",
        "the shoulders' circle less the effector joints' (mm)",
    )?;
    let shoulder_height = need(
        "printer",
        "shoulder_height",
        "the shoulders' height over the bed (mm)",
    )?;
    let upper_a = need("stepper_a", "upper_arm_length", "mm")?;
    let lower_a = need("stepper_a", "lower_arm_length", "mm")?;
    let Some(end_a) = ini.length("stepper_a", "position_endstop", false)? else {
        refuse!(ini.file, None, "[stepper_a] needs `position_endstop`");
    };
    let mut d = RotaryDelta {
        shoulder_radius,
        shoulder_height,
        angles: DEFAULT_ANGLES,
        upper_arms: [upper_a; 3],
        lower_arms: [lower_a; 3],
        endstops: [end_a; 3],
        step_angles: [0.0; 3],
        probe_radius: shoulder_radius,
        probes: vec![],
        distances: vec![],
    };
    for (i, t) in STEPPERS.iter().enumerate() {
        let s = format!("stepper_{t}");
        if !ini.has_section(&s) {
            refuse!(ini.file, None, "the configuration has no [{s}] section");
        }
        if let Some(a) = ini.number(&s, "angle")? {
            d.angles[i] = a;
        }
        if let Some(a) = ini.length(&s, "upper_arm_length", true)? {
            d.upper_arms[i] = a;
        }
        if let Some(a) = ini.length(&s, "lower_arm_length", true)? {
            d.lower_arms[i] = a;
        }
        if let Some(e) = ini.length(&s, "position_endstop", false)? {
            d.endstops[i] = e;
        }
        if let Some(e) = ini.get(&s, "rotation_distance") {
            refuse!(
                e.file,
                Some(e.line as u64),
                "[{s}] rotation_distance: a rotary delta's arm turns a full circle per rotation of its last gear, and Klipper takes its step angle from gear_ratio alone (and refuses rotation_distance here); remove it"
            );
        }
        if ini.get(&s, "gear_ratio").is_none() {
            refuse!(
                ini.file,
                None,
                "[{s}] needs `gear_ratio` (the motor's turns per turn of the arm, `a:b` pairs; Klipper's own rule for a rotary delta)"
            );
        }
        d.step_angles[i] = std::f64::consts::TAU / steps_per_rotation(ini, &s)?;
        if !d.endstop_angle(i).is_finite() {
            let e = ini
                .get(&s, "position_endstop")
                .or_else(|| ini.get("stepper_a", "position_endstop"))
                .expect("a position_endstop was read");
            refuse!(
                e.file,
                Some(e.line as u64),
                "[{s}]: the arm cannot put the effector at the centre at position_endstop = {} (shoulder_radius {shoulder_radius}, shoulder_height {shoulder_height}, upper arm {}, lower arm {} mm); check these values",
                d.endstops[i],
                d.upper_arms[i],
                d.lower_arms[i]
            );
        }
    }
    if let Some(r) = ini.number("delta_calibrate", "radius")? {
        d.probe_radius = r;
    }
    (d.probes, d.distances) = saved_results(ini)?;
    if d.probes.len() < ROTARY_FREE.len() {
        refuse!(
            ini.file,
            None,
            "[delta_calibrate] holds {} probe results (height0, height0_pos, …); at least {} are needed: run DELTA_CALIBRATE in Klipper, then SAVE_CONFIG, and read the saved printer.cfg",
            d.probes.len(),
            ROTARY_FREE.len()
        );
    }
    Ok(d)
}

/// A Klipper rotary delta: its configuration's text and path, as read,
/// and the weighting of its heights against its calibration object's
/// distances.
pub struct RotaryPrinter {
    /// The configuration file.
    pub path: PathBuf,
    /// Its text.
    pub text: String,
    /// Its options, as Klipper reads them.
    pub ini: Ini,
    /// The printer.
    pub delta: RotaryDelta,
    /// How heights and distances are weighed.
    pub weighting: Weighting,
}

impl RotaryPrinter {
    /// A `printer.cfg` read ([`super::klipper::read_config`]), as Klipper
    /// reads it. A saved probe result or distance whose stable position the
    /// geometry cannot reach is refused by name.
    pub fn from_parsed(path: &Path, text: String, ini: Ini, weighting: Weighting) -> Result<Self> {
        let delta = rotary_from_config(&ini)?;
        let printer = RotaryPrinter {
            path: path.to_path_buf(),
            text,
            ini,
            delta,
            weighting,
        };
        let d = &printer.delta;
        let reach = |steps: &[f64; 3]| -> bool {
            let a = d.shoulder_angles(steps);
            let e: [[f64; 3]; 3] = std::array::from_fn(|i| d.elbow(i, a[i]));
            trilaterate(e, d.lower_arms).is_some()
        };
        for p in &d.probes {
            if !reach(&p.steps) {
                invalid!(
                    "`{}` of {}: the arms at the stable position {:?} cannot meet at the effector with the configuration's geometry; check the saved probe results and the arm lengths",
                    p.name,
                    path.display(),
                    p.steps
                );
            }
        }
        for x in &d.distances {
            if !x.steps.iter().all(reach) {
                invalid!(
                    "`{}` of {}: the arms at its stable positions cannot meet at the effector with the configuration's geometry; check the saved distances and the arm lengths",
                    x.name,
                    path.display()
                );
            }
        }
        Ok(printer)
    }

    /// Klipper's weight of the heights against the distances.
    pub fn z_weight(&self) -> f64 {
        z_weight(&self.delta.probes, &self.delta.distances)
    }
}

/// The point `lower_arms[i]` from each elbow, below them (Klipper's
/// `trilateration`); `None` where the spheres do not meet.
pub fn trilaterate(elbows: [[f64; 3]; 3], lower_arms: [f64; 3]) -> Option<[f64; 3]> {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mul = |a: [f64; 3], s: f64| [a[0] * s, a[1] * s, a[2] * s];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let r2 = lower_arms.map(|l| l * l);
    let s21 = sub(elbows[1], elbows[0]);
    let s31 = sub(elbows[2], elbows[0]);
    let d = dot(s21, s21).sqrt();
    let ex = mul(s21, 1.0 / d);
    let i = dot(ex, s31);
    let v = sub(s31, mul(ex, i));
    let ey = mul(v, 1.0 / dot(v, v).sqrt());
    let ez = cross(ex, ey);
    let j = dot(ey, s31);
    let x = (r2[0] - r2[1] + d * d) / (2.0 * d);
    let y = (r2[0] - r2[2] - x * x + (x - i).powi(2) + j * j) / (2.0 * j);
    let z = -(r2[0] - x * x - y * y).sqrt();
    let p: [f64; 3] = std::array::from_fn(|k| elbows[0][k] + ex[k] * x + ey[k] * y + ez[k] * z);
    p.iter().all(|v| v.is_finite()).then_some(p)
}

impl Firmware for RotaryPrinter {
    fn separation(&self) -> Separation {
        Separation::Distances
    }

    fn relative_sigma(&self, readings: &Readings) -> bool {
        // Klipper's fixed ratio is given as the readings' σ.
        self.weighting == Weighting::Klipper && !readings.distances.is_empty()
    }

    fn tilt_place(&self) -> TiltPlace {
        TiltPlace::BedMesh
    }

    fn flavour(&self) -> super::Flavour {
        super::Flavour::Klipper
    }

    fn description(&self) -> String {
        self.delta.mechanism_toml()
    }

    fn readings(&self, spec: &pkmcal::Spec) -> Result<Readings> {
        let d = &self.delta;
        super::klipper::saved_readings(
            spec,
            &d.probes,
            &d.distances,
            |steps| d.commands(steps),
            self.weighting,
            self.z_weight(),
        )
    }

    fn default_free(&self, _spec: &pkmcal::Spec, readings: &Readings) -> Vec<String> {
        let mut default: Vec<String> = ROTARY_FREE.map(String::from).to_vec();
        if !readings.distances.is_empty() {
            default.extend(ROTARY_EXTENDED.map(String::from));
        }
        default
    }

    fn configure(&self, request: &mut Request, readings: &Readings) {
        super::klipper::configure_weighting(request, readings, self.weighting, self.z_weight());
    }

    fn values(
        &self,
        spec: &pkmcal::Spec,
        params: &Params,
        _instrument: &[f64],
    ) -> Result<Vec<FirmwareValue>> {
        let new = self.delta.identified(spec, params)?;
        let old = &self.delta;
        let mut out = vec![
            FirmwareValue {
                name: "[printer] shoulder_radius".into(),
                before: old.shoulder_radius,
                after: new.shoulder_radius,
                unit: "mm",
                sigma: None,
            },
            FirmwareValue {
                name: "[printer] shoulder_height".into(),
                before: old.shoulder_height,
                after: new.shoulder_height,
                unit: "mm",
                sigma: None,
            },
        ];
        for (i, t) in STEPPERS.iter().enumerate() {
            for (key, a, b, unit) in [
                ("angle", old.angles[i], new.angles[i], "°"),
                (
                    "upper_arm_length",
                    old.upper_arms[i],
                    new.upper_arms[i],
                    "mm",
                ),
                (
                    "lower_arm_length",
                    old.lower_arms[i],
                    new.lower_arms[i],
                    "mm",
                ),
                ("position_endstop", old.endstops[i], new.endstops[i], "mm"),
            ] {
                out.push(FirmwareValue {
                    name: format!("[stepper_{t}] {key}"),
                    before: a,
                    after: b,
                    unit,
                    sigma: None,
                });
            }
        }
        Ok(out)
    }

    fn updated(&self, spec: &pkmcal::Spec, params: &Params, _instrument: &[f64]) -> Result<String> {
        // A parameter Klipper has no place for that the fit moved would be
        // lost in the written configuration.
        let nominal = Params::nominal(spec);
        if let Some((name, v, v0)) = spec
            .param_names()
            .iter()
            .zip(params.values.iter().zip(&nominal.values))
            .find(|(n, (v, v0))| !holds(n) && v != v0)
            .map(|(n, (v, v0))| (n.to_string(), *v, *v0))
        {
            invalid!(
                "`{name}` = {v:.6} (from {v0:.6}) has no place in Klipper's rotary_delta configuration (one shoulder radius and height for the three arms, no motor tilts), so the written values would not reproduce the fit; fit without it to write the configuration"
            );
        }
        let new = self.delta.identified(spec, params)?;
        updated_config_values(&self.text, &new.values(&self.delta), &self.ini)
    }

    fn located(&self, e: pkmcal::Error) -> Error {
        let name = match &e {
            pkmcal::Error::Pose {
                pose,
                distance: true,
                ..
            } => self.delta.distances.get(pose - 1).map(|d| d.name.clone()),
            pkmcal::Error::Pose { pose, .. } => {
                self.delta.probes.get(pose - 1).map(|p| p.name.clone())
            }
            _ => None,
        };
        match name {
            Some(n) => Error::from(e).context(format!("`{n}` of {}", self.path.display())),
            None => Error::from(e),
        }
    }
}
