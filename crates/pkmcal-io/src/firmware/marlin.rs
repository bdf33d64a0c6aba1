//! Marlin's linear delta: the settings `M503` prints (`M665`, `M666`,
//! `M851`), heights probed with `G30` (or `G29 V3`), the heights a verbose
//! `G33` prints, and the new `M665`/`M666` lines.
//!
//! Marlin's delta (`delta.cpp`): tower `i` stands at `210°, 330°, 90°` plus
//! the angle trims `M665 X Y Z`, on the circle of radius `M665 R`; its
//! diagonal rod is `M665 L` plus the tower's rod trim (`M665 A B C`, in the
//! versions that have them). A carriage's position for the nozzle at
//! `(x, y, z)` is `z + √(rod_i² − (x − t_xi)² − (y − t_yi)²)`. Homing puts
//! every carriage at its endstop, moves it by its endstop adjustment
//! (`M666 X Y Z`, ≤ 0: the carriage goes down that far; a positive one is
//! skipped, and Marlin 2 refuses it), and calls that position
//! `H + √(rod_i² − R²)` (`M665 H`). The probe reports the height of its
//! trigger point, `z + M851 Z`, with the nozzle `M851 X Y` away from the
//! point it names (`G30`, `G29`) or over it (`G33`).
//!
//! Here that printer is the spatial linear delta of `examples/linear-delta`
//! in the frame of the settings read: its carriage positions are the
//! commands, each probe a reading of the nozzle's height over the bed. The
//! identified geometry goes back as Marlin keeps it: the homed carriage
//! positions split into `H` and endstop adjustments whose largest is 0 (as
//! `G33` normalises them), rod lengths into `L` (moved by the arms' common
//! change) and trims.
//!
//! The letters' meanings changed between versions: `M665 B` is the
//! calibration radius up to Marlin 2.0.x and tower B's rod trim later
//! (with `A` and `C`). M503's heading (`; Delta settings: … ABC<rod trim>`)
//! or the rod trims `A`, `C` say which; where nothing does and `B` is given,
//! the reader asks ([`LetterB`]).

use super::klipper::{KLIPPER_FREE, KlipperDelta, SHARED_ARM};
use super::{Firmware, FirmwareValue, Readings};
use crate::error::{Error, Result};
use crate::{invalid, refuse};
use pkmcal::{Field, MeasurementModel, Params, Request, RequestError};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Marlin's tower angles (degrees) before the trims.
pub const TOWER_ANGLES: [f64; 3] = [210.0, 330.0, 90.0];

/// Towers as Marlin's letters name them (`M665 X`, `M666 X`, …; `M665 A`
/// for the rod trims) and pkmcal's.
const TOWERS: [(char, char, &str); 3] = [('X', 'A', "a"), ('Y', 'B', "b"), ('Z', 'C', "c")];

/// The largest length a setting may have (mm): 100 m.
const MAX_LENGTH_MM: f64 = 1e5;

/// The largest tower angle trim (degrees): beyond it the towers would change
/// places.
const MAX_ANGLE_TRIM_DEG: f64 = 60.0;

/// The largest probe offset from the nozzle (mm).
const MAX_PROBE_OFFSET_MM: f64 = 1e3;

/// Decimals of the written values: 0.1 µm, as M503 prints them in Marlin 2.
const DECIMALS: usize = 4;

/// What `M665 B` means in the Marlin that wrote the settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LetterB {
    /// Marlin 1.1 to 2.0.x: the radius G33 probes at (its M503 heading
    /// reads `B<calibration radius>`); these versions have no rod trims.
    CalibrationRadius,
    /// Later versions: tower B's diagonal rod trim (`M665 A B C`; M503's
    /// heading reads `ABC<rod trim>`).
    RodTrim,
}

impl LetterB {
    /// The names a front end takes.
    pub const NAMES: [&str; 2] = ["calibration-radius", "rod-trim"];

    fn name(self) -> &'static str {
        match self {
            LetterB::CalibrationRadius => Self::NAMES[0],
            LetterB::RodTrim => Self::NAMES[1],
        }
    }
}

impl std::str::FromStr for LetterB {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "calibration-radius" => Ok(LetterB::CalibrationRadius),
            "rod-trim" => Ok(LetterB::RodTrim),
            _ => Err(format!(
                "`{s}`: one of {} (what M665 B means in your Marlin: the calibration radius up to 2.0.x, tower B's rod trim later)",
                Self::NAMES.join(", ")
            )),
        }
    }
}

/// A Marlin linear delta: what `M665` and `M666` set.
#[derive(Debug, Clone, PartialEq)]
pub struct MarlinDelta {
    /// Diagonal rod (mm), `M665 L`.
    pub diagonal: f64,
    /// The towers' diagonal rod trims (mm), `M665 A B C` (0 where the version
    /// has none).
    pub rod_trims: [f64; 3],
    /// Delta radius (mm), `M665 R`.
    pub radius: f64,
    /// Delta height (mm), `M665 H`.
    pub height: f64,
    /// Segments per second, `M665 S` (written back as read).
    pub segments: Option<f64>,
    /// The calibration radius (mm), `M665 B` in the versions where B means
    /// it (written back as read).
    pub calibration_radius: Option<f64>,
    /// Tower angle trims (degrees), `M665 X Y Z`.
    pub angle_trims: [f64; 3],
    /// Endstop adjustments (mm, ≤ 0), `M666 X Y Z`.
    pub endstops: [f64; 3],
    /// What `M665 B` means in this Marlin, where known.
    pub letter_b: Option<LetterB>,
}

impl MarlinDelta {
    /// The towers' positions (mm), as `recalc_delta_settings` computes them.
    pub fn towers(&self) -> [[f64; 2]; 3] {
        std::array::from_fn(|i| {
            let a = (TOWER_ANGLES[i] + self.angle_trims[i]).to_radians();
            [a.cos() * self.radius, a.sin() * self.radius]
        })
    }

    /// The towers' diagonal rods (mm): `L` plus each trim.
    pub fn rods(&self) -> [f64; 3] {
        self.rod_trims.map(|t| self.diagonal + t)
    }

    /// Whether this Marlin takes rod trims (`M665 A B C`).
    pub fn has_rod_trims(&self) -> bool {
        self.letter_b == Some(LetterB::RodTrim)
    }

