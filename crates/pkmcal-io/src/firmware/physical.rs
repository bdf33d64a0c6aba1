//! The physical linear delta (`--physical`): the printer as it is built,
//! not the firmware's picture of it; fitted to the firmware's probe
//! readings within the tolerances of its parts, then projected onto the
//! firmware's values for the nozzle over the whole build volume.
//!
//! Every firmware describes a linear delta with a radius, three tower
//! angles, arm lengths and endstops ([`super::klipper::KlipperDelta`]). The
//! physical model ([`physical_description`]) has, for each tower, its own
//! radius `radius_a` and angle `angle_a`, its lean (`a.tilt1`, `a.tilt2`:
//! the carriage's rail tilts), and a parallelogram of two rods (`a1`, `a2`)
//! with their own lengths (`rod_a1`, `rod_a2`), hanging from two ball
//! joints on the carriage (`a1.ex …`, at ± half the rod spacing) and
//! holding two on the effector (`a1.px …`); the effector turns as well as
//! moves (`motion = "full"`), its pose solved from the six rod
//! constraints; its frame's origin is the probe's trigger point, the nozzle
//! at minus the probe's offset; the bed is the probe's plane (`bed.z`,
//! `bed.rx`, `bed.ry`). With every extra error zero it is the firmware's
//! model (tested to 1e-9 mm on each firmware).

use super::klipper::KlipperDelta;
use super::{Firmware, Readings};
use crate::description::Mech;
use crate::error::{Error, Result};
use crate::invalid;
use pkmcal::apply::budget::Tolerance;
use pkmcal::{Mechanism, Params, Request};
use std::fmt::Write as _;

/// The effector's ball joints' radius from the nozzle (mm), which no
/// firmware keeps (only the radius less it): a typical Kossel effector's.
pub const EFFECTOR_RADIUS_MM: f64 = 30.0;
/// The spacing of a parallelogram's two rods (mm), on the carriage and on
/// the effector: a typical Kossel's.
pub const ROD_SPACING_MM: f64 = 50.0;

/// Default tolerance (σ, mm) of each rod's length: rods cut to ±0.1 mm.
pub const ROD_SIGMA_MM: f64 = 0.1;
/// Default tolerance (σ, mm) of each tower's radius.
pub const TOWER_RADIUS_SIGMA_MM: f64 = 0.5;
/// Default tolerance (σ, mm) of each tower's place around the circle (its
/// angle's σ is this over the tower's radius).
pub const TOWER_PLACE_SIGMA_MM: f64 = 0.5;
/// Default tolerance (σ, rad) of each tower's lean about either axis:
/// 0.5 mm over a 500 mm rail.
pub const TOWER_LEAN_SIGMA_RAD: f64 = 0.001;
/// Default tolerance (σ, mm) of each ball joint's place, on the carriage
/// and on the effector, in each direction.
pub const JOINT_SIGMA_MM: f64 = 0.1;
/// Default tolerance (σ, rad) of the bed's tilt about x and y: 0.5 mm over
/// 250 mm.
pub const BED_TILT_SIGMA_RAD: f64 = 0.002;
/// Default noise (σ, mm) of a probe reading, where none is stated.
pub const PROBE_NOISE_MM: f64 = 0.01;
/// Default noise (σ, mm) of a distance measured on a calibration object
/// (calipers).
pub const DISTANCE_NOISE_MM: f64 = 0.02;

/// The effector's turn about each axis that the physical model's workspace
/// spans where its tool is the whole pose (rad): far beyond what parts
/// within their tolerances give.
const EFFECTOR_TURN_RAD: f64 = 0.05;

/// Heights of the build-volume grid's layers above the bed (mm).
pub const GRID_HEIGHTS_MM: [f64; 4] = [0.0, 20.0, 50.0, 100.0];
/// Points across the build-volume grid's diameter in x and in y (those
/// within its radius are kept).
pub const GRID_POINTS: usize = 9;

/// The towers in order.
const TOWERS: [&str; 3] = ["a", "b", "c"];

/// How the firmware's description names its tower angles (`angle_a` …).
const TOWER_ANGLE: &str = "angle_";

/// Stiffness written for the carriages (N/mm), as the firmware's
/// description writes it: a linear delta is not redundant, so it changes no
/// prediction without a load.
const CARRIAGE_STIFFNESS: f64 = 2000.0;

/// A firmware's linear delta as the physical model starts from it.
#[derive(Debug, Clone)]
pub struct LinearDelta {
    /// The firmware's geometry in Klipper's terms.
    pub delta: KlipperDelta,
    /// The probe's x, y offset from the nozzle (mm; 0, 0 for a probe at
    /// the nozzle).
    pub probe_offset: [f64; 2],
    /// Which firmware.
    pub firmware: super::Flavour,
    /// The parameters of the firmware's description that its values hold
    /// (what the projection fits).
    pub values: Vec<String>,
    /// Whether the firmware tilts its z with the bed's plane (RepRapFirmware's
    /// `M666 A B`): then the projection leaves the bed's tilt to it.
    pub corrects_bed_tilt: bool,
    /// The build volume's radius (mm): Klipper's `print_radius`, else the
    /// probed circle's.
    pub print_radius: f64,
    /// What the firmware's saved probe results read where the probe
    /// triggers on the bed (mm): Klipper's `z_offset`, Marlin's −`M851 Z`
    /// (the nozzle's height over the bed then), RepRapFirmware's 0. A
    /// probe's touch on a surface ([`super::physical_heights`]) reads this
    /// over the surface's height.
    pub probe_height: f64,
    /// The nozzle's height over the bed when homed (mm), the build volume's
    /// top: Klipper's lowest `position_endstop`, RepRapFirmware's and
    /// Marlin's `M665 H`.
    pub homed_height: f64,
}

impl LinearDelta {
    /// The nozzle in the effector's frame (whose origin is the probe's
    /// trigger point).
    pub fn nozzle(&self) -> [f64; 3] {
        [-self.probe_offset[0], -self.probe_offset[1], 0.0]
    }

    /// The build volume's radius (mm), at least 10 mm.
    pub fn print_radius(&self) -> f64 {
        self.print_radius.max(10.0)
    }
}

/// The physical model of `ld` as a pkmcal spatial description (TOML), with
/// its default `[tolerances]`.
pub fn physical_description(ld: &LinearDelta) -> String {
    physical_description_with(ld, false)
}

