//! RepRapFirmware's linear delta: its `M665`/`M666` settings read as the
//! firmware runs them (`M501` and `config-override.g` followed), heights
//! probed with `G30 S-1`, and the new `M665`/`M666` lines.
//!
//! RepRapFirmware's delta (`LinearDeltaKinematics`): tower `i` stands at the
//! angle `210°, 330°, 90°` plus the `M665 X Y Z` corrections, on the circle of
//! radius `M665 R`, with the diagonal rod `M665 L` (one value or three). A
//! carriage's height for the nozzle at `(x, y, z)` is
//! `√(L_i² − (x − t_xi)² − (y − t_yi)²) + z + x·xtilt + y·ytilt` (tilts from
//! `M666 A B` in percent), and homing puts it at
//! `H + √(L_i² − R²) + E_i` (`M665 H`, `M666 X Y Z`). A probe that triggers at
//! height `zp` over `(x, y)` had the carriages at those heights for
//! `(x, y, zp)`, with the nozzle on the bed: the commands and the reading 0 of
//! a pkmcal probe. The identified geometry goes back as RepRapFirmware keeps
//! it: the homed carriage heights split into `H` and endstop adjustments of
//! mean 0 (its `NormaliseEndstopAdjustments`), the bed's tilts as `A B`.

use super::klipper::{KLIPPER_FREE, KlipperDelta, SHARED_ARM};
use super::{Firmware, FirmwareValue, Readings, TiltPlace};
use crate::csv::Csv;
use crate::error::{Error, Result};
use crate::{invalid, refuse};
use pkmcal::{Field, MeasurementModel, Params, Request, RequestError};
use std::path::{Path, PathBuf};

#[doc(hidden)] // public for the integration tests only
pub mod script;
pub use script::{MAX_EXPRESSION_DEPTH, MAX_ITERATIONS, MAX_MACRO_DEPTH};

/// RepRapFirmware's standard tower angles (degrees), before corrections.
const STANDARD_ANGLES: [f64; 3] = [210.0, 330.0, 90.0];
/// The parameters `M665`/`M666` hold: the radius, the tower angle
/// corrections, the diagonals, the endstop adjustments (with `H`), the bed
/// tilts (`all`); or, instead of the three diagonals, the one
/// [`SHARED_ARM`] of the 7- and 9-factor calibrations.
const RRF_FREE: [&str; 12] = [
    "delta_radius",
    "angle_a",
    "angle_b",
    "angle_c",
    "arm_a",
    "arm_b",
    "arm_c",
    "da",
    "db",
    "dc",
    "bed.rx",
    "bed.ry",
];

/// Towers as RepRapFirmware names them in `M665`/`M666` (and pkmcal's).
const TOWERS: [(char, &str); 3] = [('X', "a"), ('Y', "b"), ('Z', "c")];

/// A RepRapFirmware linear delta: what `M665` and `M666` set.
#[derive(Debug, Clone, PartialEq)]
pub struct RrfDelta {
    /// Diagonal rod lengths (mm), `M665 L`.
    pub diagonals: [f64; 3],
    /// Delta radius (mm), `M665 R`.
    pub radius: f64,
    /// Homed height (mm), `M665 H`.
    pub homed_height: f64,
    /// Printable radius (mm), `M665 B`.
    pub print_radius: f64,
    /// Tower angle corrections (degrees), `M665 X Y Z`.
    pub corrections: [f64; 3],
    /// Endstop adjustments (mm), `M666 X Y Z`.
    pub endstops: [f64; 3],
    /// Bed tilts (fractions: `M666 A B` / 100).
    pub tilt: [f64; 2],
}

impl Default for RrfDelta {
    /// RepRapFirmware's defaults.
    fn default() -> Self {
        Self {
            diagonals: [215.0; 3],
            radius: 105.6,
            homed_height: 240.0,
            print_radius: 80.0,
            corrections: [0.0; 3],
            endstops: [0.0; 3],
            tilt: [0.0; 2],
        }
    }
}