    /// The carriage positions (mm) for the nozzle at `p` (`DELTA_IK`); NaN
    /// where a rod cannot reach.
    pub fn carriages(&self, p: [f64; 3]) -> [f64; 3] {
        let t = self.towers();
        let rods = self.rods();
        std::array::from_fn(|i| {
            p[2] + (rods[i] * rods[i] - (t[i][0] - p[0]).powi(2) - (t[i][1] - p[1]).powi(2)).sqrt()
        })
    }

    /// The carriage positions the firmware holds right after homing: the
    /// nozzle at `(0, 0, H)`.
    pub fn homed_carriages(&self) -> [f64; 3] {
        self.carriages([0.0, 0.0, self.height])
    }

    /// The carriage position (in `self`'s terms) at which the carriage
    /// stands that `other`'s settings command to `c`: both count from the
    /// same endstops, each after its own homing (`H`, rods, adjustments).
    pub fn carriages_from(&self, other: &MarlinDelta, c: [f64; 3]) -> [f64; 3] {
        let (ho, hs) = (other.homed_carriages(), self.homed_carriages());
        std::array::from_fn(|i| c[i] - ho[i] + other.endstops[i] + hs[i] - self.endstops[i])
    }

    /// The same geometry in the form `pkmcal klipper` writes descriptions
    /// (tower angles, radius, rods; endstop errors 0).
    fn as_klipper(&self, probe_radius: f64) -> KlipperDelta {
        KlipperDelta {
            radius: self.radius,
            angles: std::array::from_fn(|i| TOWER_ANGLES[i] + self.angle_trims[i]),
            arms: self.rods(),
            endstops: [0.0; 3],
            step_distances: [0.0; 3],
            probe_radius,
            probes: vec![],
            distances: vec![],
        }
    }

    /// Marlin's values for the description's parameters `p`: the homed
    /// carriages move by the endstop errors and are split into `H` and
    /// adjustments whose largest is 0 (G33's normalisation); the rods into
    /// `L`, moved by their common change, and the trims.
    pub fn identified(&self, spec: &pkmcal::Spec, p: &Params) -> Result<Self> {
        let mut out = self.clone();
        out.radius = p.get(spec, "delta_radius")?;
        let shared = spec.param_index(SHARED_ARM).is_ok();
        let old_rods = self.rods();
        let mut rods = [0.0; 3];
        for (i, (_, _, t)) in TOWERS.iter().enumerate() {
            rods[i] = if shared {
                p.get(spec, SHARED_ARM)?
            } else {
                p.get(spec, &format!("arm_{t}"))?
            };
            if rods[i].is_nan() || rods[i] <= out.radius {
                invalid!(
                    "the identified arm_{t} = {:.3} mm is not longer than delta_radius = {:.3} mm; the probe data cannot support this parameter set (use fewer free parameters)",
                    rods[i],
                    out.radius
                );
            }
            out.angle_trims[i] = p.get(spec, &format!("angle_{t}"))?.to_degrees() - TOWER_ANGLES[i];
            if out.angle_trims[i].is_nan() || out.angle_trims[i].abs() > MAX_ANGLE_TRIM_DEG {
                invalid!(
                    "the identified angle_{t} puts tower {t} {:.3}° from Marlin's {}°, beyond the {MAX_ANGLE_TRIM_DEG}° a trim can hold; the probe data cannot support this parameter set (use fewer free parameters)",
                    out.angle_trims[i],
                    TOWER_ANGLES[i]
                );
            }
        }
        let common = (0..3).map(|i| rods[i] - old_rods[i]).sum::<f64>() / 3.0;
        out.diagonal = self.diagonal + common;
        out.rod_trims = std::array::from_fn(|i| rods[i] - out.diagonal);
        if !self.has_rod_trims() && out.rod_trims.iter().any(|t| t.abs() > 1e-9) {
            invalid!(
                "the identified rods differ between towers ({:.4}, {:.4}, {:.4} mm), which this Marlin cannot hold (it has no rod trims M665 A B C); fit one diagonal for the three towers",
                rods[0],
                rods[1],
                rods[2]
            );
        }
        // Where the homed carriages stand now, in the old settings' terms,
        // and what the new settings must call them.
        let homed = self.homed_carriages();
        let k: [f64; 3] = std::array::from_fn(|i| {
            let d = p.get(spec, &format!("d{}", TOWERS[i].2)).unwrap_or(0.0);
            homed[i] + d - self.endstops[i] - (rods[i].powi(2) - out.radius.powi(2)).sqrt()
        });
        let z_home = k.iter().copied().fold(f64::INFINITY, f64::min);
        out.height = z_home;
        out.endstops = k.map(|v| z_home - v);
        if !out.height.is_finite() || out.endstops.iter().any(|e| !e.is_finite()) {
            invalid!(
                "the identified geometry has no homed position (a rod shorter than the radius?); the probe data cannot support this parameter set (use fewer free parameters)"
            );
        }
        Ok(out)
    }

    /// The `M665` and `M666` lines of these values, in the letters of this
    /// Marlin.
    pub fn gcode(&self) -> String {
        let f = |v: f64| fixed(v, DECIMALS);
        let mut m665 = format!(
            "M665 L{} R{} H{}",
            f(self.diagonal),
            f(self.radius),
            f(self.height)
        );
        if let Some(s) = self.segments {
            let _ = write!(m665, " S{}", f(s));
        }
        if let (Some(b), Some(LetterB::CalibrationRadius)) =
            (self.calibration_radius, self.letter_b)
        {
            let _ = write!(m665, " B{}", f(b));
        }
        for (i, (w, _, _)) in TOWERS.iter().enumerate() {
            let _ = write!(m665, " {w}{}", f(self.angle_trims[i]));
        }
        if self.has_rod_trims() {
            for (i, (_, w, _)) in TOWERS.iter().enumerate() {
                let _ = write!(m665, " {w}{}", f(self.rod_trims[i]));
            }
        }
        format!(
            "{m665}\nM666 X{} Y{} Z{}\n",
            f(self.endstops[0]),
            f(self.endstops[1]),
            f(self.endstops[2])
        )
    }
}

/// `v` with `decimals` decimals, never `-0.0000`.
fn fixed(v: f64, decimals: usize) -> String {
    let t = format!("{v:.decimals$}");
    if t.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        t.trim_start_matches('-').to_string()
    } else {
        t
    }
}