/// [`physical_description`], its tool the effector's whole pose (x y z rx
/// ry rz) with `whole_pose`: a reading of the nozzle turns with the
/// effector ([`pkmcal::Measurement::point`]). The same printer.
pub fn physical_description_with(ld: &LinearDelta, whole_pose: bool) -> String {
    let d = &ld.delta;
    let o = ld.probe_offset;
    let half = ROD_SPACING_MM / 2.0;
    let mut s = String::new();
    let mut free: Vec<String> = vec![];
    let mut tol: Vec<(String, f64, &str)> = vec![];
    for t in TOWERS {
        let radius = d.radius + EFFECTOR_RADIUS_MM;
        tol.push((format!("radius_{t}"), TOWER_RADIUS_SIGMA_MM, "mm"));
        tol.push((format!("angle_{t}"), TOWER_PLACE_SIGMA_MM / radius, "rad"));
        for k in 1..=2 {
            tol.push((format!("{t}.tilt{k}"), TOWER_LEAN_SIGMA_RAD, "rad"));
        }
        for k in 1..=2 {
            tol.push((format!("rod_{t}{k}"), ROD_SIGMA_MM, "mm"));
            for c in ["ex", "ey", "ez", "px", "py", "pz"] {
                tol.push((format!("{t}{k}.{c}"), JOINT_SIGMA_MM, "mm"));
            }
        }
    }
    free.extend(tol.iter().map(|(n, _, _)| n.clone()));
    free.extend(TOWERS.map(|t| format!("d{t}")));
    let _ = writeln!(
        s,
        "# The physical linear delta of {}'s values (pkmcal's physical model): each\n\
         # tower at its own radius and angle, leaning (a.tilt1, a.tilt2), its\n\
         # parallelogram two rods of their own lengths from two ball joints on the\n\
         # carriage to two on the effector, which turns as well as moves. The\n\
         # effector's frame is at the probe's trigger point; the nozzle at\n\
         # ({:?}, {:?}, 0) in it. Commands are the firmware's carriage heights (mm).\n\
         type = \"spatial\"\nname = \"Linear delta printer, physical (from {})\"\nfree = [{}]\n\n\
         [platform]\nmotion = \"full\"\ntool = [{}]   # the probe's trigger point{}\n",
        ld.firmware,
        -o[0],
        -o[1],
        ld.firmware,
        free.iter()
            .map(|n| format!("\"{n}\""))
            .collect::<Vec<_>>()
            .join(", "),
        match whole_pose {
            true => "\"x\", \"y\", \"z\", \"rx\", \"ry\", \"rz\"",
            false => "\"x\", \"y\", \"z\"",
        },
        match whole_pose {
            true => " and the effector's turn",
            false => "",
        }
    );
    for (i, t) in TOWERS.iter().enumerate() {
        let th = d.angles[i].to_radians();
        let (sn, cs) = th.sin_cos();
        for (k, sign) in [(1, 1.0), (2, -1.0)] {
            // The effector's joint, in the effector's frame (origin: the
            // probe), at the tower's angle and half the spacing aside.
            let p = [
                EFFECTOR_RADIUS_MM * cs - sign * half * sn - o[0],
                EFFECTOR_RADIUS_MM * sn + sign * half * cs - o[1],
            ];
            if k == 1 {
                let _ = writeln!(
                    s,
                    "[[leg]]   # tower {t}'s carriage and its first rod\nname = \"{t}1\"\nangle = \"angle_{t}\"\n\
                     [[leg.joint]]\nname = \"{t}\"\nkind = \"prismatic\"\nat = [\"radius_{t}\", 0.0, 0.0]\n\
                     axis = [0.0, 0.0, 1.0]   # leaning by {t}.tilt1, {t}.tilt2\nactuated = true\n\
                     stiffness = {CARRIAGE_STIFFNESS:?}   # N/mm"
                );
            } else {
                let _ = writeln!(
                    s,
                    "[[leg]]   # tower {t}'s second rod, from the same carriage\nname = \"{t}2\"\nchain = \"{t}1\""
                );
            }
            let _ = writeln!(
                s,
                "[leg.end]\nkind = \"rod\"\nat = [0.0, {:?}, 0.0]\nlength = \"rod_{t}{k}\"\nplatform = [{:?}, {:?}, 0.0]\n",
                sign * half,
                p[0],
                p[1]
            );
        }
    }
    let _ = writeln!(s, "[parameters]");
    for (i, t) in TOWERS.iter().enumerate() {
        let _ = writeln!(
            s,
            "radius_{t} = {:?}   # delta_radius + the effector's {EFFECTOR_RADIUS_MM} mm\n\
             angle_{t} = {:?}   # {}°\nrod_{t}1 = {:?}\nrod_{t}2 = {:?}",
            d.radius + EFFECTOR_RADIUS_MM,
            d.angles[i].to_radians(),
            d.angles[i],
            d.arms[i],
            d.arms[i]
        );
    }
    let _ = writeln!(
        s,
        "\n[assembly]\npose = [{:?}, {:?}, 10.0, 0.0, 0.0, 0.0]",
        o[0], o[1]
    );
    for (i, t) in TOWERS.iter().enumerate() {
        let rise = (d.arms[i].powi(2) - d.radius.powi(2)).sqrt();
        let _ = writeln!(s, "{t} = {:?}", 10.0 + rise);
    }
    let r = (1.1 * d.probe_radius.max(ld.print_radius)).max(10.0) + o[0].hypot(o[1]);
    let _ = writeln!(
        s,
        "\n[workspace]   # the probed region\nx = [{:?}, {r:?}]\ny = [{:?}, {r:?}]\nz = [-10.0, {:?}]\n",
        -r,
        -r,
        GRID_HEIGHTS_MM[GRID_HEIGHTS_MM.len() - 1] + 10.0
    );
    if whole_pose {
        // The effector's turn within its parts' tolerances (rad).
        s.pop();
        let _ = writeln!(
            s,
            "rx = [{t:?}, {EFFECTOR_TURN_RAD:?}]\nry = [{t:?}, {EFFECTOR_TURN_RAD:?}]\nrz = [{t:?}, {EFFECTOR_TURN_RAD:?}]\n",
            t = -EFFECTOR_TURN_RAD
        );
    }
    let _ = writeln!(s, "[tolerances]   # σ of each part (pkmcal's defaults)");
    for (n, v, unit) in &tol {
        let _ = writeln!(s, "\"{n}\" = {v:?}   # {unit}");
    }
    s
}

/// The physical model of `ld`: its mechanism and its `[tolerances]`.
pub fn physical_mechanism(ld: &LinearDelta) -> Result<(Mech, Vec<(String, Tolerance)>)> {
    physical_mechanism_with(ld, false)
}

/// [`physical_mechanism`] of [`physical_description_with`].
pub fn physical_mechanism_with(
    ld: &LinearDelta,
    whole_pose: bool,
) -> Result<(Mech, Vec<(String, Tolerance)>)> {
    let parts =
        crate::description::description_from_str(&physical_description_with(ld, whole_pose))
            .map_err(|e| {
                e.context(format!(
                    "the physical model of the {} geometry",
                    ld.firmware
                ))
            })?;
    Ok((parts.mech, parts.tolerances))
}

/// The physical model fitted to a printer's readings.
pub struct PhysicalFit {
    /// Where it started.
    pub delta: LinearDelta,
    /// The physical mechanism.
    pub mech: Mech,
    /// The readings (the firmware's, its weights left to the stated noise).
    pub readings: Readings,
    /// The free parameters' names.
    pub free_names: Vec<String>,
    /// The study (a MAP fit: the readings and the tolerances).
    pub study: pkmcal::identify::Study,
    /// The probe's noise the fit weighed the heights with: stated by its
    /// user, or pkmcal's assumption ([`PROBE_NOISE_MM`], a typical
    /// probe's).
    pub probe_noise: ProbeNoise,
    /// How many of the readings' poses (the last) are touches measured by
    /// hand ([`super::physical_heights`]), nozzle touches of them.
    pub touches: (usize, usize),
}

/// One kind of part's tolerances as a physical fit used them: the
/// defaults, or a user's in their place.
#[derive(Debug, Clone, PartialEq)]
pub struct ToleranceGroup {
    /// The parts, in words (`rods`, `tower radii`…).
    pub what: &'static str,
    /// The unit shown.
    pub unit: &'static str,
    /// The smallest and largest σ of its parts, in that unit.
    pub range: (f64, f64),
}

impl ToleranceGroup {
    /// In words: `rods 0.1 mm`, or `rods 0.01–0.1 mm` where they differ.
    pub fn words(&self) -> String {
        // To nine significant digits: `33.3`, not a sum's last bits.
        let short = |v: f64| -> f64 { format!("{v:.8e}").parse().unwrap_or(v) };
        let (lo, hi) = (short(self.range.0), short(self.range.1));
        if lo == hi {
            format!("{} {lo} {}", self.what, self.unit)
        } else {
            format!("{} {lo}–{hi} {}", self.what, self.unit)
        }
    }
}

/// The tolerances `fit` held its parts by, by kind (rods, tower radii,
/// tower lean, ball joints, bed tilt; angles in mrad), from the priors it
/// used: a kind whose parts are all fixed is left out.
pub fn tolerance_groups(fit: &PhysicalFit) -> Vec<ToleranceGroup> {
    fn joint(n: &str) -> bool {
        let b = n.as_bytes();
        b.len() == 5
            && matches!(b[0], b'a' | b'b' | b'c')
            && matches!(b[1], b'1' | b'2')
            && b[2] == b'.'
            && matches!(b[3], b'e' | b'p')
            && matches!(b[4], b'x' | b'y' | b'z')
    }
    // Words, unit, scale to it, and which parameters.
    type Kind = (&'static str, &'static str, f64, fn(&str) -> bool);
    let kinds: [Kind; 5] = [
        ("rods", "mm", 1.0, |n| n.starts_with("rod_")),
        ("tower radii", "mm", 1.0, |n| n.starts_with("radius_")),
        ("tower lean", "mrad", 1e3, |n| n.contains(".tilt")),
        ("ball joints", "mm", 1.0, joint),
        ("bed tilt", "mrad", 1e3, |n| n == "bed.rx" || n == "bed.ry"),
    ];
    let priors = &fit.study.calibration.priors;
    kinds
        .iter()
        .filter_map(|(what, unit, scale, of)| {
            let sigmas: Vec<f64> = priors
                .iter()
                .filter(|p| of(&p.name))
                .map(|p| p.sigma * scale)
                .collect();
            let lo = sigmas.iter().copied().reduce(f64::min)?;
            let hi = sigmas.iter().copied().reduce(f64::max)?;
            Some(ToleranceGroup {
                what,
                unit,
                range: (lo, hi),
            })
        })
        .collect()
}

