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
/// `config-override.g`): every `M665` and `M666` in order, later ones
/// overriding, other lines ignored; RepRapFirmware's defaults for what no
/// line sets. `M501` (load `config-override.g`) is refused: read the file
/// with [`delta_from_config_file`], which follows it as the firmware does.
pub fn delta_from_gcode(text: &str, file: &str) -> Result<RrfDelta> {
    delta_from_text(text, file, &mut |n| {
        refuse!(
            file,
            Some((n) as u64),
            "M501 loads config-override.g, whose M665/M666 values the firmware runs; give the configuration's path so that it can be read beside it"
        )
    })
}

/// The name of the file `M501` loads, beside `config.g`.
pub const OVERRIDE_FILE: &str = "config-override.g";

/// The delta settings the firmware runs after `config.g` at `path`: its
/// `M665`/`M666` lines in order, and at an `M501` line those of
/// `config-override.g` in the same folder (as RepRapFirmware loads it from
/// `/sys`), later lines overriding earlier ones. A missing
/// `config-override.g` after `M501` is an error naming both: the geometry
/// would otherwise be stale and undo the saved calibration.
pub fn delta_from_config_file(run: &crate::Run<'_>, path: &std::path::Path) -> Result<RrfDelta> {
    let text = run
        .files
        .read_to_string(path, crate::output::InputKind::Description)?;
    let file = path.display().to_string();
    let override_path = path
        .parent()
        .unwrap_or(std::path::Path::new("."))
        .join(OVERRIDE_FILE);
    delta_from_text(&text, &file, &mut |n| {
        if path.file_name().is_some_and(|f| f == OVERRIDE_FILE) {
            refuse!(
                file,
                Some((n) as u64),
                "M501 inside {OVERRIDE_FILE} itself; remove that line"
            );
        }
        let t = run
            .files
            .read_to_string(&override_path, crate::output::InputKind::Description)
            .map_err(|e| {
                e.context(format!(
                    "{file}:{n}: M501 loads {OVERRIDE_FILE}, which holds the calibration the firmware runs, but {} cannot be read; copy it from the printer's /sys folder beside {file}, or remove the M501 line if the printer has none",
                    override_path.display()
                ))
            })?;
        Ok(Some((t, override_path.display().to_string())))
    })
}