/// The settings of a Marlin printer as read: its delta and its probe's
/// offset from the nozzle (`M851`).
#[derive(Debug, Clone, PartialEq)]
pub struct MarlinSettings {
    /// The delta.
    pub delta: MarlinDelta,
    /// The probe's offset from the nozzle (mm), `M851 X Y Z`, where given.
    pub probe_offset: [Option<f64>; 3],
    /// The last `M665` line, where there is one.
    pub m665_line: Option<usize>,
    /// The last `M666` line, where there is one.
    pub m666_line: Option<usize>,
}

/// A console line without what hosts and Marlin put before the command:
/// timestamps (`08:33:00.013 : `), `Recv:`/`Send:`, `SENDING:`, `>>>`,
/// `echo:`, `//`.
fn console(line: &str) -> &str {
    let mut s = line.trim();
    loop {
        let before = s;
        for p in ["Recv:", "Send:", "SENDING:", ">>>", ">", "echo:", "//"] {
            if let Some(r) = s.strip_prefix(p) {
                s = r.trim_start();
            }
        }
        // A timestamp `hh:mm:ss[.fff] :`.
        let b = s.as_bytes();
        if b.len() > 8 && b[2] == b':' && b[5] == b':' && b[..2].iter().all(u8::is_ascii_digit) {
            let end = s
                .char_indices()
                .find(|&(i, c)| i > 8 && c == ':')
                .map(|(i, _)| i);
            if let Some(e) = end {
                s = s[e + 1..].trim_start();
            }
        }
        if s == before {
            return s;
        }
    }
}

/// The words of a G-code command, as Marlin's parser reads them with or
/// without spaces between them (`M665 L250 R120`, `M665L250R120`): a letter
/// starts a word, its number runs to the next letter.
fn words_of(line: &str) -> Vec<String> {
    let mut out: Vec<String> = vec![];
    let chars: Vec<char> = line.chars().collect();
    let mut skip = 0;
    for (i, &c) in chars.iter().enumerate() {
        if skip > 0 {
            skip -= 1;
            continue;
        }
        // An exponent (`1e3`) stays in its number.
        let exponent = matches!(c, 'e' | 'E')
            && i > 0
            && chars[i - 1].is_ascii_digit()
            && chars
                .get(i + 1)
                .is_some_and(|n| n.is_ascii_digit() || *n == '-' || *n == '+');
        if c.is_ascii_alphabetic() && !exponent {
            // `HNaN`, `R-inf`: a value that is no number stays in its word,
            // to be refused there.
            let next: String = chars[i..].iter().take(3).collect::<String>().to_lowercase();
            if (next == "nan" || next == "inf")
                && let Some(w) = out.last_mut()
                && matches!(w.get(1..), Some("" | "-" | "+"))
            {
                w.extend(&chars[i..i + 3]);
                skip = 2;
                continue;
            }
            out.push(c.to_string());
        } else if c.is_whitespace() {
            continue;
        } else if let Some(w) = out.last_mut() {
            w.push(c);
        } else {
            out.push(c.to_string());
        }
    }
    out
}

/// One command line of a settings file: its code (`M665`) and words.
struct Command<'a> {
    code: String,
    words: Vec<String>,
    text: &'a str,
}

/// The command on a console line, if any: line numbers (`N12`) and
/// checksums (`*71`) dropped, comments cut.
fn command_of(raw: &str) -> Option<Command<'_>> {
    let s = console(raw);
    let s = s.split(';').next().unwrap_or("").trim();
    let s = match s.rsplit_once('*') {
        Some((head, sum)) if !sum.is_empty() && sum.chars().all(|c| c.is_ascii_digit()) => {
            head.trim()
        }
        _ => s,
    };
    // Marlin 2.1 reports the sensorless-probing offsets on the M666 line.
    let s = s.split("sensorless").next().unwrap_or("").trim();
    let mut words = words_of(s);
    if words.first().is_some_and(|w| {
        w.starts_with(['N', 'n']) && w.len() > 1 && w[1..].chars().all(|c| c.is_ascii_digit())
    }) {
        words.remove(0);
    }
    let code = words.first()?.to_ascii_uppercase();
    if !matches!(code.as_str(), "M665" | "M666" | "M851") {
        return None;
    }
    Some(Command {
        code,
        words: words[1..].to_vec(),
        text: s,
    })
}

/// What the heading M503 prints before `M665` says about `M665 B`.
fn heading_meaning(raw: &str) -> Option<LetterB> {
    let s = console(raw);
    let s = s.strip_prefix(';').unwrap_or(s).trim();
    // `Delta settings: L<diagonal rod> …` (Marlin 1.1 to 2.0), `Delta (L<diagonal
    // rod> …)` (2.1).
    if !(s.starts_with("Delta") && s.contains("L<diagonal")) {
        return None;
    }
    if s.contains("ABC<") {
        Some(LetterB::RodTrim)
    } else if s.contains("B<calibration") {
        Some(LetterB::CalibrationRadius)
    } else {
        None
    }
}

/// Read the settings in a file of `M503` output or `M665`/`M666`/`M851`
/// lines (a console log, a start script) and check that they describe a
/// delta: [`parse_settings`], then `M665 L R H` and `M666` given, every rod
/// longer than the radius.
pub fn settings_from_text(
    text: &str,
    path: &Path,
    letter_b: Option<LetterB>,
) -> Result<MarlinSettings> {
    let settings = parse_settings(text, path, letter_b)?;
    let d = &settings.delta;
    if settings.m665_line.is_none() {
        if text
            .lines()
            .any(|l| l.trim_start().starts_with("#define DELTA_"))
        {
            refuse!(
                path,
                None,
                "this is Marlin's Configuration.h, whose DELTA_* values are only the firmware's defaults (what EEPROM holds overrides them); send M503 to the printer and give its output (the `M665 L… R… H…` and `M666 X… Y… Z…` lines)"
            );
        }
        refuse!(
            path,
            None,
            "no M665 line; give the printer's settings as M503 prints them (the `M665 L… R… H…` and `M666 X… Y… Z…` lines)"
        );
    }
    for (v, letter, what) in [
        (d.diagonal, 'L', "diagonal rod"),
        (d.radius, 'R', "delta radius"),
        (d.height, 'H', "delta height"),
    ] {
        if v.is_nan() {
            refuse!(
                path,
                None,
                "no M665 {letter} (the {what}); give the printer's settings as M503 prints them"
            );
        }
    }
    if settings.m666_line.is_none() {
        refuse!(
            path,
            None,
            "no M666 line; give the printer's endstop adjustments as M503 prints them (`M666 X… Y… Z…`, just before the M665 line)"
        );
    }
    if let Some(i) = (0..3).find(|&i| d.rods()[i] <= d.radius) {
        refuse!(
            path,
            settings.m665_line.map(|l| l as u64),
            "tower {}'s diagonal rod ({} mm with its trim) is not longer than the delta radius R{}; no delta assembles so",
            TOWERS[i].2,
            d.rods()[i],
            d.radius
        );
    }
    Ok(settings)
}