impl RrfDelta {
    /// The towers' positions (mm).
    pub fn towers(&self) -> [[f64; 2]; 3] {
        std::array::from_fn(|i| {
            let a = (STANDARD_ANGLES[i] + self.corrections[i]).to_radians();
            [self.radius * a.cos(), self.radius * a.sin()]
        })
    }

    /// The carriage heights (mm) for the nozzle at `p`.
    pub fn carriage_heights(&self, p: [f64; 3]) -> [f64; 3] {
        let t = self.towers();
        std::array::from_fn(|i| {
            (self.diagonals[i].powi(2) - (p[0] - t[i][0]).powi(2) - (p[1] - t[i][1]).powi(2)).sqrt()
                + p[2]
                + p[0] * self.tilt[0]
                + p[1] * self.tilt[1]
        })
    }

    /// The carriages' heights when homed (mm).
    pub fn homed_carriages(&self) -> [f64; 3] {
        std::array::from_fn(|i| {
            self.homed_height
                + (self.diagonals[i].powi(2) - self.radius.powi(2)).sqrt()
                + self.endstops[i]
        })
    }

    /// The same geometry in the form `pkmcal klipper` writes descriptions
    /// (tower angles, radius, arms; endstop errors 0).
    fn as_klipper(&self) -> KlipperDelta {
        KlipperDelta {
            radius: self.radius,
            angles: std::array::from_fn(|i| STANDARD_ANGLES[i] + self.corrections[i]),
            arms: self.diagonals,
            endstops: [0.0; 3],
            step_distances: [0.0; 3],
            probe_radius: self.print_radius,
            probes: vec![],
            distances: vec![],
        }
    }

    /// The spatial description of this printer (TOML); with `shared_arm`,
    /// one diagonal `diagonal` for the three towers (`M665 L` with one
    /// value).
    pub fn mechanism_toml(&self, shared_arm: bool) -> String {
        self.as_klipper().description_toml_with(
            "RepRapFirmware's M665/M666 by pkmcal",
            "the X, Y, Z towers",
            "RepRapFirmware",
            shared_arm,
        )
    }

    /// The bed plane's parameters (`bed.z bed.rx bed.ry`) of these tilts:
    /// the bed where the firmware's z is 0, `z = x·xtilt + y·ytilt`.
    pub fn bed(&self) -> [f64; 3] {
        [0.0, self.tilt[1].atan(), -self.tilt[0].atan()]
    }

    /// The firmware's values for identified parameters `p` and bed `bed`:
    /// the homed carriage heights move by the endstop errors, and are split
    /// into `H` and adjustments of mean 0 as RepRapFirmware does.
    pub fn identified(&self, spec: &pkmcal::Spec, p: &Params, bed: &[f64]) -> Result<Self> {
        let mut out = self.clone();
        out.radius = p.get(spec, "delta_radius")?;
        let homed = self.homed_carriages();
        let mut k = [0.0; 3];
        let shared = spec.param_index(SHARED_ARM).is_ok();
        for (i, (_, t)) in TOWERS.iter().enumerate() {
            let arm = if shared {
                p.get(spec, SHARED_ARM)?
            } else {
                p.get(spec, &format!("arm_{t}"))?
            };
            if arm.is_nan() || arm <= out.radius {
                invalid!(
                    "the identified arm_{t} = {arm:.3} mm is not longer than delta_radius = {:.3} mm; the probe data cannot support this parameter set (use fewer free parameters)",
                    out.radius
                );
            }
            out.diagonals[i] = arm;
            out.corrections[i] =
                p.get(spec, &format!("angle_{t}"))?.to_degrees() - STANDARD_ANGLES[i];
            k[i] = homed[i] + p.get(spec, &format!("d{t}"))?
                - (arm * arm - out.radius * out.radius).sqrt();
        }
        out.homed_height = k.iter().sum::<f64>() / 3.0;
        out.endstops = k.map(|v| v - out.homed_height);
        out.tilt = [-bed[2].tan(), bed[1].tan()];
        Ok(out)
    }