/// The probe's σ of a physical fit (mm), and whose it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ProbeNoise {
    /// Stated by the probe's user.
    Stated(f64),
    /// pkmcal's assumption, a typical probe's ([`PROBE_NOISE_MM`]).
    Assumed(f64),
}

impl ProbeNoise {
    /// The σ (mm).
    pub fn mm(self) -> f64 {
        match self {
            ProbeNoise::Stated(s) | ProbeNoise::Assumed(s) => s,
        }
    }

    /// Whether it is pkmcal's assumption.
    pub fn assumed(self) -> bool {
        matches!(self, ProbeNoise::Assumed(_))
    }
}

/// What the residuals say of the readings' noise, where the adequacy test
/// finds it wrong ([`pkmcal::identify::adequacy`]): which readings, the
/// σ the fit weighed them with (the probe's stated or assumed; the
/// distances' is always assumed, [`DISTANCE_NOISE_MM`]) and the σ the
/// residuals show.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseNote {
    /// The probe heights' (or else the distances').
    pub heights: bool,
    /// The σ the fit weighed them with.
    pub noise: ProbeNoise,
    /// The σ the residuals show (mm).
    pub found: f64,
    /// The χ² test's p-value (the tail the residuals are in).
    pub p: f64,
    /// Whether they scatter more than that σ (else less).
    pub more: bool,
    /// With `more`: the parameters left out whose freeing would explain
    /// it, with their share of the misfit (empty: none does, the misfit is
    /// spread like noise).
    pub suspects: Vec<(String, f64)>,
}

impl NoiseNote {
    /// Whether it is a warning: the readings scatter more than the σ they
    /// were weighed with, or less than one a user stated (a typical part
    /// scattering less than assumed is news, not a fault: a note).
    pub fn is_warning(&self) -> bool {
        self.more || !self.noise.assumed()
    }

    /// What the residuals say, in words naming no option (each front end
    /// adds its hint, in its own options' names).
    pub fn message(&self) -> String {
        let whose = match (self.heights, self.noise) {
            (true, ProbeNoise::Assumed(_)) => "a typical probe's".to_string(),
            (true, ProbeNoise::Stated(s)) => format!("the σ {s} mm stated"),
            (false, _) => "a caliper's".to_string(),
        };
        let readings = if self.heights {
            "the probe's readings"
        } else {
            "the distances"
        };
        let against = match self.noise {
            ProbeNoise::Assumed(s) => format!("against the {s} mm assumed"),
            ProbeNoise::Stated(s) => format!("against the {s} mm stated"),
        };
        if !self.more {
            return match self.noise {
                ProbeNoise::Assumed(_) => format!(
                    "{readings} scatter less than {whose} (σ {:.2e} mm from the residuals {against}): the uncertainties are on the safe side",
                    self.found
                ),
                ProbeNoise::Stated(_) => format!(
                    "{readings} scatter less than {whose} (σ {:.2e} mm from the residuals; χ² test, lower tail p = {:.1e}): every uncertainty is as much too large",
                    self.found, self.p
                ),
            };
        }
        let freeing = if self.suspects.is_empty() {
            String::new()
        } else {
            format!(
                "; freeing {} would remove the share of the misfit given: {}",
                if self.suspects.len() == 1 {
                    "this parameter"
                } else {
                    "these parameters"
                },
                self.suspects
                    .iter()
                    .map(|(p, s)| format!("`{p}` ({:.0} %)", 100.0 * s))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        };
        format!(
            "{readings} scatter more than {whose} (σ {:.2e} mm from the residuals {against}; χ² test, p = {:.1e}){freeing}: every uncertainty is as much too small",
            self.found, self.p
        )
    }

    /// The note of a fit's adequacy warning, if `w` is one (on readings
    /// whose σ the fit stated, not given in the data).
    pub fn of(fit: &PhysicalFit, w: &pkmcal::identify::Warning) -> Option<NoiseNote> {
        use pkmcal::identify::WarningKind as K;
        let (axes, found, given, p, more, suspects) = match &w.kind {
            K::NoiseOverstated {
                axes,
                found,
                given,
                p,
                ..
            } => (axes, *found, *given, *p, false, vec![]),
            K::NoiseUnderstated {
                axes,
                found,
                given,
                p,
                ..
            } => (axes, *found, *given, *p, true, vec![]),
            K::ModelInadequate {
                axes,
                found,
                given,
                p,
                suspects,
                ..
            } => (axes, *found, *given, *p, true, suspects.clone()),
            _ => return None,
        };
        if given {
            return None;
        }
        let heights = !axes.iter().any(|a| a == pkmcal::DISTANCE_AXIS);
        Some(NoiseNote {
            heights,
            noise: if heights {
                fit.probe_noise
            } else {
                ProbeNoise::Assumed(DISTANCE_NOISE_MM)
            },
            found,
            p,
            more,
            suspects,
        })
    }
}

/// The physical model of `firmware`'s printer fitted to its readings as far
/// as they and the tolerances allow (a MAP fit): the description's
/// tolerances, the bed's tilt [`BED_TILT_SIGMA_RAD`] and the readings'
/// noise [`PROBE_NOISE_MM`] (distances [`DISTANCE_NOISE_MM`]) unless
/// `request` states its own. The probe's σ, stated or assumed, is taken as
/// known: what the residuals say of it is the adequacy test's
/// ([`NoiseNote`]).
pub fn calibrate(
    firmware: &dyn Firmware,
    ld: &LinearDelta,
    request: Request,
) -> Result<PhysicalFit> {
    calibrate_with(firmware, ld, request, None)
}

/// [`calibrate`], with the touches measured by hand (`touches`,
/// [`super::physical_heights`]) read as well: the physical model's tool is
/// then the effector's whole pose, so that a nozzle touch reads the
/// effector's tilt; each touch weighs by its σ.
pub fn calibrate_with(
    firmware: &dyn Firmware,
    ld: &LinearDelta,
    mut request: Request,
    touches: Option<&super::physical_heights::Touches>,
) -> Result<PhysicalFit> {
    let (mech, table) = physical_mechanism_with(ld, touches.is_some())?;
    let spec = mech.spec();
    let mut readings = firmware.physical_readings(spec)?;
    // The readings weigh as their stated noise says, not as the firmware's
    // own fit weighs them against each other.
    for m in readings
        .poses
        .iter_mut()
        .chain(readings.distances.iter_mut())
    {
        m.sigma.clear();
    }
    let first = readings.poses.len();
    let mut counts = (0, 0);
    if let Some(t) = touches {
        let fw_mech = firmware.mechanism()?;
        let fw_bed = ld
            .corrects_bed_tilt
            .then(|| readings.measurement.nominal().to_vec());
        let rows = super::physical_heights::readings(t, ld, &fw_mech, fw_bed.as_deref(), first)?;
        counts = (
            rows.len(),
            rows.iter().filter(|m| m.point.is_some()).count(),
        );
        readings.poses.extend(rows);
    }
    for axis in ["bed.rx", "bed.ry"] {
        if !request.tolerances.iter().any(|(n, _)| n == axis) {
            request
                .tolerances
                .push((axis.to_string(), Tolerance::Absolute(BED_TILT_SIGMA_RAD)));
        }
    }
    let probe_noise = match request.stated_noise {
        Some(s) => ProbeNoise::Stated(s),
        None => ProbeNoise::Assumed(PROBE_NOISE_MM),
    };
    request.stated_noise = Some(probe_noise.mm());
    request.stated_readings = f64::INFINITY;
    if request.stated_distance_noise.is_none() && !readings.distances.is_empty() {
        request.stated_distance_noise = Some(DISTANCE_NOISE_MM);
    }
    let measurement = &readings.measurement;
    let (_, free) = request.priors_and_free(spec, measurement, &table)?;
    let free_names = request.free_names(spec, measurement, &free);
    let nominal = Params::nominal(spec);
    let opts = request.study_options(&mech, measurement, &table, &nominal)?;
    let study = super::study_located(&mech, &readings, &opts, &|e| match touches
        .and_then(|t| super::physical_heights::located(t, first, &e))
    {
        Some(located) => located,
        None => firmware.located(e),
    })?;
    Ok(PhysicalFit {
        delta: ld.clone(),
        mech,
        readings,
        free_names,
        study,
        probe_noise,
        touches: counts,
    })
}

/// The nozzle (base frame, mm) of the physical printer `mech` with
/// parameters `params` at the firmware's carriage heights `commands`; the
/// nozzle at `nozzle` in the effector's frame.
pub fn nozzle_at(
    mech: &Mech,
    params: &Params,
    commands: &[f64],
    nozzle: [f64; 3],
) -> Result<[f64; 3]> {
    Ok(nozzle_from(mech, params, commands, nozzle, None)?.0)
}

/// [`nozzle_at`], and the printer's joints there; from `start`, the joints
/// at nearby commands or on a nearby printer ([`pkmcal::predict_near`]),
/// where given: a projection's steps and a posterior's draws move the
/// nozzle by millimetres at most, and a cold prediction's nominal forward
/// kinematics is most of its cost.
fn nozzle_from(
    mech: &Mech,
    params: &Params,
    commands: &[f64],
    nozzle: [f64; 3],
    start: Option<&[f64]>,
) -> Result<([f64; 3], Vec<f64>)> {
    let exact = pkmcal::Model::Exact;
    let pr = match start {
        Some(q) => pkmcal::predict_near(mech, params, commands, exact, &[], q)?,
        None => pkmcal::predict(mech, params, commands, exact, &[])?,
    };
    let n = pr.q.len();
    let pose = &pr.q[n - 6..];
    let r = pkmcal::linalg::pose::rotation(pose[3], pose[4], pose[5]);
    let at = std::array::from_fn(|i| pose[i] + (0..3).map(|k| r[i][k] * nozzle[k]).sum::<f64>());
    Ok((at, pr.q))
}

/// The bed plane's height (mm) at `x`, `y` for the probe's parameters
/// `bed` (`bed.z bed.rx bed.ry`, [`pkmcal::Instrument::Probe`]).
pub fn bed_height(bed: &[f64], x: f64, y: f64) -> f64 {
    bed[0] - x * bed[2].tan() + y * bed[1].tan()
}

/// The build-volume grid (nozzle targets over the bed, mm): [`GRID_POINTS`]
/// across the printer's probed circle in x and y, at [`GRID_HEIGHTS_MM`].
pub fn build_volume(radius: f64) -> Vec<[f64; 3]> {
    let n = GRID_POINTS;
    let mut out = vec![];
    for &z in &GRID_HEIGHTS_MM {
        for i in 0..n {
            for j in 0..n {
                let x = radius * (2.0 * i as f64 / (n - 1) as f64 - 1.0);
                let y = radius * (2.0 * j as f64 / (n - 1) as f64 - 1.0);
                if x.hypot(y) <= radius * (1.0 + 1e-9) {
                    out.push([x, y, z]);
                }
            }
        }
    }
    out
}

/// The firmware's carriage heights for the nozzle target `t` (over the
/// bed) under its description's parameters `fw_params`, tilting its z with
/// the bed plane `fw_bed` where it does.
pub fn firmware_commands(
    fw_mech: &Mech,
    fw_params: &Params,
    fw_bed: Option<&[f64]>,
    t: [f64; 3],
) -> Result<Vec<f64>> {
    let z = match fw_bed {
        Some(b) => t[2] + bed_height(&[0.0, b[1], b[2]], t[0], t[1]),
        None => t[2],
    };
    Ok(pkmcal::controller_commands(
        fw_mech,
        fw_params,
        &[t[0], t[1], z],
    )?)
}

/// What the firmware's values do on the physical printer: at each nozzle
/// target over the bed, the real nozzle's error (x, y, and z over the bed
/// plane `bed`, mm).
#[allow(clippy::too_many_arguments)]
pub fn nozzle_errors(
    fw_mech: &Mech,
    fw_params: &Params,
    fw_bed: Option<&[f64]>,
    mech: &Mech,
    params: &Params,
    bed: &[f64],
    nozzle: [f64; 3],
    targets: &[[f64; 3]],
) -> Result<Vec<[f64; 3]>> {
    let at = Printer {
        mech,
        params,
        bed,
        nozzle,
    };
    Ok(nozzle_errors_from(fw_mech, fw_params, fw_bed, &at, targets, None)?.0)
}

/// A printer's joints at each nozzle target (its predictions' `q`), kept
/// to start the next evaluation's predictions at the same targets.
pub(crate) type Joints = Vec<Vec<f64>>;

/// A printer as the nozzle's errors read it: its description, parameters,
/// bed plane and nozzle offset.
#[derive(Clone, Copy)]
pub(crate) struct Printer<'a> {
    pub mech: &'a Mech,
    pub params: &'a Params,
    pub bed: &'a [f64],
    pub nozzle: [f64; 3],
}