/// The settings a file of `M503` output or `M665`/`M666`/`M851` lines
/// gives, as Marlin applies them: every such line in order, later ones
/// overriding the letters they give; other lines ignored; `L R H` NaN
/// where no line gives them. `letter_b` is what `M665 B` means when the
/// file does not say. Bad values are refused with their line.
pub fn parse_settings(
    text: &str,
    path: &Path,
    letter_b: Option<LetterB>,
) -> Result<MarlinSettings> {
    let lines: Vec<&str> = text.lines().collect();
    // What the file says about the letters: M503's heading, or rod trims.
    let mut heading: Option<(LetterB, usize)> = None;
    let mut trims_at: Option<usize> = None;
    for (n, l) in lines.iter().enumerate() {
        if let Some(m) = heading_meaning(l) {
            heading = Some((m, n + 1));
        }
        if let Some(c) = command_of(l)
            && c.code == "M665"
            && trims_at.is_none()
            && c.words.iter().any(|w| w.starts_with(['A', 'a', 'C', 'c']))
        {
            trims_at = Some(n + 1);
        }
    }
    let meaning = match (letter_b, heading) {
        (Some(given), Some((said, line))) if given != said => {
            return Err(Error::Request {
                file: Some(path.to_path_buf()),
                cause: RequestError::invalid(
                    Field::FirmwareLetters,
                    format!(
                        "`{}` is given, but line {line}'s M503 heading says M665 B is {}; leave it out",
                        given.name(),
                        said.name()
                    ),
                ),
            });
        }
        (Some(given), _) => Some(given),
        (None, Some((said, _))) => Some(said),
        (None, None) => trims_at.map(|_| LetterB::RodTrim),
    };
    let mut d = MarlinDelta {
        diagonal: f64::NAN,
        rod_trims: [0.0; 3],
        radius: f64::NAN,
        height: f64::NAN,
        segments: None,
        calibration_radius: None,
        angle_trims: [0.0; 3],
        endstops: [0.0; 3],
        letter_b: meaning,
    };
    let mut probe_offset = [None; 3];
    let mut seen = (None::<usize>, None::<usize>);
    for (n, raw) in lines.iter().enumerate() {
        let Some(c) = command_of(raw) else {
            continue;
        };
        let line = n + 1;
        if c.code == "M665" {
            seen.0 = Some(line);
        } else if c.code == "M666" {
            seen.1 = Some(line);
        }
        for w in &c.words {
            let mut chars = w.chars();
            let letter = chars.next().map(|x| x.to_ascii_uppercase()).unwrap_or(' ');
            let value = chars.as_str();
            let v: f64 = match value.parse::<f64>() {
                Ok(v) if v.is_finite() => v,
                _ => refuse!(
                    path,
                    Some(line as u64),
                    "`{w}` in `{}`: the value of {letter} must be a finite number",
                    c.text
                ),
            };
            let bounded = |limit: f64, what: &str| -> Result<f64> {
                if v.abs() > limit {
                    refuse!(
                        path,
                        Some(line as u64),
                        "`{w}` in `{}`: {what} {v} is beyond what a printer holds (at most {limit} in size)",
                        c.text
                    );
                }
                Ok(v)
            };
            let positive = |what: &str| -> Result<f64> {
                let v = bounded(MAX_LENGTH_MM, what)?;
                if v <= 0.0 {
                    refuse!(
                        path,
                        Some(line as u64),
                        "`{w}` in `{}`: {what} must be positive",
                        c.text
                    );
                }
                Ok(v)
            };
            match (c.code.as_str(), letter) {
                ("M665", 'L') => d.diagonal = positive("the diagonal rod")?,
                ("M665", 'R') => d.radius = positive("the delta radius")?,
                ("M665", 'H') => d.height = positive("the delta height")?,
                ("M665", 'S') => d.segments = Some(bounded(1e6, "the segments per second")?),
                ("M665", 'X' | 'Y' | 'Z') => {
                    let i = TOWERS.iter().position(|t| t.0 == letter).unwrap_or(0);
                    d.angle_trims[i] = bounded(MAX_ANGLE_TRIM_DEG, "the tower angle trim (°)")?;
                }
                ("M665", 'A' | 'C') | ("M665", 'B') if meaning == Some(LetterB::RodTrim) => {
                    let i = TOWERS.iter().position(|t| t.1 == letter).unwrap_or(0);
                    d.rod_trims[i] = bounded(MAX_LENGTH_MM, "the rod trim")?;
                }
                ("M665", 'B') if meaning == Some(LetterB::CalibrationRadius) => {
                    d.calibration_radius = Some(positive("the calibration radius")?);
                }
                ("M665", 'B') => {
                    return Err(Error::Request {
                        file: Some(path.to_path_buf()),
                        cause: RequestError::invalid(
                            Field::FirmwareLetters,
                            format!(
                                "line {line}: `{}`: M665 B is the calibration radius in Marlin 1.1 to 2.0.x and tower B's diagonal rod trim in later versions, and nothing in the file says which this Marlin is; give the meaning ({}), or paste M503's `; Delta settings:` heading line with the M665 line",
                                c.text,
                                LetterB::NAMES.join(" or ")
                            ),
                        ),
                    });
                }
                ("M665", 'A' | 'C') => refuse!(
                    path,
                    Some(line as u64),
                    "`{w}` in `{}`: this Marlin's M665 has no {letter} (M665 B is its calibration radius, so it has no rod trims A B C); give the settings of the Marlin that runs the printer",
                    c.text
                ),
                ("M666", 'X' | 'Y' | 'Z') => {
                    let i = TOWERS.iter().position(|t| t.0 == letter).unwrap_or(0);
                    let v = bounded(MAX_LENGTH_MM, "the endstop adjustment")?;
                    if v > 0.0 {
                        refuse!(
                            path,
                            Some(line as u64),
                            "`{w}` in `{}`: Marlin's endstop adjustments are at most 0 (Marlin 2 refuses a positive one, earlier versions skip it when homing), so the printer does not run {v}; give the values M503 prints",
                            c.text
                        );
                    }
                    d.endstops[i] = v;
                }
                ("M851", 'X' | 'Y' | 'Z') => {
                    let i = (letter as u8 - b'X') as usize;
                    probe_offset[i] = Some(bounded(MAX_PROBE_OFFSET_MM, "the probe offset")?);
                }
                (code, _) => refuse!(
                    path,
                    Some(line as u64),
                    "`{w}` in `{}`: {code} has no letter {letter} in Marlin's delta settings; give M503's output or {code} lines as Marlin prints them",
                    c.text
                ),
            }
        }
    }
    Ok(MarlinSettings {
        delta: d,
        probe_offset,
        m665_line: seen.0,
        m666_line: seen.1,
    })
}