    /// The `M665` and `M666` lines of these values, as RepRapFirmware writes
    /// them to `config-override.g`.
    pub fn gcode(&self) -> String {
        // Fixed decimals as the firmware writes them, never `-0.000`.
        let f = |v: f64, decimals: usize| -> String {
            let t = format!("{v:.decimals$}");
            if t.trim_start_matches('-')
                .chars()
                .all(|c| c == '0' || c == '.')
            {
                t.trim_start_matches('-').to_string()
            } else {
                t
            }
        };
        let d = &self.diagonals;
        let l = if d[1] == d[0] && d[2] == d[0] {
            f(d[0], 3)
        } else {
            format!("{}:{}:{}", f(d[0], 3), f(d[1], 3), f(d[2], 3))
        };
        format!(
            "M665 L{l} R{} H{} B{} X{} Y{} Z{}\nM666 X{} Y{} Z{} A{} B{}\n",
            f(self.radius, 3),
            f(self.homed_height, 3),
            f(self.print_radius, 1),
            f(self.corrections[0], 3),
            f(self.corrections[1], 3),
            f(self.corrections[2], 3),
            f(self.endstops[0], 3),
            f(self.endstops[1], 3),
            f(self.endstops[2], 3),
            f(self.tilt[0] * 100.0, 2),
            f(self.tilt[1] * 100.0, 2)
        )
    }
}

/// The delta settings of a RepRapFirmware G-code file (`config.g`,
/// `config-override.g`), read as the firmware runs it ([`script`]): its
/// `M665` and `M666` commands in order, later ones overriding, through its
/// variables, expressions and blocks; RepRapFirmware's defaults for what no
/// command sets. A macro (`M98`, `M501`) is refused: read the file with
/// [`delta_from_config_file`], which follows them as the firmware does.
pub fn delta_from_gcode(text: &str, file: &str) -> Result<RrfDelta> {
    delta_from_text(text, Path::new(file), &mut |name, cmd| {
        Err(cmd.error(format!(
            "`{}` runs {name}, whose commands the firmware runs there; give the configuration's path so that it can be read beside it",
            cmd.text
        )))
    })
}

/// The name of the file `M501` loads, beside `config.g`.
pub const OVERRIDE_FILE: &str = "config-override.g";

/// The file a macro call names (`M98 P"name"`; `config-override.g` for
/// `M501`), for a configuration in `dir` standing for the card's `/sys`: a
/// relative name or one in `/sys` beside it; another absolute one (`/macros/
/// x.g`, `0:/macros/x.g`) in the card's folder above `dir`, when `dir` is
/// named `sys` as on the card.
fn macro_path(dir: &Path, name: &str) -> std::result::Result<PathBuf, String> {
    let name = name.trim();
    let bare = name
        .strip_prefix("0:")
        .or_else(|| name.strip_prefix("1:"))
        .unwrap_or(name);
    let Some(absolute) = bare.strip_prefix('/') else {
        return Ok(dir.join(bare));
    };
    if let Some(sys) = absolute.strip_prefix("sys/") {
        return Ok(dir.join(sys));
    }
    let on_card = dir
        .file_name()
        .is_some_and(|f| f.eq_ignore_ascii_case("sys"));
    match dir.parent() {
        Some(card) if on_card => Ok(card.join(absolute)),
        _ => Err(format!(
            "{name} is on the card outside /sys; copy the card's folders as they are (sys/ and the folder of {name}) and give the configuration as sys/{}",
            "config.g"
        )),
    }
}

/// The delta settings the firmware runs after `config.g` at `path`: its
/// `M665`/`M666` commands in order, and those of the macros it runs (`M98
/// P"file"`, and at `M501` `config-override.g`) at their place, read from
/// the configuration's folder (which stands for the card's `/sys`); later
/// commands override earlier ones. A macro that cannot be read is an error
/// naming the line and the file: the geometry would otherwise be stale and
/// undo the saved calibration.
pub fn delta_from_config_file(run: &crate::Run<'_>, path: &std::path::Path) -> Result<RrfDelta> {
    Ok(settings_from_config_file(run, path)?.0)
}