/// The walk of [`delta_from_gcode`]: `m501(line)` gives the text and name
/// of the file `M501` loads (its lines applied at that line), or an error.
fn delta_from_text(
    text: &str,
    file: &str,
    m501: &mut dyn FnMut(usize) -> Result<Option<(String, String)>>,
) -> Result<RrfDelta> {
    let mut d = RrfDelta::default();
    let seen = apply_lines(&mut d, text, file, m501, &mut Globals::new())?;
    if !seen {
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
    Ok(d)
}

/// The words of a G-code line, as the firmware reads them with or without
/// spaces between them (`M665 L361 R180` and `M665L361R180`): a letter
/// starts a word, its number runs to the next letter.
fn words_of(line: &str) -> Vec<String> {
    let mut out: Vec<String> = vec![];
    let chars: Vec<char> = line.chars().collect();
    for (i, &c) in chars.iter().enumerate() {
        // An exponent (`1e3`) stays in its number, to be refused there.
        let exponent = matches!(c, 'e' | 'E')
            && i > 0
            && chars[i - 1].is_ascii_digit()
            && chars
                .get(i + 1)
                .is_some_and(|n| n.is_ascii_digit() || *n == '-' || *n == '+');
        if c.is_ascii_alphabetic() && !exponent {
            out.push(c.to_string());
        } else if c.is_whitespace() {
            continue;
        } else if let Some(w) = out.last_mut() {
            w.push(c);
        } else {
            out.push(c.to_string());
        }
    }
    // `M665`: the code is a letter and its digits, like any word.
    out
}

/// RepRapFirmware 3's global variables met so far: a number, or why the
/// expression that set it is not one pkmcal evaluates.
type Globals = std::collections::HashMap<String, std::result::Result<f64, String>>;

/// The `{…}` expressions of a G-code line replaced by their values (at full
/// precision), or why one cannot be evaluated.
fn substitute(line: &str, globals: &Globals) -> std::result::Result<String, String> {
    let mut out = String::with_capacity(line.len());
    let mut rest = line;
    while let Some(open) = rest.find('{') {
        out.push_str(&rest[..open]);
        let Some(close) = rest[open..].find('}') else {
            return Err(format!("`{}` has no closing brace", &rest[open..]));
        };
        let expr = &rest[open + 1..open + close];
        let v = eval(expr, globals)?;
        out.push_str(&format!("{v:?}"));
        rest = &rest[open + close + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// The value of a RepRapFirmware expression as far as pkmcal evaluates
/// one: numbers, `global.` variables set to numbers, `+ - * /` and
/// parentheses. Anything else (the object model, `var`, functions, strings)
/// is refused by name: the firmware's value is not known here.
fn eval(expr: &str, globals: &Globals) -> std::result::Result<f64, String> {
    struct P<'a> {
        s: &'a [u8],
        i: usize,
        globals: &'a Globals,
        expr: &'a str,
    }
    impl P<'_> {
        fn ws(&mut self) {
            while self.s.get(self.i).is_some_and(u8::is_ascii_whitespace) {
                self.i += 1;
            }
        }
        fn sum(&mut self) -> std::result::Result<f64, String> {
            let mut v = self.product()?;
            loop {
                self.ws();
                match self.s.get(self.i) {
                    Some(b'+') => {
                        self.i += 1;
                        v += self.product()?;
                    }
                    Some(b'-') => {
                        self.i += 1;
                        v -= self.product()?;
                    }
                    _ => return Ok(v),
                }
            }
        }
        fn product(&mut self) -> std::result::Result<f64, String> {
            let mut v = self.unary()?;
            loop {
                self.ws();
                match self.s.get(self.i) {
                    Some(b'*') => {
                        self.i += 1;
                        v *= self.unary()?;
                    }
                    Some(b'/') => {
                        self.i += 1;
                        v /= self.unary()?;
                    }
                    _ => return Ok(v),
                }
            }
        }
        fn unary(&mut self) -> std::result::Result<f64, String> {
            self.ws();
            match self.s.get(self.i) {
                Some(b'-') => {
                    self.i += 1;
                    Ok(-self.unary()?)
                }
                Some(b'+') => {
                    self.i += 1;
                    self.unary()
                }
                Some(b'(') => {
                    self.i += 1;
                    let v = self.sum()?;
                    self.ws();
                    if self.s.get(self.i) != Some(&b')') {
                        return Err(format!("`{}`: a `(` is not closed", self.expr));
                    }
                    self.i += 1;
                    Ok(v)
                }
                Some(c) if c.is_ascii_digit() || *c == b'.' => {
                    let start = self.i;
                    while self
                        .s
                        .get(self.i)
                        .is_some_and(|c| c.is_ascii_digit() || *c == b'.')
                    {
                        self.i += 1;
                    }
                    let t = std::str::from_utf8(&self.s[start..self.i]).unwrap_or("");
                    t.parse()
                        .map_err(|_| format!("`{}`: `{t}` is not a number", self.expr))
                }
                Some(c) if c.is_ascii_alphabetic() || *c == b'_' => {
                    let start = self.i;
                    while self.s.get(self.i).is_some_and(|c| {
                        c.is_ascii_alphanumeric() || matches!(c, b'_' | b'.' | b'[' | b']')
                    }) {
                        self.i += 1;
                    }
                    let name = std::str::from_utf8(&self.s[start..self.i]).unwrap_or("");
                    match name.strip_prefix("global.") {
                        Some(g) => match self.globals.get(g) {
                            Some(Ok(v)) => Ok(*v),
                            Some(Err(why)) => Err(format!(
                                "`{name}` cannot be evaluated where it is set: {why}"
                            )),
                            None => Err(format!(
                                "`{name}` is used before any `global {g} = …` sets it"
                            )),
                        },
                        None => Err(format!(
                            "`{name}` in `{}` is the firmware's own state (its object model or a local variable), whose value pkmcal cannot know; write the number there",
                            self.expr
                        )),
                    }
                }
                _ => Err(format!(
                    "`{}` is not an expression pkmcal evaluates (numbers, global variables, + - * / and parentheses); write the number there",
                    self.expr
                )),
            }
        }
    }
    let mut p = P {
        s: expr.as_bytes(),
        i: 0,
        globals,
        expr,
    };
    let v = p.sum()?;
    p.ws();
    if p.i != p.s.len() {
        return Err(format!(
            "`{expr}` is not an expression pkmcal evaluates (numbers, global variables, + - * / and parentheses); write the number there"
        ));
    }
    if !v.is_finite() {
        return Err(format!("`{expr}` is not a finite number"));
    }
    Ok(v)
}

/// Apply the `M665`/`M666` lines of `text` to `d` in order (and, at `M501`,
/// those of the file `m501` loads); whether any was found.
fn apply_lines(
    d: &mut RrfDelta,
    text: &str,
    file: &str,
    m501: &mut dyn FnMut(usize) -> Result<Option<(String, String)>>,
    globals: &mut Globals,
) -> Result<bool> {
    let mut seen = false;
    for (n, raw) in text.lines().enumerate() {
        // A byte-order mark, a line number (`N10`) and a checksum (`*71`)
        // are not part of the command.
        let raw = if n == 0 {
            raw.trim_start_matches('\u{feff}')
        } else {
            raw
        };
        let line = raw.split(';').next().unwrap_or("").trim();
        // A checksum is `*` and digits at the end; a `*` elsewhere
        // multiplies in an expression.
        let line = match line.rsplit_once('*') {
            Some((head, sum))
                if !sum.trim().is_empty() && sum.trim().chars().all(|c| c.is_ascii_digit()) =>
            {
                head.trim()
            }
            _ => line,
        };
        // RepRapFirmware 3's variables: `global name = expression` and
        // `set global.name = expression`, used as `{global.name}` in a
        // parameter.
        if let Some(rest) = line
            .strip_prefix("global ")
            .or_else(|| line.strip_prefix("set global."))
        {
            if let Some((name, expr)) = rest.split_once('=') {
                globals.insert(name.trim().to_string(), eval(expr.trim(), globals));
            }
            continue;
        }
        let substituted;
        let line = if line.contains('{') {
            substituted = substitute(line, globals)
                .map_err(|e| Error::at(Path::new(file), Some(n as u64 + 1), e))?;
            substituted.as_str()
        } else {
            line
        };
        let owned = words_of(line);
        let mut words = owned.iter().map(String::as_str);
        let mut code = words.next().unwrap_or("").to_ascii_uppercase();
        if code.starts_with('N') && code[1..].chars().all(|c| c.is_ascii_digit()) {
            code = words.next().unwrap_or("").to_ascii_uppercase();
        }
        if code.is_empty() {
            continue;
        }
        if code == "M501" {
            if let Some((t, f)) = m501(n + 1)? {
                seen |= apply_lines(
                    d,
                    &t,
                    &f,
                    &mut |k| {
                        refuse!(
                            f,
                            Some((k) as u64),
                            "M501 inside {OVERRIDE_FILE} itself; remove that line"
                        )
                    },
                    globals,
                )?;
            }
            continue;
        }
        if code != "M665" && code != "M666" {
            continue;
        }
        seen = true;
        for w in words {
            let mut chars = w.chars();
            let Some(letter) = chars.next().map(|c| c.to_ascii_uppercase()) else {
                continue;
            };
            let value = chars.as_str();
            let bad = || {
                Error::at(
                    Path::new(file),
                    Some(n as u64 + 1),
                    format!(
                        "`{w}` in `{line}`: the value of {letter} must be a number{}",
                        if letter == 'L' {
                            " or three separated by ':'"
                        } else {
                            ""
                        }
                    ),
                )
            };
            let number = |v: &str| -> Result<f64> {
                v.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(bad)
            };
            // What the firmware could hold: lengths within 100 m, angle
            // corrections within a turn, tilts within 100 %.
            let limit = match (code.as_str(), letter) {
                ("M665", 'X' | 'Y' | 'Z') => 360.0,
                ("M666", 'A' | 'B') => 100.0,
                _ => 1e5,
            };
            let number = |v: &str| -> Result<f64> {
                let x = number(v)?;
                if x.abs() > limit {
                    refuse!(
                        file,
                        Some((n + 1) as u64),
                        "`{w}` in `{line}`: {letter} = {v} is beyond what a printer holds (at most {limit} in size)"
                    );
                }
                Ok(x)
            };
            match (code.as_str(), letter) {
                ("M665", 'L') => {
                    let v: Vec<f64> = value.split(':').map(number).collect::<Result<_>>()?;
                    d.diagonals = match v.len() {
                        1 => [v[0]; 3],
                        3 => [v[0], v[1], v[2]],
                        _ => refuse!(
                            file,
                            Some((n + 1) as u64),
                            "M665 L takes one diagonal or three (L215:215.2:214.9); more towers are not supported"
                        ),
                    };
                }
                ("M665", 'R') => d.radius = number(value)?,
                ("M665", 'H') => d.homed_height = number(value)?,
                ("M665", 'B') => d.print_radius = number(value)?,
                ("M665", 'X') => d.corrections[0] = number(value)?,
                ("M665", 'Y') => d.corrections[1] = number(value)?,
                ("M665", 'Z') => d.corrections[2] = number(value)?,
                ("M666", 'X') => d.endstops[0] = number(value)?,
                ("M666", 'Y') => d.endstops[1] = number(value)?,
                ("M666", 'Z') => d.endstops[2] = number(value)?,
                ("M666", 'A') => d.tilt[0] = number(value)? * 0.01,
                ("M666", 'B') => d.tilt[1] = number(value)? * 0.01,
                _ => {}
            }
        }
    }
    Ok(seen)
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
        let delta = delta_from_config_file(run, config)?;
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

    fn name(&self) -> &'static str {
        "RepRapFirmware"
    }

    fn description(&self) -> String {
        self.delta.mechanism_toml(self.shared_arm)
    }

    fn readings(&self, spec: &pkmcal::Spec) -> Result<Readings> {
        let poses = self
            .points
            .iter()
            .enumerate()
            .map(|(i, (p, line))| pkmcal::Measurement {
                target: None,
                commands: self.delta.carriage_heights(*p).to_vec(),
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

    fn located(&self, e: pkmcal::Error) -> Error {
        Error::located(e, &self.probes)
    }
}