/// How a probed height came to be: the point a command named and where the
/// nozzle was.
#[derive(Debug, Clone, PartialEq)]
pub enum ProbeKind {
    /// `G30` or `G29 V3` (`Bed X: … Y: … Z: …`): the point names the probe's
    /// position; the nozzle stands `M851 X Y` away.
    Probe,
    /// A height a verbose `G33` prints at one of its calibration points,
    /// probed with the nozzle over the point (for `P4` and more, G33's
    /// average of the points around it), with the settings it printed last.
    G33 {
        /// The settings G33 printed before probing: height, endstops,
        /// radius, tower angle trims, where printed.
        settings: G33Settings,
    },
}

/// The settings a `G33` line prints (`.Height:… Ex:… Ey:… Ez:… Radius:…`,
/// `Tx:… Ty:… Tz:…`): each where printed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct G33Settings {
    /// `Height`.
    pub height: Option<f64>,
    /// `Ex Ey Ez`.
    pub endstops: [Option<f64>; 3],
    /// `Radius`.
    pub radius: Option<f64>,
    /// `Tx Ty Tz`.
    pub angle_trims: [Option<f64>; 3],
    /// Its line.
    pub line: usize,
}

impl G33Settings {
    /// `base` with these values where printed.
    pub fn over(&self, base: &MarlinDelta) -> MarlinDelta {
        let mut d = base.clone();
        if let Some(h) = self.height {
            d.height = h;
        }
        if let Some(r) = self.radius {
            d.radius = r;
        }
        for i in 0..3 {
            if let Some(e) = self.endstops[i] {
                d.endstops[i] = e;
            }
            if let Some(t) = self.angle_trims[i] {
                d.angle_trims[i] = t;
            }
        }
        d
    }
}

/// One probed height.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbePoint {
    /// The point (mm): the probe's for `G30`, the nozzle's for `G33`.
    pub xy: [f64; 2],
    /// The height Marlin reported (mm): the probe's trigger point's z.
    pub z: f64,
    /// Its line.
    pub line: usize,
    /// How it was probed.
    pub kind: ProbeKind,
}

/// What a probe log holds: the probed heights, and the radius G33 probed
/// at where it said (`Checking... AC at radius:…`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ProbeLog {
    /// The heights, in order.
    pub points: Vec<ProbePoint>,
    /// G33's calibration radius (mm), where printed.
    pub g33_radius: Option<f64>,
    /// G33's heights that could not be placed (no radius known): their
    /// first line.
    pub g33_unplaced: Option<usize>,
    /// Every set of settings G33 printed, in order.
    pub g33_settings: Vec<G33Settings>,
}

/// The `name:value` pairs of a line (`Bed X: 1.00 Y:2.00`, `.Height:297.8
/// Ex:-0.1`); `None` for a value that is no finite number.
fn pairs(s: &str) -> Vec<(String, Option<f64>, String)> {
    let mut out = vec![];
    let b = s.as_bytes();
    let mut i = 0;
    while let Some(off) = s[i..].find(':') {
        let colon = i + off;
        // The name: the word before the colon.
        let mut start = colon;
        while start > 0 && (b[start - 1].is_ascii_alphanumeric()) {
            start -= 1;
        }
        let name = s[start..colon].to_string();
        let rest = &s[colon + 1..];
        let value_start = rest.len() - rest.trim_start().len();
        let v = &rest[value_start..];
        let len = v.find(|c: char| c.is_whitespace()).unwrap_or(v.len());
        let text = v[..len].to_string();
        let parsed = text.parse::<f64>().ok().filter(|x| x.is_finite());
        out.push((name, parsed, text));
        i = colon + 1;
    }
    out
}

/// G33's calibration points (`CEN`, the towers, the opposite points) by
/// the names it prints them with: their angle (degrees) on the calibration
/// circle, or `None` for the centre.
const G33_POINTS: [(&str, Option<f64>); 7] = [
    ("c", None),
    ("x", Some(210.0)),
    ("y", Some(330.0)),
    ("z", Some(90.0)),
    ("yz", Some(30.0)),
    ("zx", Some(150.0)),
    ("xy", Some(270.0)),
];