/// [`delta_from_config_file`] with the offset of Z probe 0 from the
/// nozzle the configuration gives (`G31 X Y`, as the firmware runs it).
pub fn settings_from_config_file(
    run: &crate::Run<'_>,
    path: &std::path::Path,
) -> Result<(RrfDelta, [f64; 2])> {
    let text = run
        .files
        .read_to_string(path, crate::output::InputKind::Description)?;
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let config = path.display().to_string();
    settings_from_text(&text, path, &mut |name, cmd| {
        let place = format!("{}:{}", cmd.file.display(), cmd.line);
        if cmd.code == ('M', 98) && !cmd.text.contains(['"', '{']) {
            return Err(cmd.error(format!(
                "`{}`: RepRapFirmware 3 takes a macro's name in quotes and refuses this line (version 2 ran the rest of the line as the name); write M98 P\"{name}\" if the printer runs version 2, or remove the line",
                cmd.text
            )));
        }
        let file = macro_path(&dir, name).map_err(|e| cmd.error(format!("`{}`: {e}", cmd.text)))?;
        let t = run
            .files
            .read_to_string(&file, crate::output::InputKind::Description)
            .map_err(|e| {
                e.context(if cmd.code == ('M', 501) {
                    format!(
                        "{place}: M501 loads {OVERRIDE_FILE}, which holds the calibration the firmware runs, but {} cannot be read; copy it from the printer's /sys folder beside {config}, or remove the M501 line if the printer has none",
                        file.display()
                    )
                } else {
                    format!(
                        "{place}: `{}` runs {}, whose commands may set the delta's geometry, but it cannot be read; copy it from the printer's card beside {config} as the card holds it, or remove the line if the printer has no such file",
                        cmd.text,
                        file.display()
                    )
                })
            })?;
        Ok((t, file))
    })
}

/// The text and path of the macro a command runs (by the name it gives).
type OpenMacro<'a> = dyn FnMut(&str, &script::Command<'_>) -> Result<(String, PathBuf)> + 'a;

/// The commands of a run that set the delta: `M665` and `M666`.
struct Settings<'a> {
    delta: RrfDelta,
    /// Whether any was run.
    seen: bool,
    /// The X and Y offsets of Z probe 0 from the nozzle (`G31 X Y`, its
    /// last), the probe's trigger point at the nozzle's plus these.
    probe_offset: [f64; 2],
    /// The macro files, by name.
    open: &'a mut OpenMacro<'a>,
}

impl script::Host for Settings<'_> {
    fn reads(&self, code: (char, u32)) -> bool {
        matches!(code, ('M', 665 | 666) | ('G', 31))
    }

    fn command(&mut self, cmd: &script::Command<'_>) -> Result<()> {
        if !self.reads(cmd.code) {
            return Ok(());
        }
        if cmd.code == ('G', 31) {
            return probe_offset(&mut self.probe_offset, cmd);
        }
        self.seen = true;
        apply(&mut self.delta, cmd)
    }

    fn open(&mut self, name: &str, cmd: &script::Command<'_>) -> Result<(String, PathBuf)> {
        (self.open)(name, cmd)
    }
}

/// The largest probe offset from the nozzle a `G31` may give (mm).
const MAX_PROBE_OFFSET_MM: f64 = 1e3;