/// [`nozzle_errors`] on `at`, and the printer's joints at each target;
/// each prediction from the joints `starts` of the same target (at nearby
/// firmware values or on a nearby printer) where given ([`nozzle_from`]).
fn nozzle_errors_from(
    fw_mech: &Mech,
    fw_params: &Params,
    fw_bed: Option<&[f64]>,
    at: &Printer,
    targets: &[[f64; 3]],
    starts: Option<&[Vec<f64>]>,
) -> Result<(Vec<[f64; 3]>, Joints)> {
    let sent = Sent::new(fw_mech, fw_params, fw_bed, targets)?;
    sent.nozzle_errors(at, starts)
}

/// The carriage heights the firmware sends for each nozzle target under
/// fixed values ([`firmware_commands`]): made once where many printers
/// (a posterior's draws) are compared under the same values.
pub(crate) struct Sent<'t> {
    targets: &'t [[f64; 3]],
    commands: Vec<Vec<f64>>,
}

impl<'t> Sent<'t> {
    pub(crate) fn new(
        fw_mech: &Mech,
        fw_params: &Params,
        fw_bed: Option<&[f64]>,
        targets: &'t [[f64; 3]],
    ) -> Result<Self> {
        use rayon::prelude::*;
        let commands = targets
            .par_iter()
            .map(|t| firmware_commands(fw_mech, fw_params, fw_bed, *t))
            .collect::<Result<_>>()?;
        Ok(Sent { targets, commands })
    }

    /// The nozzle's error at each target on the printer `at` (as
    /// [`nozzle_errors`]), and the printer's joints there; each prediction
    /// from `starts`' joints of the same target where given.
    pub(crate) fn nozzle_errors(
        &self,
        at: &Printer,
        starts: Option<&[Vec<f64>]>,
    ) -> Result<(Vec<[f64; 3]>, Joints)> {
        use rayon::prelude::*;
        let errors: Vec<([f64; 3], Vec<f64>)> = self
            .targets
            .par_iter()
            .zip(&self.commands)
            .enumerate()
            .map(|(i, (t, c))| {
                let start = starts.and_then(|s| s.get(i)).map(Vec::as_slice);
                let (n, q) = nozzle_from(at.mech, at.params, c, at.nozzle, start)?;
                Ok((
                    [
                        n[0] - t[0],
                        n[1] - t[1],
                        n[2] - bed_height(at.bed, n[0], n[1]) - t[2],
                    ],
                    q,
                ))
            })
            .collect::<Result<_>>()?;
        Ok(errors.into_iter().unzip())
    }
}

/// The rigid motion in the bed's plane that best explains the XY errors
/// `errors` at the nozzle targets `targets` (least squares): a shift in x
/// and y (mm) and a turn about z (rad, counter-clockwise), to first order.
///
/// The bed has no datum in its plane: nothing a probe, a caliper or its
/// owner measures fixes where on the bed, or at which heading, a part is
/// printed, and no probe height sees either. A printer whose every nozzle
/// position is shifted or turned by the same small motion prints the same
/// parts, so the nozzle's error in the bed's frame is its error less this
/// motion ([`in_bed_frame`]). Its size and its form (scale, skew, bowing,
/// walls leaning with height) are left whole.
pub fn bed_motion(targets: &[[f64; 3]], errors: &[[f64; 3]]) -> [f64; 3] {
    let n = targets.len().min(errors.len());
    if n == 0 {
        return [0.0; 3];
    }
    let nf = n as f64;
    let mean = |f: &dyn Fn(usize) -> f64| (0..n).map(f).sum::<f64>() / nf;
    let (x0, y0) = (mean(&|i| targets[i][0]), mean(&|i| targets[i][1]));
    let (ex, ey) = (mean(&|i| errors[i][0]), mean(&|i| errors[i][1]));
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..n {
        let (x, y) = (targets[i][0] - x0, targets[i][1] - y0);
        num += x * (errors[i][1] - ey) - y * (errors[i][0] - ex);
        den += x * x + y * y;
    }
    let turn = if den > 0.0 { num / den } else { 0.0 };
    [ex + turn * y0, ey - turn * x0, turn]
}

/// The nozzle's errors `errors` at `targets` in the bed's frame: less the
/// rigid motion in the bed's plane ([`bed_motion`]) that no part printed
/// shows. Z is left as it is: the bed's plane is its datum.
pub fn in_bed_frame(targets: &[[f64; 3]], errors: &[[f64; 3]]) -> Vec<[f64; 3]> {
    weighed(targets, errors, 0.0)
}