/// Read a console log of probes: `G30` (and `G29 V3`) reports `Bed X: … Y:
/// … Z: …` (with or without spaces after the colons), and the heights a
/// verbose `G33` prints (`c:… x:… y:… z:…`, `yz:… zx:… xy:…`) with the
/// settings it printed before them. `g33_radius` places G33's heights when
/// the log does not say its radius.
pub fn probes_from_text(text: &str, path: &Path, g33_radius: Option<f64>) -> Result<ProbeLog> {
    let mut log = ProbeLog::default();
    let mut settings: Option<G33Settings> = None;
    let mut g33_heights: Vec<(String, f64, usize)> = vec![];
    for (n, raw) in text.lines().enumerate() {
        let line = n + 1;
        let s = console(raw);
        let bad = |name: &str, text: &str| -> Error {
            Error::at(
                path,
                Some(line as u64),
                format!("`{name}:{text}` in `{s}`: the value must be a finite number"),
            )
        };
        if let Some(pos) = s.find("Bed X:") {
            let p = pairs(&s[pos + 4..]);
            let get = |k: &str| -> Result<f64> {
                match p.iter().find(|(n, _, _)| n == k) {
                    Some((_, Some(v), _)) => Ok(*v),
                    Some((n, None, t)) => Err(bad(n, t)),
                    None => Err(Error::at(
                        path,
                        Some(line as u64),
                        format!("`{s}` has no {k}: a probe report reads `Bed X: … Y: … Z: …`"),
                    )),
                }
            };
            let (x, y, z) = (get("X")?, get("Y")?, get("Z")?);
            for (k, v) in [("X", x), ("Y", y), ("Z", z)] {
                if v.abs() > MAX_LENGTH_MM {
                    refuse!(
                        path,
                        Some(line as u64),
                        "`{s}`: {k} = {v} mm is beyond what a printer reaches"
                    );
                }
            }
            log.points.push(ProbePoint {
                xy: [x, y],
                z,
                line,
                kind: ProbeKind::Probe,
            });
            continue;
        }
        if s.starts_with("Checking... AC") {
            settings = None;
            if let Some(r) = pairs(s).iter().find(|(n, _, _)| n == "radius") {
                match r.1 {
                    Some(v) if v > 0.0 && v <= MAX_LENGTH_MM => log.g33_radius = Some(v),
                    Some(v) => refuse!(
                        path,
                        Some(line as u64),
                        "`{s}`: G33's calibration radius {v} mm must be positive and at most {MAX_LENGTH_MM:e} mm"
                    ),
                    None => return Err(bad("radius", &r.2)),
                }
            }
            continue;
        }
        let Some(rest) = s.strip_prefix('.') else {
            continue;
        };
        let p = pairs(rest);
        let number = |name: &str| -> Result<Option<f64>> {
            match p.iter().find(|(n, _, _)| n == name) {
                Some((_, Some(v), _)) => Ok(Some(*v)),
                Some((n, None, t)) => Err(bad(n, t)),
                None => Ok(None),
            }
        };
        if let Some(h) = number("Height")? {
            let st = G33Settings {
                height: Some(h),
                endstops: [number("Ex")?, number("Ey")?, number("Ez")?],
                radius: number("Radius")?,
                angle_trims: [number("Tx")?, number("Ty")?, number("Tz")?],
                line,
            };
            log.g33_settings.push(st.clone());
            settings = Some(st);
            continue;
        }
        if p.iter().any(|(n, _, _)| n == "Tx") {
            if let Some(st) = &mut settings {
                st.angle_trims = [number("Tx")?, number("Ty")?, number("Tz")?];
                if let Some(r) = number("Radius")? {
                    st.radius = Some(r);
                }
                if let Some(last) = log.g33_settings.last_mut() {
                    *last = st.clone();
                }
            }
            continue;
        }
        for (name, _) in G33_POINTS {
            if let Some(v) = number(name)? {
                if v.abs() > MAX_LENGTH_MM {
                    refuse!(
                        path,
                        Some(line as u64),
                        "`{s}`: {name} = {v} mm is beyond what a printer reaches"
                    );
                }
                g33_heights.push((name.to_string(), v, line));
            }
        }
        if g33_heights.is_empty() {
            continue;
        }
        let Some(st) = settings.clone() else {
            refuse!(
                path,
                Some(line as u64),
                "G33's heights `{s}` follow no `.Height:` line: paste G33's whole output from `G33 Auto Calibrate` on"
            );
        };
        let radius = log.g33_radius.or(g33_radius);
        for (name, z, line) in g33_heights.drain(..) {
            let angle = G33_POINTS.iter().find(|p| p.0 == name).and_then(|p| p.1);
            let xy = match (angle, radius) {
                (None, _) => [0.0, 0.0],
                (Some(a), Some(radius)) => {
                    [radius * a.to_radians().cos(), radius * a.to_radians().sin()]
                }
                (Some(_), None) => {
                    log.g33_unplaced.get_or_insert(line);
                    continue;
                }
            };
            log.points.push(ProbePoint {
                xy,
                z,
                line,
                kind: ProbeKind::G33 {
                    settings: st.clone(),
                },
            });
        }
    }
    Ok(log)
}

/// A Marlin printer: its settings, the probe log and its heights.
pub struct MarlinPrinter {
    /// The settings file.
    pub config: PathBuf,
    /// The settings.
    pub settings: MarlinSettings,
    /// The probe log.
    pub probes: PathBuf,
    /// Its heights.
    pub log: ProbeLog,
    /// The probe's offset from the nozzle used (mm).
    pub probe_offset: [f64; 3],
    /// One diagonal for the three towers (`M665 L` alone), fitted as one.
    pub shared_arm: bool,
}

/// The parameters M665/M666 hold in a Marlin with rod trims; without them,
/// the one [`SHARED_ARM`] in place of the three arms: a linear delta's ten
/// values, as Klipper's.
const MARLIN_FREE: [&str; 10] = super::klipper::KLIPPER_VALUES;

impl MarlinPrinter {
    /// Read the settings and the probe log. `probe_xy` gives the probe's
    /// x, y offset where the settings have no `M851 X Y`; `free` (the names
    /// a user gives) says whether the shared diagonal is fitted. A probed
    /// point the printer cannot reach is refused with the settings.
    pub fn read(
        run: &crate::Run<'_>,
        config: &Path,
        probes: &Path,
        letter_b: Option<LetterB>,
        probe_xy: Option<[f64; 2]>,
        g33_radius: Option<f64>,
        free: Option<&[String]>,
    ) -> Result<Self> {
        let text = run
            .files
            .read_to_string(config, crate::output::InputKind::Description)
            .map_err(|e| e.named("Marlin settings"))?;
        let settings = settings_from_text(&text, config, letter_b)?;
        let text = run
            .files
            .read_to_string(probes, crate::output::InputKind::Description)
            .map_err(|e| e.named("probe log"))?;
        let radius = g33_radius.or(match settings.delta.letter_b {
            Some(LetterB::CalibrationRadius) => settings.delta.calibration_radius,
            _ => None,
        });
        let log = probes_from_text(&text, probes, radius)?;
        Self::new(config, settings, probes, log, probe_xy, free)
    }