/// Apply a `G31` command to the offset of Z probe 0 (`K0`, or no `K`: the
/// probe `G30` uses unless told): its `X` and `Y`, each read as the
/// firmware reads it, set what they give (the probe's trigger point at the
/// nozzle's position plus them: RepRapFirmware moves the nozzle to a probe
/// point less the offset); another probe's is left.
fn probe_offset(offset: &mut [f64; 2], cmd: &script::Command<'_>) -> Result<()> {
    if let Some((k, word)) = cmd.floats('K')?
        && k.first().is_some_and(|k| *k != 0.0)
    {
        let _ = word;
        return Ok(());
    }
    for (i, letter) in ['X', 'Y'].into_iter().enumerate() {
        let Some((values, word)) = cmd.floats(letter)? else {
            continue;
        };
        match values.as_slice() {
            [v] if v.is_finite() && v.abs() <= MAX_PROBE_OFFSET_MM => offset[i] = *v,
            [v] => {
                return Err(cmd.error(format!(
                    "`{word}` in `{}`: the probe's {letter} offset {v} mm is beyond what a printer holds (at most {MAX_PROBE_OFFSET_MM} mm in size)",
                    cmd.text
                )));
            }
            _ => return Err(cmd.error(format!("`{word}`: {letter} takes one value, not a list"))),
        }
    }
    Ok(())
}

/// Apply an `M665` or `M666` command to `d`, each parameter read as the
/// firmware reads it (the first of a letter); what the firmware could not
/// hold refused with its line.
fn apply(d: &mut RrfDelta, cmd: &script::Command<'_>) -> Result<()> {
    if cmd.has_parenthesis() {
        return Err(cmd.error(format!(
            "`{}`: RepRapFirmware (in its 3D printer mode) reads the letters inside ( ) as parameters, not as a comment; use a `;` comment at the end of the line",
            cmd.text
        )));
    }
    let m665 = cmd.code == ('M', 665);
    let letters: &[char] = if m665 {
        &['L', 'R', 'H', 'B', 'X', 'Y', 'Z']
    } else {
        &['X', 'Y', 'Z', 'A', 'B']
    };
    for &letter in letters {
        let Some((values, word)) = cmd.floats(letter)? else {
            continue;
        };
        // What the firmware could hold: lengths within 100 m, angle
        // corrections within a turn, tilts within 100 %.
        let limit = match (m665, letter) {
            (true, 'X' | 'Y' | 'Z') => 360.0,
            (false, 'A' | 'B') => 100.0,
            _ => 1e5,
        };
        if let Some(v) = values.iter().find(|v| !(v.is_finite() && v.abs() <= limit)) {
            return Err(cmd.error(format!(
                "`{word}` in `{}`: {letter} = {v} is beyond what a printer holds (at most {limit} in size)",
                cmd.text
            )));
        }
        let one = || -> Result<f64> {
            if values.len() == 1 {
                Ok(values[0])
            } else {
                Err(cmd.error(format!("`{word}`: {letter} takes one value, not a list")))
            }
        };
        match (m665, letter) {
            (true, 'L') => {
                d.diagonals = match values.len() {
                    1 => [values[0]; 3],
                    3 => [values[0], values[1], values[2]],
                    _ => {
                        return Err(cmd.error(
                            "M665 L takes one diagonal or three (L215:215.2:214.9); more towers are not supported",
                        ));
                    }
                }
            }
            (true, 'R') => d.radius = one()?,
            (true, 'H') => d.homed_height = one()?,
            (true, 'B') => d.print_radius = one()?,
            (true, 'X') => d.corrections[0] = one()?,
            (true, 'Y') => d.corrections[1] = one()?,
            (true, 'Z') => d.corrections[2] = one()?,
            (false, 'X') => d.endstops[0] = one()?,
            (false, 'Y') => d.endstops[1] = one()?,
            (false, 'Z') => d.endstops[2] = one()?,
            (false, 'A') => d.tilt[0] = one()? * 0.01,
            (false, 'B') => d.tilt[1] = one()? * 0.01,
            _ => {}
        }
    }
    Ok(())
}

/// The run of [`delta_from_gcode`]: `open(name, command)` gives the text
/// and path of the macro a command runs, or an error.
fn delta_from_text(text: &str, file: &Path, open: &mut OpenMacro<'_>) -> Result<RrfDelta> {
    Ok(settings_from_text(text, file, open)?.0)
}