/// The nozzle's errors `errors` at `targets` with the rigid motion in the
/// bed's plane ([`bed_motion`]) weighing `placement` (0: in the bed's
/// frame, 1: as they are): their sum of squares is that of the errors in
/// the bed's frame plus `placement²` times that of the motion's.
pub fn weighed(targets: &[[f64; 3]], errors: &[[f64; 3]], placement: f64) -> Vec<[f64; 3]> {
    let [tx, ty, turn] = bed_motion(targets, errors);
    let k = 1.0 - placement;
    targets
        .iter()
        .zip(errors)
        .map(|(t, e)| {
            [
                e[0] - k * (tx - turn * t[1]),
                e[1] - k * (ty + turn * t[0]),
                e[2],
            ]
        })
        .collect()
}

/// RMS and largest size of the XY and Z errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorSummary {
    /// RMS of the XY errors' lengths (mm).
    pub xy_rms: f64,
    /// The largest XY error (mm).
    pub xy_max: f64,
    /// RMS of the Z errors (mm).
    pub z_rms: f64,
    /// The largest Z error (mm).
    pub z_max: f64,
}

impl ErrorSummary {
    /// The summary of `errors`.
    pub fn of(errors: &[[f64; 3]]) -> Self {
        let n = errors.len().max(1) as f64;
        let xy: Vec<f64> = errors.iter().map(|e| e[0].hypot(e[1])).collect();
        ErrorSummary {
            xy_rms: (xy.iter().map(|v| v * v).sum::<f64>() / n).sqrt(),
            xy_max: xy.iter().fold(0.0, |m, v| m.max(*v)),
            z_rms: (errors.iter().map(|e| e[2] * e[2]).sum::<f64>() / n).sqrt(),
            z_max: errors.iter().fold(0.0, |m, e| m.max(e[2].abs())),
        }
    }

    /// The RMS of the whole error (mm): `√(xy_rms² + z_rms²)`.
    pub fn rms(&self) -> f64 {
        self.xy_rms.hypot(self.z_rms)
    }
}

/// The firmware's values for the nozzle on a physical printer: its
/// description's parameters and bed, and what they leave.
#[derive(Debug, Clone)]
pub struct Projection {
    /// The firmware description's parameters.
    pub params: Params,
    /// The bed's parameters to write (the firmware's tilt where it tilts).
    pub bed: Vec<f64>,
    /// The build-volume targets.
    pub targets: Vec<[f64; 3]>,
    /// The nozzle's errors there with these values.
    pub errors: Vec<[f64; 3]>,
    /// Their summary.
    pub summary: ErrorSummary,
}

/// Iterations of the projection (each a linear least-squares fit of the
/// firmware's values to the nozzle's errors over the grid).
const PROJECTION_ITERATIONS: usize = 6;
/// The projection stops when its values move less than this (mm or rad).
const PROJECTION_STEP: f64 = 1e-9;
/// Step of the finite differences of the projection's Jacobian (mm, rad).
const PROJECTION_DIFF: f64 = 1e-6;
/// Directions of the firmware's values whose singular value is below this
/// share of the largest are left where they are (their change would not
/// show in the error: a turn of every tower angle together).
const PROJECTION_RANK: f64 = 1e-9;
/// Halvings of a Gauss-Newton step before the projection stops.
const PROJECTION_HALVINGS: usize = 8;
/// How much the placement of a part on the bed (the rigid motion in the
/// bed's plane, [`bed_motion`]) weighs in the projection against its form:
/// a millimetre off where it was asked as a hundredth of a millimetre of
/// form. It only chooses between values that print the same parts.
pub const PLACEMENT_WEIGHT: f64 = 0.01;

/// The firmware's values that minimise the real nozzle's error in the
/// bed's frame ([`in_bed_frame`]: x, y, and z over the bed; least squares)
/// over the build-volume grid, on the physical printer `params` with bed
/// `bed`: Gauss-Newton on the values [`LinearDelta::values`] from the
/// firmware's current ones. Among values that print the same parts, those
/// that place them where asked ([`PLACEMENT_WEIGHT`]).
pub fn project(
    ld: &LinearDelta,
    fw_mech: &Mech,
    mech: &Mech,
    params: &Params,
    bed: &[f64],
) -> Result<Projection> {
    project_weighing(ld, fw_mech, mech, params, bed, 1.0)
}

/// [`project`] with the nozzle's Z error weighing `z_weight` times its XY
/// error (in the bed's frame) in the least squares.
pub fn project_weighing(
    ld: &LinearDelta,
    fw_mech: &Mech,
    mech: &Mech,
    params: &Params,
    bed: &[f64],
    z_weight: f64,
) -> Result<Projection> {
    let fw_spec = fw_mech.spec();
    let targets = build_volume(ld.print_radius());
    let names: Vec<&String> = ld
        .values
        .iter()
        .filter(|n| fw_spec.param_index(n).is_ok())
        .collect();
    let fw_bed = ld.corrects_bed_tilt.then(|| bed.to_vec());
    let mut fw = Params::nominal(fw_spec);
    let at = Printer {
        mech,
        params,
        bed,
        nozzle: ld.nozzle(),
    };
    // The weighed errors, and the joints at each target (each step's
    // predictions start from the last accepted values' joints).
    let errors = |p: &Params, starts: Option<&[Vec<f64>]>| -> Result<(Vec<f64>, Joints)> {
        let (e, q) = nozzle_errors_from(fw_mech, p, fw_bed.as_deref(), &at, &targets, starts)?;
        let e = weighed(&targets, &e, PLACEMENT_WEIGHT)
            .into_iter()
            .flat_map(|v| [v[0], v[1], z_weight * v[2]])
            .collect();
        Ok((e, q))
    };
    let ss = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>();
    let (mut e, mut joints) = errors(&fw, None)?;
    for _ in 0..PROJECTION_ITERATIONS {
        let mut jac = nalgebra::DMatrix::zeros(e.len(), names.len());
        for (k, n) in names.iter().enumerate() {
            let mut p = fw.clone();
            let v = p.get(fw_spec, n)?;
            p.set(fw_spec, n, v + PROJECTION_DIFF)?;
            let (ep, _) = errors(&p, Some(&joints))?;
            for (i, (a, b)) in ep.iter().zip(&e).enumerate() {
                jac[(i, k)] = (a - b) / PROJECTION_DIFF;
            }
        }
        let rhs = nalgebra::DVector::from_column_slice(&e);
        let svd = jac.svd(true, true);
        let cut = svd.singular_values.max() * PROJECTION_RANK;
        let step = svd
            .solve(&rhs, cut)
            .map_err(|m| Error::Content(format!("the projection's least squares failed: {m}")))?;
        // Gauss-Newton's step, halved until it lowers the error.
        let mut accepted = None;
        let mut scale = 1.0;
        for _ in 0..PROJECTION_HALVINGS {
            let mut next = fw.clone();
            for (k, n) in names.iter().enumerate() {
                let v = next.get(fw_spec, n)?;
                next.set(fw_spec, n, v - scale * step[k])?;
            }
            let (en, qn) = errors(&next, Some(&joints))?;
            if ss(&en) <= ss(&e) {
                accepted = Some((next, en, qn));
                break;
            }
            scale /= 2.0;
        }
        let Some((next, en, qn)) = accepted else {
            break;
        };
        fw = next;
        e = en;
        joints = qn;
        if scale * step.amax() < PROJECTION_STEP {
            break;
        }
    }
    let (e, _) = nozzle_errors_from(
        fw_mech,
        &fw,
        fw_bed.as_deref(),
        &at,
        &targets,
        Some(&joints),
    )?;
    let e: Vec<f64> = in_bed_frame(&targets, &e).into_iter().flatten().collect();
    let errors: Vec<[f64; 3]> = e.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    if errors.is_empty() {
        invalid!("the build volume holds no point to project on");
    }
    let fw_bed_out = match &fw_bed {
        Some(b) => vec![0.0, b[1], b[2]],
        None => vec![0.0; 3],
    };
    Ok(Projection {
        params: fw,
        bed: fw_bed_out,
        summary: ErrorSummary::of(&errors),
        targets,
        errors,
    })
}