    /// A printer of settings and a probe log already read.
    pub fn new(
        config: &Path,
        settings: MarlinSettings,
        probes: &Path,
        log: ProbeLog,
        probe_xy: Option<[f64; 2]>,
        free: Option<&[String]>,
    ) -> Result<Self> {
        if let Some(line) = log.g33_unplaced {
            return Err(Error::Request {
                file: Some(probes.to_path_buf()),
                cause: RequestError::invalid(
                    Field::G33Radius,
                    format!(
                        "line {line}: G33's heights are at its calibration radius, which the log does not print (Marlin 2.0.9 and later print `Checking... AC at radius:…`) nor the settings give (M665 B); give the radius G33 probed at"
                    ),
                ),
            });
        }
        if log.points.is_empty() {
            refuse!(
                probes,
                None,
                "no probed heights: give a console log of G30 probes (`Bed X: … Y: … Z: …`), or of G29 V3, or G33's output with V3 (its heights `c:… x:… y:… z:…`)"
            );
        }
        let d = &settings.delta;
        let g30 = log.points.iter().find(|p| p.kind == ProbeKind::Probe);
        let xy = match (probe_xy, settings.probe_offset) {
            (Some(xy), _) => xy,
            (None, [Some(x), Some(y), _]) => [x, y],
            (None, _) => match g30 {
                Some(p) => {
                    return Err(Error::Request {
                        file: Some(config.to_path_buf()),
                        cause: RequestError::invalid(
                            Field::ProbeOffset,
                            format!(
                                "no `M851 X… Y…` line gives the probe's offset from the nozzle, which G30 moves by (line {} of {} is a G30 report); give it (0,0 for a probe at the nozzle), or paste M503's M851 line",
                                p.line,
                                probes.display()
                            ),
                        ),
                    });
                }
                None => [0.0, 0.0],
            },
        };
        let probe_offset = [xy[0], xy[1], settings.probe_offset[2].unwrap_or(0.0)];
        // The shared diagonal: one `M665 L` for the three towers, fitted as
        // one; the only form when the Marlin has no rod trims.
        let given: Vec<&str> = free.unwrap_or_default().iter().map(|s| s.trim()).collect();
        let shared_arm = given.contains(&SHARED_ARM) || !d.has_rod_trims();
        if !d.has_rod_trims()
            && let Some(n) = given.iter().find(|n| n.starts_with("arm_"))
        {
            let why = if d.letter_b == Some(LetterB::CalibrationRadius) {
                "this Marlin has no rod trims (its M665 B is the calibration radius)".to_string()
            } else {
                format!(
                    "{} sets no rod trims (M665 A B C) and says nothing that would have them (M503's heading `ABC<rod trim>`); say that M665 B is a rod trim if your Marlin has them",
                    config.display()
                )
            };
            return Err(RequestError::invalid(
                Field::Free,
                format!(
                    "`{n}`: each tower's rod cannot be written, since {why}; free `{SHARED_ARM}` (M665 L for the three towers)"
                ),
            )
            .into());
        }
        if given.contains(&SHARED_ARM) {
            if let Some(n) = given.iter().find(|n| n.starts_with("arm_") || **n == "all") {
                return Err(RequestError::invalid(
                    Field::Free,
                    format!(
                        "`{SHARED_ARM}` (one diagonal for the three towers) and `{n}` exclude each other; free either the shared diagonal or the three arm_a, arm_b, arm_c"
                    ),
                )
                .into());
            }
            if d.rod_trims.iter().any(|t| *t != 0.0) {
                return Err(RequestError::invalid(
                    Field::Free,
                    format!(
                        "`{SHARED_ARM}` fits one diagonal for the three towers, but {} sets rod trims (A{} B{} C{}); free arm_a, arm_b, arm_c instead",
                        config.display(),
                        d.rod_trims[0],
                        d.rod_trims[1],
                        d.rod_trims[2]
                    ),
                )
                .into());
            }
        }
        let printer = MarlinPrinter {
            config: config.to_path_buf(),
            settings,
            probes: probes.to_path_buf(),
            log,
            probe_offset,
            shared_arm,
        };
        // A probed point the settings cannot reach is named here, with the
        // geometry, not later as a command of NaN.
        for p in &printer.log.points {
            if printer.commands(p).iter().any(|c| !c.is_finite()) {
                let d = &printer.settings.delta;
                refuse!(
                    probes,
                    Some(p.line as u64),
                    "the probed point ({}, {}) is out of reach of the printer {} describes (rods {:?} mm, radius {} mm); check the settings or the probe log",
                    p.xy[0],
                    p.xy[1],
                    config.display(),
                    d.rods(),
                    d.radius
                );
            }
        }
        Ok(printer)
    }

    /// The settings' delta.
    pub fn delta(&self) -> &MarlinDelta {
        &self.settings.delta
    }

    /// The nozzle's position (mm, in the terms of the settings in effect)
    /// when the probe triggered at `p`.
    pub fn nozzle(&self, p: &ProbePoint) -> [f64; 3] {
        let o = self.probe_offset;
        match p.kind {
            ProbeKind::Probe => [p.xy[0] - o[0], p.xy[1] - o[1], p.z - o[2]],
            ProbeKind::G33 { .. } => [p.xy[0], p.xy[1], p.z - o[2]],
        }
    }

    /// The carriage positions (mm, in the settings' terms) at which `p` was
    /// probed.
    pub fn commands(&self, p: &ProbePoint) -> [f64; 3] {
        let d = self.delta();
        let nozzle = self.nozzle(p);
        match &p.kind {
            ProbeKind::Probe => d.carriages(nozzle),
            ProbeKind::G33 { settings } => {
                let then = settings.over(d);
                d.carriages_from(&then, then.carriages(nozzle))
            }
        }
    }

    /// The probe radius: the farthest probed point from the centre.
    pub fn probe_radius(&self) -> f64 {
        self.log
            .points
            .iter()
            .map(|p| p.xy[0].hypot(p.xy[1]))
            .fold(0.0, f64::max)
    }

    /// The height the probe reports (mm) at the nozzle position `xy` with
    /// the settings `settings` on the printer that `params` and the bed
    /// `bed` describe (the mechanism `mech` of this printer): the firmware
    /// lowers the nozzle until the probe's trigger point meets the bed.
    pub fn probe_as(
        &self,
        settings: &MarlinDelta,
        xy: [f64; 2],
        mech: &crate::description::Mech,
        measurement: &MeasurementModel,
        params: &Params,
        bed: &[f64],
    ) -> Result<f64> {
        let oz = self.probe_offset[2];
        let d = self.delta();
        // The nozzle's height over the bed with the firmware's nozzle at z.
        let height = |z: f64| -> Result<f64> {
            let c = d.carriages_from(settings, settings.carriages([xy[0], xy[1], z]));
            if c.iter().any(|v| !v.is_finite()) {
                invalid!(
                    "the point ({:.3}, {:.3}) is out of reach of the settings M665 L{} R{}",
                    xy[0],
                    xy[1],
                    settings.diagonal,
                    settings.radius
                );
            }
            let pr = pkmcal::predict(mech, params, &c, pkmcal::Model::Exact, &[])?;
            let mut y = [0.0];
            measurement.observe(&pr.x, bed, &mut y);
            Ok(y[0])
        };
        // It triggers where the nozzle stands −oz over the bed; the heights
        // change with z at a slope of 1 (tilted towers: nearly).
        let mut z = 0.0;
        for _ in 0..PROBE_ITERATIONS {
            let step = height(z)? + oz;
            z -= step;
            if step.abs() < PROBE_TOLERANCE_MM {
                break;
            }
        }
        Ok(z + oz)
    }
}