/// The run of [`delta_from_text`], with the offset of Z probe 0 from the
/// nozzle (`G31 X Y`; 0, 0 where none is given, the firmware's default).
fn settings_from_text(
    text: &str,
    file: &Path,
    open: &mut OpenMacro<'_>,
) -> Result<(RrfDelta, [f64; 2])> {
    let mut settings = Settings {
        delta: RrfDelta::default(),
        seen: false,
        probe_offset: [0.0, 0.0],
        open,
    };
    script::run(text, file, &mut settings)?;
    let d = settings.delta;
    if !settings.seen {
        refuse!(
            file,
            None,
            "no M665 or M666 line; give the file that sets the delta's geometry (config.g, or config-override.g after M500)"
        );
    }
    if !(d.radius > 0.0 && d.diagonals.iter().all(|l| *l > d.radius) && d.print_radius > 0.0) {
        refuse!(
            file,
            None,
            "M665 needs a positive delta radius R, diagonals L longer than R and a positive print radius B (got R{} L{:?} B{})",
            d.radius,
            d.diagonals,
            d.print_radius
        );
    }
    Ok((d, settings.probe_offset))
}

/// A RepRapFirmware printer: the configuration's path, its delta as the
/// firmware runs it, and the probe results (`x`, `y` where the probe
/// touched, `z` where it triggered, as `G30 S-1` reports them).
pub struct RrfPrinter {
    /// The configuration (`config.g`, or `config-override.g`).
    pub config: PathBuf,
    /// The delta it sets.
    pub delta: RrfDelta,
    /// The probe file.
    pub probes: PathBuf,
    /// Each probe point `(x, y, z)` and its line.
    pub points: Vec<([f64; 3], u64)>,
    /// One diagonal for the three towers (`M665 L` with one value), fitted
    /// as one.
    pub shared_arm: bool,
    /// The offset of Z probe 0 from the nozzle (mm, `G31 X Y`): the
    /// physical model's probe ([`Firmware::physical_readings`]).
    pub probe_offset: [f64; 2],
}

/// The parameters `M665`/`M666` hold: the radius, the tower angle
/// corrections, the diagonals, the endstop adjustments (with `H`), the bed
/// tilts; or, instead of the three diagonals, the one [`SHARED_ARM`].
pub fn rrf_holds() -> Vec<String> {
    RRF_FREE
        .iter()
        .map(|s| s.to_string())
        .chain(std::iter::once(SHARED_ARM.to_string()))
        .collect()
}

impl RrfPrinter {
    /// The readings with the nozzle at each probe point less `offset` (the
    /// probe's offset from the nozzle: RepRapFirmware moves the nozzle so
    /// for `G30 P… X… Y…`); the firmware's own fit takes the probe at the
    /// nozzle.
    fn readings_with(&self, spec: &pkmcal::Spec, offset: [f64; 2]) -> Result<Readings> {
        let poses = self
            .points
            .iter()
            .enumerate()
            .map(|(i, (p, line))| pkmcal::Measurement {
                point: None,
                target: None,
                commands: self
                    .delta
                    .carriage_heights([p[0] - offset[0], p[1] - offset[1], p[2]])
                    .to_vec(),
                partner: None,
                measured: vec![0.0],
                sigma: vec![],
                origin: Some(pkmcal::Origin {
                    pose: i + 1,
                    line: Some(*line),
                    distance: false,
                }),
            })
            .collect();
        let bed = self.delta.bed();
        Ok(Readings {
            measurement: MeasurementModel::probe(spec)?.with_own(&bed)?,
            poses,
            distances: vec![],
        })
    }