/// `count` draws of the physical printer (its parameters and its bed) from
/// the fit's posterior: the free parameters from their covariance about
/// the fit's values, seeded by `seed`.
pub fn posterior_draws(
    fit: &PhysicalFit,
    count: usize,
    seed: u64,
) -> Result<Vec<(Params, Vec<f64>)>> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let cal = &fit.study.calibration;
    let spec = fit.mech.spec();
    let names = fit.readings.measurement.all_names(spec);
    let n_params = spec.n_params();
    let eig = cal.covariance.clone().symmetric_eigen();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    (0..count)
        .map(|_| -> Result<(Params, Vec<f64>)> {
            let z: Vec<f64> = (0..cal.free.len())
                .map(|_| StandardNormal.sample(&mut rng))
                .collect();
            let (mut p, mut bed) = (cal.params.clone(), cal.measurement.clone());
            for (k, &i) in cal.free.iter().enumerate() {
                let d: f64 = (0..z.len())
                    .map(|j| eig.eigenvectors[(k, j)] * eig.eigenvalues[j].max(0.0).sqrt() * z[j])
                    .sum();
                if i < n_params {
                    let v = p.get(spec, &names[i])?;
                    p.set(spec, &names[i], v + d)?;
                } else {
                    bed[i - n_params] += d;
                }
            }
            Ok((p, bed))
        })
        .collect()
}

/// Draws from the fit's posterior behind the choice of the values written
/// ([`choose`]).
pub const CHOICE_DRAWS: usize = 32;
/// Their seed.
pub const CHOICE_SEED: u64 = 2;
/// The projection replaces the firmware's own fit only where the expected
/// gain over the posterior exceeds this many of its standard deviations.
pub const CHOICE_SIGMAS: f64 = 1.0;
/// The largest weight of Z against XY the projection tries to keep the
/// nozzle's Z no worse than the firmware's own fit leaves it.
const MAX_Z_WEIGHT: f64 = 64.0;

/// Which values are written, and why.
pub struct Choice {
    /// The values written (the projection's, or the firmware's own fit's),
    /// with their errors on the fitted printer.
    pub written: Projection,
    /// The firmware's own fit's values and their errors on the fitted
    /// printer.
    pub own: Projection,
    /// The projection's, weighing Z [`Choice::z_weight`] times XY.
    pub projected: Projection,
    /// The weight of Z against XY that keeps the projection's Z no worse
    /// than the firmware's own fit's on the fitted printer (1: no need).
    pub z_weight: f64,
    /// The expected mean square nozzle error (mm², in the bed's frame,
    /// over the build volume and the posterior) the projection removes
    /// from the firmware's own fit's, and its standard deviation.
    pub gain: [f64; 2],
    /// The same of Z alone.
    pub z_gain: [f64; 2],
    /// Whether the projection was written (its gain beyond
    /// [`CHOICE_SIGMAS`] standard deviations).
    pub projection_written: bool,
}

/// The firmware values to write for the nozzle: the projection onto the
/// fitted printer ([`project_weighing`]), Z weighing as much as keeps it no
/// worse than the firmware's own fit (`own`, `own_bed`: its values and
/// bed) leaves it; written in place of the firmware's own fit only where
/// that lowers the nozzle's mean square error over the build volume in
/// expectation over the fit's posterior by more than [`CHOICE_SIGMAS`] of
/// its standard deviation (what the data cannot see is no reason to move
/// from what the firmware's own fit writes).
pub fn choose(fit: &PhysicalFit, fw_mech: &Mech, own: &Params, own_bed: &[f64]) -> Result<Choice> {
    let ld = &fit.delta;
    let cal = &fit.study.calibration;
    let targets = build_volume(ld.print_radius());
    let nozzle = ld.nozzle();
    let tilt = |b: &[f64]| match ld.corrects_bed_tilt {
        true => vec![
            0.0,
            b.get(1).copied().unwrap_or(0.0),
            b.get(2).copied().unwrap_or(0.0),
        ],
        false => vec![0.0; 3],
    };
    let fw_bed = |b: &[f64]| ld.corrects_bed_tilt.then(|| b.to_vec());
    let own_bed = tilt(own_bed);
    // The errors in the bed's frame with the firmware's values `p` (bed
    // `b`) on the printer `mp` (bed `mb`), and its joints at each target;
    // from `starts` where given.
    let sent = |p: &Params, b: &[f64]| Sent::new(fw_mech, p, fw_bed(b).as_deref(), &targets);
    let on = |sent: &Sent,
              mp: &Params,
              mb: &[f64],
              starts: Option<&[Vec<f64>]>|
     -> Result<(Vec<[f64; 3]>, Joints)> {
        let at = Printer {
            mech: &fit.mech,
            params: mp,
            bed: mb,
            nozzle,
        };
        let (e, q) = sent.nozzle_errors(&at, starts)?;
        Ok((in_bed_frame(&targets, &e), q))
    };
    let own_sent = sent(own, &own_bed)?;
    let (own_errors, own_joints) = on(&own_sent, &cal.params, &cal.measurement, None)?;
    let own = Projection {
        params: own.clone(),
        bed: own_bed,
        summary: ErrorSummary::of(&own_errors),
        targets: targets.clone(),
        errors: own_errors,
    };
    let mut z_weight = 1.0;
    let mut projected = project_weighing(
        ld,
        fw_mech,
        &fit.mech,
        &cal.params,
        &cal.measurement,
        z_weight,
    )?;
    while projected.summary.z_rms > own.summary.z_rms && z_weight < MAX_Z_WEIGHT {
        z_weight *= 2.0;
        projected = project_weighing(
            ld,
            fw_mech,
            &fit.mech,
            &cal.params,
            &cal.measurement,
            z_weight,
        )?;
    }
    let draws = posterior_draws(fit, CHOICE_DRAWS, CHOICE_SEED)?;
    let mean_square = |e: &[[f64; 3]]| {
        let n = e.len().max(1) as f64;
        let z = e.iter().map(|v| v[2] * v[2]).sum::<f64>() / n;
        (
            e.iter().map(|v| v[0] * v[0] + v[1] * v[1]).sum::<f64>() / n + z,
            z,
        )
    };
    // Each draw's predictions start from the fitted printer's joints at
    // the same commands.
    let projected_sent = sent(&projected.params, &projected.bed)?;
    let (_, projected_joints) = on(
        &projected_sent,
        &cal.params,
        &cal.measurement,
        Some(&own_joints),
    )?;
    let mut gains = vec![];
    for (p, b) in &draws {
        let (own_e, _) = on(&own_sent, p, b, Some(&own_joints))?;
        let (projected_e, _) = on(&projected_sent, p, b, Some(&projected_joints))?;
        let (t0, z0) = mean_square(&own_e);
        let (t1, z1) = mean_square(&projected_e);
        gains.push([t0 - t1, z0 - z1]);
    }
    let stat = |k: usize| -> [f64; 2] {
        let n = gains.len().max(2) as f64;
        let m = gains.iter().map(|g| g[k]).sum::<f64>() / n;
        let v = gains.iter().map(|g| (g[k] - m).powi(2)).sum::<f64>() / (n - 1.0);
        [m, v.sqrt()]
    };
    let (gain, z_gain) = (stat(0), stat(1));
    let projection_written = gain[0] > CHOICE_SIGMAS * gain[1];
    Ok(Choice {
        written: if projection_written {
            projected.clone()
        } else {
            own.clone()
        },
        own,
        projected,
        z_weight,
        gain,
        z_gain,
        projection_written,
    })
}

/// The values `firmware` writes under `--physical` ([`Firmware::values`],
/// before and after), each with its σ: the firmware's own fit's (`own`)
/// where its values are written, else the posterior's through the
/// projection ([`projection_sigmas`]).
pub fn written_values(
    firmware: &dyn Firmware,
    fit: &PhysicalFit,
    fw_mech: &Mech,
    choice: &Choice,
    own: &super::PrinterCalibration,
) -> Result<Vec<super::FirmwareValue>> {
    let proj = &choice.written;
    let mut values = firmware.values(fw_mech.spec(), &proj.params, &proj.bed)?;
    let sigmas: Vec<f64> = if choice.projection_written {
        projection_sigmas(firmware, fit, fw_mech, proj, choice.z_weight)?
    } else {
        super::written(firmware, own)?
            .values
            .iter()
            .map(|v| v.sigma.unwrap_or(0.0))
            .collect()
    };
    for (v, s) in values.iter_mut().zip(&sigmas) {
        v.sigma = Some(*s);
    }
    Ok(values)
}