/// Newton steps of a simulated probe.
const PROBE_ITERATIONS: usize = 8;
/// Where a simulated probe has met the bed (mm).
const PROBE_TOLERANCE_MM: f64 = 1e-10;

/// The parameters `M665`/`M666` hold for this printer's Marlin.
pub fn marlin_holds(delta: &MarlinDelta, shared_arm: bool) -> Vec<String> {
    MARLIN_FREE
        .iter()
        .filter(|n| !n.starts_with("arm_") || (delta.has_rod_trims() && !shared_arm))
        .map(|s| s.to_string())
        .chain(shared_arm.then(|| SHARED_ARM.to_string()))
        .collect()
}

impl Firmware for MarlinPrinter {
    fn flavour(&self) -> super::Flavour {
        super::Flavour::Marlin
    }

    fn description(&self) -> String {
        self.delta()
            .as_klipper(self.probe_radius())
            .description_toml_with(
                "Marlin's M665/M666 by `pkmcal marlin`",
                "the X, Y, Z towers",
                "Marlin",
                self.shared_arm,
            )
    }

    fn readings(&self, spec: &pkmcal::Spec) -> Result<Readings> {
        let oz = self.probe_offset[2];
        let poses = self
            .log
            .points
            .iter()
            .enumerate()
            .map(|(i, p)| pkmcal::Measurement {
                point: None,
                target: None,
                commands: self.commands(p).to_vec(),
                partner: None,
                // The probe's trigger point is on the bed: the nozzle is
                // −oz over it.
                measured: vec![-oz],
                sigma: vec![],
                origin: Some(pkmcal::Origin {
                    pose: i + 1,
                    line: Some(p.line as u64),
                    distance: false,
                }),
            })
            .collect();
        Ok(Readings {
            measurement: MeasurementModel::probe(spec)?,
            poses,
            distances: vec![],
        })
    }

    fn default_free(&self, _spec: &pkmcal::Spec, _readings: &Readings) -> Vec<String> {
        KLIPPER_FREE.map(String::from).to_vec()
    }

    fn holds(&self) -> Option<Vec<String>> {
        Some(marlin_holds(self.delta(), self.shared_arm))
    }

    fn configure(&self, request: &mut Request, _readings: &Readings) {
        // As many probe points as factors are solved exactly, as G33 solves
        // its 7 points.
        request.exactly_determined = true;
        if let Some(free) = &mut request.free {
            let holds = marlin_holds(self.delta(), self.shared_arm);
            let expanded: Vec<String> = free
                .iter()
                .flat_map(|n| {
                    if n.trim() == "all" {
                        holds.clone()
                    } else {
                        vec![n.clone()]
                    }
                })
                .collect();
            *free = expanded;
        }
    }

    fn check_free(&self, names: &[String]) -> std::result::Result<(), RequestError> {
        let holds = marlin_holds(self.delta(), self.shared_arm);
        if let Some(n) = names.iter().find(|n| !holds.contains(n)) {
            let why = if n == "bed.z" {
                " (a bed height is the endstops' common shift: da, db, dc take it)"
            } else if n.starts_with("bed.") {
                " (a tilted bed is for Marlin's bed levelling, G29)"
            } else if n.starts_with("arm_") && !self.delta().has_rod_trims() {
                " (this Marlin has no rod trims M665 A B C: free `diagonal`, or say that M665 B is a rod trim if your Marlin has them)"
            } else {
                ""
            };
            return Err(RequestError::invalid(
                Field::Free,
                format!(
                    "`{n}` has no place in M665/M666, so Marlin could not run what the fit finds{why}; the parameters they hold are {}",
                    holds.join(", ")
                ),
            ));
        }
        Ok(())
    }

    fn values(
        &self,
        spec: &pkmcal::Spec,
        params: &Params,
        _instrument: &[f64],
    ) -> Result<Vec<FirmwareValue>> {
        let new = self.delta().identified(spec, params)?;
        let old = self.delta();
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
        push("M665 L".into(), old.diagonal, new.diagonal, "mm");
        if old.has_rod_trims() {
            for (i, (_, w, _)) in TOWERS.iter().enumerate() {
                push(
                    format!("M665 {w}"),
                    old.rod_trims[i],
                    new.rod_trims[i],
                    "mm",
                );
            }
        }
        push("M665 R".into(), old.radius, new.radius, "mm");
        push("M665 H".into(), old.height, new.height, "mm");
        for (i, (w, _, _)) in TOWERS.iter().enumerate() {
            push(
                format!("M665 {w}"),
                old.angle_trims[i],
                new.angle_trims[i],
                "°",
            );
        }
        for (i, (w, _, _)) in TOWERS.iter().enumerate() {
            push(format!("M666 {w}"), old.endstops[i], new.endstops[i], "mm");
        }
        Ok(out)
    }

    fn updated(&self, spec: &pkmcal::Spec, params: &Params, _instrument: &[f64]) -> Result<String> {
        Ok(self.delta().identified(spec, params)?.gcode())
    }

    fn linear_delta(&self) -> Result<Option<super::physical::LinearDelta>> {
        Ok(Some(super::physical::LinearDelta {
            delta: self.delta().as_klipper(self.probe_radius()),
            probe_offset: [self.probe_offset[0], self.probe_offset[1]],
            firmware: super::Flavour::Marlin,
            values: marlin_holds(self.delta(), self.shared_arm),
            corrects_bed_tilt: false,
            print_radius: self.probe_radius(),
            // The nozzle is −oz over the bed where the probe triggers.
            probe_height: -self.probe_offset[2],
            homed_height: self.delta().height,
        }))
    }

    fn mesh_layout(
        &self,
        radius: f64,
        count: Option<usize>,
    ) -> Result<Option<super::height_map::MeshLayout>> {
        use super::height_map::{MESH_POINTS, MeshFormat, MeshLayout, round_count};
        MeshLayout::round(MeshFormat::Marlin, radius, round_count(count, MESH_POINTS)?).map(Some)
    }

    fn located(&self, e: pkmcal::Error) -> Error {
        Error::located(e, &self.probes)
    }
}