    /// Read the configuration as the firmware runs it and the probe
    /// results; `free` (the names a user gives) says whether the shared
    /// diagonal is fitted. A probe point the printer cannot reach is
    /// refused with the geometry.
    pub fn read(
        run: &crate::Run<'_>,
        config: &Path,
        probes: &Path,
        free: Option<&[String]>,
    ) -> Result<Self> {
        let (delta, probe_offset) = settings_from_config_file(run, config)?;
        let csv = Csv::read(run, probes)?;
        csv.require_rows()?;
        let points = csv.named(&["x".to_string(), "y".to_string(), "z".to_string()])?;
        // The shared diagonal: one `M665 L` for the three towers, fitted as one.
        let given: Vec<&str> = free.unwrap_or_default().iter().map(|s| s.trim()).collect();
        let shared_arm = given.contains(&SHARED_ARM);
        if shared_arm {
            if let Some(n) = given.iter().find(|n| n.starts_with("arm_") || **n == "all") {
                return Err(RequestError::invalid(
                    Field::Free,
                    format!(
                        "`{SHARED_ARM}` (one diagonal for the three towers) and `{n}` exclude each other; free either the shared diagonal or the three arm_a, arm_b, arm_c"
                    ),
                )
                .into());
            }
            if delta.diagonals.iter().any(|l| *l != delta.diagonals[0]) {
                return Err(RequestError::invalid(
                    Field::Free,
                    format!(
                        "`{SHARED_ARM}` fits one diagonal for the three towers, but {} sets three (L{}:{}:{}); free arm_a, arm_b, arm_c instead",
                        config.display(),
                        delta.diagonals[0],
                        delta.diagonals[1],
                        delta.diagonals[2]
                    ),
                )
                .into());
            }
        }
        // A probe point the printer of these M665/M666 values cannot reach
        // (a diagonal shorter than the distance to its tower) is named here,
        // with the geometry, not later as a command of NaN.
        for (i, p) in points.iter().enumerate() {
            if delta
                .carriage_heights([p[0], p[1], p[2]])
                .iter()
                .any(|h| !h.is_finite())
            {
                refuse!(
                    probes,
                    Some(csv.line(i)),
                    "the probe point ({}, {}) is out of reach of the printer {} describes (diagonals {:?} mm, radius {} mm{}); check the file or the probe points",
                    p[0],
                    p[1],
                    config.display(),
                    delta.diagonals,
                    delta.radius,
                    if delta.diagonals == RrfDelta::default().diagonals
                        && delta.radius == RrfDelta::default().radius
                    {
                        ": RepRapFirmware's defaults, as if no M665 set them"
                    } else {
                        ""
                    }
                );
            }
        }
        Ok(RrfPrinter {
            config: config.to_path_buf(),
            delta,
            probes: probes.to_path_buf(),
            points: points
                .iter()
                .enumerate()
                .map(|(i, p)| ([p[0], p[1], p[2]], csv.line(i)))
                .collect(),
            shared_arm,
            probe_offset,
        })
    }
}

impl Firmware for RrfPrinter {
    fn tilt_place(&self) -> TiltPlace {
        TiltPlace::Values {
            values: "M666 A B",
            free: vec!["bed.rx".into(), "bed.ry".into()],
        }
    }

    fn flavour(&self) -> super::Flavour {
        super::Flavour::RepRapFirmware
    }

    fn description(&self) -> String {
        self.delta.mechanism_toml(self.shared_arm)
    }

    fn readings(&self, spec: &pkmcal::Spec) -> Result<Readings> {
        self.readings_with(spec, [0.0, 0.0])
    }

    fn physical_readings(&self, spec: &pkmcal::Spec) -> Result<Readings> {
        self.readings_with(spec, self.probe_offset)
    }

    fn default_free(&self, _spec: &pkmcal::Spec, _readings: &Readings) -> Vec<String> {
        KLIPPER_FREE.map(String::from).to_vec()
    }

    fn holds(&self) -> Option<Vec<String>> {
        Some(rrf_holds())
    }