/// The standard deviation of each value `firmware` writes
/// ([`Firmware::values`], in its order and unit) from the projection
/// `proj` (weighing Z `z_weight`): the fit's posterior propagated through
/// the projection. Each of [`CHOICE_DRAWS`] draws of the printer moves the
/// projection by one Gauss-Newton step from its values (the projection is
/// linear in the printer's errors over their uncertainty). The tower
/// angles' common turn, which no printed part shows, is left out.
pub fn projection_sigmas(
    firmware: &dyn Firmware,
    fit: &PhysicalFit,
    fw_mech: &Mech,
    proj: &Projection,
    z_weight: f64,
) -> Result<Vec<f64>> {
    let ld = &fit.delta;
    let cal = &fit.study.calibration;
    let fw_spec = fw_mech.spec();
    let targets = &proj.targets;
    let nozzle = ld.nozzle();
    let names: Vec<&String> = ld
        .values
        .iter()
        .filter(|n| fw_spec.param_index(n).is_ok())
        .collect();
    // The weighed errors with the firmware's values `fw` (the
    // projection's where `None`) on the printer `params`, and the joints at
    // each target, from `starts` where given (the fitted printer's at the
    // projection's values).
    // Where the firmware does not tilt its z with the printer's bed, the
    // projection's values send the same commands to every draw.
    let sent = match ld.corrects_bed_tilt {
        true => None,
        false => Some(Sent::new(fw_mech, &proj.params, None, targets)?),
    };
    let objective = |fw: Option<&Params>,
                     params: &Params,
                     bed: &[f64],
                     starts: Option<&[Vec<f64>]>|
     -> Result<(Vec<f64>, Joints)> {
        let fw_bed = ld.corrects_bed_tilt.then(|| bed.to_vec());
        let at = Printer {
            mech: &fit.mech,
            params,
            bed,
            nozzle,
        };
        let (e, q) = match (fw, &sent) {
            (None, Some(sent)) => sent.nozzle_errors(&at, starts)?,
            (fw, _) => {
                let fw = fw.unwrap_or(&proj.params);
                nozzle_errors_from(fw_mech, fw, fw_bed.as_deref(), &at, targets, starts)?
            }
        };
        let e = weighed(targets, &e, PLACEMENT_WEIGHT)
            .into_iter()
            .flat_map(|v| [v[0], v[1], z_weight * v[2]])
            .collect();
        Ok((e, q))
    };
    let (e0, joints) = objective(None, &cal.params, &cal.measurement, None)?;
    let mut jac = nalgebra::DMatrix::zeros(e0.len(), names.len());
    for (k, n) in names.iter().enumerate() {
        let mut p = proj.params.clone();
        let v = p.get(fw_spec, n)?;
        p.set(fw_spec, n, v + PROJECTION_DIFF)?;
        let (ep, _) = objective(Some(&p), &cal.params, &cal.measurement, Some(&joints))?;
        for (i, (a, b)) in ep.iter().zip(&e0).enumerate() {
            jac[(i, k)] = (a - b) / PROJECTION_DIFF;
        }
    }
    let svd = jac.svd(true, true);
    let cut = svd.singular_values.max() * PROJECTION_RANK;
    let written = |p: &Params, bed: &[f64]| -> Result<Vec<f64>> {
        let bed = match ld.corrects_bed_tilt {
            true => vec![0.0, bed[1], bed[2]],
            false => proj.bed.clone(),
        };
        Ok(firmware
            .values(fw_spec, p, &bed)?
            .into_iter()
            .map(|v| v.after)
            .collect())
    };
    let mut sum: Vec<f64> = vec![];
    let mut sq: Vec<f64> = vec![];
    let base = written(&proj.params, &cal.measurement)?;
    let draws = posterior_draws(fit, CHOICE_DRAWS, CHOICE_SEED)?;
    for (p, bed) in &draws {
        let (e, _) = objective(None, p, bed, Some(&joints))?;
        let de: Vec<f64> = e.iter().zip(&e0).map(|(a, b)| a - b).collect();
        let step = svd
            .solve(&nalgebra::DVector::from_column_slice(&de), cut)
            .map_err(|m| Error::Content(format!("the projection's least squares failed: {m}")))?;
        // A turn of every tower angle together turns every part printed:
        // no part shows it, and only the placement's small weight holds it;
        // the σ are of the angles less their common turn.
        let angles: Vec<usize> = (0..names.len())
            .filter(|&k| names[k].starts_with(TOWER_ANGLE))
            .collect();
        let turn = match angles.len() {
            3 => angles.iter().map(|&k| step[k]).sum::<f64>() / 3.0,
            _ => 0.0,
        };
        let mut moved = proj.params.clone();
        for (k, n) in names.iter().enumerate() {
            let common = if angles.len() == 3 && angles.contains(&k) {
                turn
            } else {
                0.0
            };
            let v = moved.get(fw_spec, n)?;
            moved.set(fw_spec, n, v - (step[k] - common))?;
        }
        // About the projection's own values: no cancellation.
        let vals: Vec<f64> = written(&moved, bed)?
            .iter()
            .zip(&base)
            .map(|(a, b)| a - b)
            .collect();
        if sum.is_empty() {
            sum = vec![0.0; vals.len()];
            sq = vec![0.0; vals.len()];
        }
        for (i, v) in vals.iter().enumerate() {
            sum[i] += v;
            sq[i] += v * v;
        }
    }
    let n = draws.len().max(2) as f64;
    Ok(sum
        .iter()
        .zip(&sq)
        .map(|(s, q)| ((q - s * s / n) / (n - 1.0)).max(0.0).sqrt())
        .collect())
}

/// The nozzle's uncertainty with the firmware's values `fw_params`
/// written: over [`CUBE_DRAWS`] draws of the fitted printer, the standard
/// deviation of the nozzle's error at each point of the build volume
/// ([`build_volume`]) in the bed's frame ([`in_bed_frame`]: XY less the
/// shift and turn no part shows), as the root mean square over the points:
/// XY (the two axes' together), then Z (mm). What a print shows of the
/// values' uncertainty: values that move together (an arm length with its
/// endstop) may each have a large σ and place the nozzle well.
pub fn nozzle_sigma(
    fit: &PhysicalFit,
    fw_mech: &Mech,
    fw_params: &Params,
    fw_bed: Option<&[f64]>,
) -> Result<[f64; 2]> {
    let targets = build_volume(fit.delta.print_radius());
    let nozzle = fit.delta.nozzle();
    let mut sum = vec![[0.0; 3]; targets.len()];
    let mut sq = vec![[0.0; 3]; targets.len()];
    let draws = posterior_draws(fit, CUBE_DRAWS, CUBE_SEED)?;
    // Each draw's predictions start from the fitted printer's joints.
    let cal = &fit.study.calibration;
    let fitted = Printer {
        mech: &fit.mech,
        params: &cal.params,
        bed: &cal.measurement,
        nozzle,
    };
    let sent = Sent::new(fw_mech, fw_params, fw_bed, &targets)?;
    let (_, joints) = sent.nozzle_errors(&fitted, None)?;
    for (p, bed) in &draws {
        let at = Printer {
            params: p,
            bed,
            ..fitted
        };
        let (e, _) = sent.nozzle_errors(&at, Some(&joints))?;
        let e = in_bed_frame(&targets, &e);
        for ((s, q), e) in sum.iter_mut().zip(sq.iter_mut()).zip(&e) {
            for k in 0..3 {
                s[k] += e[k];
                q[k] += e[k] * e[k];
            }
        }
    }
    let n = draws.len().max(2) as f64;
    let var = |s: f64, q: f64| ((q - s * s / n) / (n - 1.0)).max(0.0);
    let points = targets.len().max(1) as f64;
    let (mut xy, mut z) = (0.0, 0.0);
    for (s, q) in sum.iter().zip(&sq) {
        xy += var(s[0], q[0]) + var(s[1], q[1]);
        z += var(s[2], q[2]);
    }
    Ok([(xy / points).sqrt(), (z / points).sqrt()])
}

/// The σ-beyond-limit warning of an assessment's written values
/// ([`super::uncertain`]), with the nozzle's σ they leave together
/// ([`nozzle_sigma`]); `None` when every σ is within `max_sigma`.
pub fn uncertain(a: &Assessment, max_sigma: f64) -> Result<Option<super::FirmwareWarning>> {
    if !a
        .values
        .iter()
        .any(|v| v.sigma.is_some_and(|s| s > max_sigma))
    {
        return Ok(None);
    }
    let proj = &a.choice.written;
    let fw_bed = a.delta.corrects_bed_tilt.then_some(proj.bed.as_slice());
    let nozzle = nozzle_sigma(&a.fit, &a.fw_mech, &proj.params, fw_bed)?;
    Ok(super::uncertain(&a.values, max_sigma, Some(nozzle)))
}

/// The side of the verdict's calibration cube (mm).
pub const CUBE_MM: f64 = 20.0;
/// Draws from the fit's posterior behind the cube's uncertainty.
pub const CUBE_DRAWS: usize = 64;
/// Their seed.
pub const CUBE_SEED: u64 = 1;

/// The predicted error of a printed cube: its size error in X and Y (at
/// half its height) and its top's flatness, each with its standard
/// deviation from the fit's uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CubeError {
    /// The cube's centre on the bed (mm).
    pub centre: [f64; 2],
    /// Printed minus nominal size in X and Y (mm).
    pub size: [f64; 2],
    /// Their standard deviations (mm).
    pub size_sd: [f64; 2],
    /// The top's flatness: the largest minus the smallest height error at
    /// its corners (mm).
    pub flatness: f64,
    /// Its standard deviation (mm).
    pub flatness_sd: f64,
}

/// Where the verdict's cubes stand: the centre, and the edge of the build
/// volume (the cube inside it, toward tower c).
pub fn cube_centres(ld: &LinearDelta) -> [[f64; 2]; 2] {
    let r = ld.print_radius() - CUBE_MM / std::f64::consts::SQRT_2;
    [[0.0, 0.0], [0.0, r.max(0.0)]]
}

/// The size errors (X, Y) and top flatness of a cube at `centre` printed
/// with the firmware's values on the printer `params` (mm).
#[allow(clippy::too_many_arguments)]
pub fn cube_at(
    fw_mech: &Mech,
    fw_params: &Params,
    fw_bed: Option<&[f64]>,
    mech: &Mech,
    params: &Params,
    bed: &[f64],
    nozzle: [f64; 3],
    centre: [f64; 2],
) -> Result<([f64; 2], f64)> {
    let at = Printer {
        mech,
        params,
        bed,
        nozzle,
    };
    let points = cube_points(centre);
    let sent = Sent::new(fw_mech, fw_params, fw_bed, &points)?;
    Ok(cube_of(&sent.nozzle_errors(&at, None)?.0))
}

/// The cube's points at `centre`: the middles of its four sides at half
/// its height, then its top's four corners.
pub(crate) fn cube_points(centre: [f64; 2]) -> [[f64; 3]; 8] {
    let (h, [x, y]) = (CUBE_MM / 2.0, centre);
    [
        [x - h, y, h],
        [x + h, y, h],
        [x, y - h, h],
        [x, y + h, h],
        [x - h, y - h, CUBE_MM],
        [x + h, y - h, CUBE_MM],
        [x - h, y + h, CUBE_MM],
        [x + h, y + h, CUBE_MM],
    ]
}

/// The size errors (X, Y) and top flatness from the nozzle's errors at
/// [`cube_points`].
pub(crate) fn cube_of(e: &[[f64; 3]]) -> ([f64; 2], f64) {
    let top = e[4..].iter().map(|v| v[2]);
    let flatness = top.clone().fold(f64::MIN, f64::max) - top.fold(f64::MAX, f64::min);
    ([e[1][0] - e[0][0], e[3][1] - e[2][1]], flatness)
}

/// The verdict's cubes ([`cube_centres`]) printed with the firmware's
/// values `fw_params` on the fitted printer: each error at the fit's
/// values, its standard deviation from [`CUBE_DRAWS`] draws of the free
/// parameters from the fit's covariance.
pub fn cube_errors(
    fit: &PhysicalFit,
    fw_mech: &Mech,
    fw_params: &Params,
    fw_bed: Option<&[f64]>,
) -> Result<Vec<CubeError>> {
    let cal = &fit.study.calibration;
    let nozzle = fit.delta.nozzle();
    let draws = posterior_draws(fit, CUBE_DRAWS, CUBE_SEED)?;
    cube_centres(&fit.delta)
        .into_iter()
        .map(|centre| {
            let fitted = Printer {
                mech: &fit.mech,
                params: &cal.params,
                bed: &cal.measurement,
                nozzle,
            };
            let points = cube_points(centre);
            let sent = Sent::new(fw_mech, fw_params, fw_bed, &points)?;
            let (e, joints) = sent.nozzle_errors(&fitted, None)?;
            let (size, flatness) = cube_of(&e);
            let mut sum = [0.0; 3];
            let mut sq = [0.0; 3];
            for (p, bed) in &draws {
                let at = Printer {
                    params: p,
                    bed,
                    ..fitted
                };
                // From the fitted printer's joints at the same commands.
                let (s, f) = cube_of(&sent.nozzle_errors(&at, Some(&joints))?.0);
                for (k, v) in [s[0], s[1], f].into_iter().enumerate() {
                    sum[k] += v;
                    sq[k] += v * v;
                }
            }
            let n = draws.len().max(2) as f64;
            let sd: Vec<f64> = (0..3)
                .map(|k| ((sq[k] - sum[k] * sum[k] / n) / (n - 1.0)).max(0.0).sqrt())
                .collect();
            Ok(CubeError {
                centre,
                size,
                size_sd: [sd[0], sd[1]],
                flatness,
                flatness_sd: sd[2],
            })
        })
        .collect()
}

/// A printer's physical calibration: the fit, the firmware's values chosen
/// for the nozzle, and what the verdict says of them (every front end's
/// `--physical`).
pub struct Assessment {
    /// The printer as built, where it started.
    pub delta: LinearDelta,
    /// The firmware's description.
    pub fw_mech: Mech,
    /// The firmware's own fit of the probe.
    pub own: super::PrinterCalibration,
    /// The physical fit.
    pub fit: PhysicalFit,
    /// The values written: the projection or the firmware's own fit.
    pub choice: Choice,
    /// The nozzle's error over the build volume with the current values.
    pub before: ErrorSummary,
    /// The probe heights' errors of the physical fit, before and after.
    pub heights: [Vec<f64>; 2],
    /// The predicted cubes with the values written ([`cube_centres`]).
    pub cubes: Vec<CubeError>,
    /// The values written, with their σ.
    pub values: Vec<super::FirmwareValue>,
}

impl Assessment {
    /// The bed tilt the firmware applies with the written values, where it
    /// applies one.
    pub fn fw_bed(&self) -> Option<&[f64]> {
        self.delta
            .corrects_bed_tilt
            .then_some(self.choice.written.bed.as_slice())
    }
}

/// The height map's mesh on `firmware`'s printer with `mesh_points`
/// nodes across (a user's count, else the printer's own or pkmcal's),
/// over its build volume; `None` for a printer that is not a linear delta
/// or keeps no map. Checked before a fit: a count the mesh cannot take is
/// refused before any work.
pub fn mesh_layout(
    firmware: &dyn Firmware,
    mesh_points: Option<usize>,
) -> Result<Option<super::height_map::MeshLayout>> {
    match firmware.linear_delta()? {
        Some(ld) => firmware.mesh_layout(ld.print_radius(), mesh_points),
        None => Ok(None),
    }
}

/// Fit `firmware`'s printer as built (`request`: the free set, the
/// tolerances, the probe's stated noise), project onto the firmware's
/// values, choose what to write and predict its cubes; `None` for a
/// printer that is not a linear delta.
pub fn assess(
    firmware: &dyn Firmware,
    request: Request,
    touches: Option<&super::physical_heights::Touches>,
) -> Result<Option<Assessment>> {
    let Some(ld) = firmware.linear_delta()? else {
        return Ok(None);
    };
    let fw_mech = firmware.mechanism()?;
    let fw_spec = fw_mech.spec();
    let own = super::calibrate(firmware, Request::new(pkmcal::Model::Exact))?;
    let own_cal = own.calibration();
    let fit = calibrate_with(firmware, &ld, request, touches)?;
    let cal = &fit.study.calibration;
    let spec = fit.mech.spec();
    let choice = choose(&fit, &fw_mech, &own_cal.params, &own_cal.measurement)?;
    let proj = &choice.written;
    let before = ErrorSummary::of(&in_bed_frame(
        &proj.targets,
        &nozzle_errors(
            &fw_mech,
            &Params::nominal(fw_spec),
            Some(own.readings.measurement.nominal()).filter(|_| ld.corrects_bed_tilt),
            &fit.mech,
            &cal.params,
            &cal.measurement,
            ld.nozzle(),
            &proj.targets,
        )?,
    ));
    let measurement = &fit.readings.measurement;
    let poses = &fit.readings.poses;
    let heights = [
        super::probe_errors(
            &fit.mech,
            measurement,
            &Params::nominal(spec),
            measurement.nominal(),
            poses,
        )?,
        super::probe_errors(&fit.mech, measurement, &cal.params, &cal.measurement, poses)?,
    ];
    let fw_bed = ld.corrects_bed_tilt.then_some(proj.bed.as_slice());
    let cubes = cube_errors(&fit, &fw_mech, &proj.params, fw_bed)?;
    let values = written_values(firmware, &fit, &fw_mech, &choice, &own)?;
    Ok(Some(Assessment {
        delta: ld,
        fw_mech,
        own,
        fit,
        choice,
        before,
        heights,
        cubes,
        values,
    }))
}