    fn configure(&self, request: &mut Request, _readings: &Readings) {
        // As many probe points as factors are solved exactly, as the
        // firmware solves them.
        request.exactly_determined = true;
        // `all` is every parameter M665/M666 hold.
        if let Some(free) = &mut request.free {
            let expanded: Vec<String> = free
                .iter()
                .flat_map(|n| {
                    if n.trim() == "all" {
                        RRF_FREE.iter().map(|s| s.to_string()).collect()
                    } else {
                        vec![n.clone()]
                    }
                })
                .collect();
            *free = expanded;
        }
    }

    fn check_free(&self, names: &[String]) -> std::result::Result<(), RequestError> {
        if let Some(n) = names
            .iter()
            .find(|n| !RRF_FREE.contains(&n.as_str()) && *n != SHARED_ARM)
        {
            return Err(RequestError::invalid(
                Field::Free,
                format!(
                    "`{n}` has no place in M665/M666, so RepRapFirmware could not run what the fit finds{}; the parameters they hold are {}",
                    if n == "bed.z" {
                        " (a bed height is the endstops' common shift: da, db, dc take it)"
                    } else {
                        ""
                    },
                    RRF_FREE.join(", ")
                        + ", or "
                        + SHARED_ARM
                        + " (one diagonal for the three towers)"
                ),
            ));
        }
        Ok(())
    }

    fn values(
        &self,
        spec: &pkmcal::Spec,
        params: &Params,
        instrument: &[f64],
    ) -> Result<Vec<FirmwareValue>> {
        let new = self.delta.identified(spec, params, instrument)?;
        let old = &self.delta;
        let mut out = vec![];
        let mut push = |name: String, a: f64, b: f64, unit: &'static str| {
            out.push(FirmwareValue {
                name,
                before: a,
                after: b,
                unit,
                sigma: None,
            })
        };
        for (i, (w, _)) in TOWERS.iter().enumerate() {
            push(
                format!("M665 L ({w})"),
                old.diagonals[i],
                new.diagonals[i],
                "mm",
            );
        }
        push("M665 R".into(), old.radius, new.radius, "mm");
        push("M665 H".into(), old.homed_height, new.homed_height, "mm");
        for (i, (w, _)) in TOWERS.iter().enumerate() {
            push(
                format!("M665 {w}"),
                old.corrections[i],
                new.corrections[i],
                "°",
            );
        }
        for (i, (w, _)) in TOWERS.iter().enumerate() {
            push(format!("M666 {w}"), old.endstops[i], new.endstops[i], "mm");
        }
        push(
            "M666 A".into(),
            old.tilt[0] * 100.0,
            new.tilt[0] * 100.0,
            "%",
        );
        push(
            "M666 B".into(),
            old.tilt[1] * 100.0,
            new.tilt[1] * 100.0,
            "%",
        );
        Ok(out)
    }

    fn updated(&self, spec: &pkmcal::Spec, params: &Params, instrument: &[f64]) -> Result<String> {
        Ok(self.delta.identified(spec, params, instrument)?.gcode())
    }

    fn linear_delta(&self) -> Result<Option<super::physical::LinearDelta>> {
        Ok(Some(super::physical::LinearDelta {
            delta: self.delta.as_klipper(),
            // The probe file gives where the probe touched; the nozzle was
            // at that less G31's offset.
            probe_offset: self.probe_offset,
            firmware: super::Flavour::RepRapFirmware,
            values: rrf_holds(),
            corrects_bed_tilt: true,
            print_radius: self.delta.print_radius,
            // The probe file's heights are 0 where the probe meets the bed.
            probe_height: 0.0,
            homed_height: self.delta.homed_height,
        }))
    }

    fn mesh_layout(
        &self,
        radius: f64,
        count: Option<usize>,
    ) -> Result<Option<super::height_map::MeshLayout>> {
        use super::height_map::{MESH_POINTS, MeshFormat, MeshLayout, round_count};
        MeshLayout::round(MeshFormat::RepRap, radius, round_count(count, MESH_POINTS)?).map(Some)
    }

    fn located(&self, e: pkmcal::Error) -> Error {
        Error::located(e, &self.probes)
    }
}
