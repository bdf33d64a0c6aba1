//! Klipper's linear delta: a `printer.cfg` read as Klipper reads it, the
//! printer and its saved probe results, and the values written back in
//! Klipper's keys.
//!
//! Klipper's delta geometry: towers at `angle` (degrees) on a circle of
//! `delta_radius` (the effector's offset already subtracted), arms of
//! `arm_length`; a carriage's height (the centre of its arms' joints) is
//! `position_endstop + √(arm_length² − delta_radius²) − steps · step_distance`,
//! `steps` counted from the endstop (Klipper's "stable positions", which
//! `DELTA_CALIBRATE` saves as `height{N}_pos` with the probed height
//! `height{N}`). Here that printer is the spatial linear delta of
//! `examples/linear-delta` (tower `a` at `angle_a`, …), its carriage heights the
//! commands, and each probe point a measurement of z alone. An encoder offset
//! `da` (mm of carriage height) becomes Klipper's
//! `position_endstop + da + √(arm² − r²) − √(arm'² − r'²)` with the new arm
//! length and radius.
//!
//! The file is read as Klipper reads it: `key: value` or `key = value`,
//! inline `#`/`;` comments, indented continuation lines, `[include file]`,
//! and the `#*#` SAVE_CONFIG block at the end, whose values override. (Written
//! here: no INI crate reads that block, and the dialect is a few rules.)

use super::{Firmware, FirmwareValue, Readings, Separation, TiltPlace};
use crate::error::{Error, Result};
use crate::{invalid, refuse};
use pkmcal::{MeasurementModel, Params, Request};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// How probe heights and calibration-object distances are weighed against
/// each other in one fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Weighting {
    /// A noise level each, estimated from the residuals (variance
    /// components).
    Estimated,
    /// Klipper's fixed ratio (`delta_calibrate.py`): the heights' squares
    /// weigh `n_distances / (0.5 · n_probed)` times the distances'
    /// (`n_probed` counts the probed heights, not the manual ones).
    Klipper,
    /// A noise level each, estimated from the residuals as far as they
    /// support it: each group's variance shrinks towards its share of
    /// Klipper's ratio (at the pooled scale) with the given number of
    /// pseudo-readings (0: `Estimated`; infinite: `Klipper`).
    Shrunk(f64),
}

/// Pseudo-readings `--weighting shrunk` gives Klipper's ratio by default,
/// as many as a stated noise is worth in `calibrate`
/// ([`pkmcal::identify::DEFAULT_STATED_NOISE_READINGS`]). On the real
/// printers' 7 heights and 12 distances, leave-one-out prediction improves
/// with every pseudo-reading added, up to Klipper's fixed ratio (infinitely
/// many), which is why that is the default weighting
/// (`examples/klipper_loo.rs`, BENCHMARKS.md).
pub const DEFAULT_RATIO_READINGS: f64 = pkmcal::identify::DEFAULT_STATED_NOISE_READINGS;

impl Weighting {
    /// The names a front end takes, in order (`shrunk:N` gives the
    /// pseudo-readings).
    pub const NAMES: [&str; 3] = ["estimated", "klipper", "shrunk"];
}

impl std::str::FromStr for Weighting {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.split_once(':') {
            None if s == "estimated" => Ok(Weighting::Estimated),
            None if s == "klipper" => Ok(Weighting::Klipper),
            None if s == "shrunk" => Ok(Weighting::Shrunk(DEFAULT_RATIO_READINGS)),
            Some(("shrunk", n)) => match n.trim().parse::<f64>() {
                Ok(v) if v.is_finite() && v >= 0.0 => Ok(Weighting::Shrunk(v)),
                _ => Err(format!(
                    "`shrunk:{n}`: give the pseudo-readings as a non-negative number, e.g. shrunk:{DEFAULT_RATIO_READINGS}"
                )),
            },
            _ => Err(format!(
                "unknown weighting `{s}`; one of {} (shrunk:N for N pseudo-readings)",
                Weighting::NAMES.join(", ")
            )),
        }
    }
}

/// Klipper's `MEASURE_WEIGHT`.
const KLIPPER_MEASURE_WEIGHT: f64 = 0.5;

/// The largest length a printer's configuration may give (mm): 100 m.
const MAX_KLIPPER_LENGTH_MM: f64 = 1e5;

/// Klipper's SAVE_CONFIG header line.
const AUTOSAVE_HEADER: &str = "#*# <---------------------- SAVE_CONFIG ---------------------->";

/// Towers in Klipper's order.
const TOWERS: [&str; 3] = ["a", "b", "c"];

/// Klipper's default tower angles (degrees).
const DEFAULT_ANGLES: [f64; 3] = [210.0, 330.0, 90.0];

/// Klipper's parameter set for probe heights alone: `delta_radius`, two
/// tower angles, the three endstops.
pub const KLIPPER_FREE: [&str; 6] = ["delta_radius", "angle_a", "angle_b", "da", "db", "dc"];

/// Every parameter Klipper's values hold: `delta_radius`, the towers'
/// `angle`s, `arm_length`s and `position_endstop`s.
pub const KLIPPER_VALUES: [&str; 10] = [
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
];

/// The probe's x, y offset from the nozzle (mm): `[probe]` or `[bltouch]`
/// `x_offset`, `y_offset` (0 where neither says: a probe at the nozzle).
pub fn probe_offset(ini: &Ini) -> Result<[f64; 2]> {
    for section in ["probe", "bltouch"] {
        if ini.has_section(section) {
            return Ok([
                ini.length(section, "x_offset", false)?.unwrap_or(0.0),
                ini.length(section, "y_offset", false)?.unwrap_or(0.0),
            ]);
        }
    }
    Ok([0.0, 0.0])
}

/// What Klipper's saved probe results read where the probe triggers on the
/// bed (mm): the `z_offset` they were saved with (`DELTA_CALIBRATE` saves
/// it as each height), else the probe's `z_offset`, else 0.
pub fn probe_height(ini: &Ini, probes: &[Probe]) -> Result<f64> {
    if let Some(p) = probes.first() {
        return Ok(p.height);
    }
    for section in ["probe", "bltouch"] {
        if ini.has_section(section) {
            return Ok(ini.length(section, "z_offset", false)?.unwrap_or(0.0));
        }
    }
    Ok(0.0)
}

/// What Klipper adds to [`KLIPPER_FREE`] when distances were measured on its
/// calibration object (its extended calibration): the three arm lengths.
pub const KLIPPER_EXTENDED: [&str; 3] = ["arm_a", "arm_b", "arm_c"];

/// The one diagonal rod length of a description whose towers share it
/// ([`KlipperDelta::description_toml_with`]).
pub const SHARED_ARM: &str = "diagonal";

/// Stiffness written for the carriages (N/mm): a linear delta is not
/// redundant, so it changes no prediction without a load.
const CARRIAGE_STIFFNESS: f64 = 2000.0;

/// One option: section, key, value and the line it came from.
#[derive(Debug, Clone)]
pub(crate) struct Entry {
    pub(crate) section: String,
    pub(crate) key: String,
    pub(crate) value: String,
    pub(crate) line: usize,
    pub(crate) file: String,
    /// Read from an included file (not the configuration named).
    pub(crate) included: bool,
    /// Read from the SAVE_CONFIG block.
    pub(crate) autosave: bool,
}

/// A Klipper configuration: every option, the SAVE_CONFIG block's last.
#[derive(Debug, Default)]
pub struct Ini {
    entries: Vec<Entry>,
    /// The configuration's own file (for messages about what it lacks).
    pub(crate) file: String,
    /// (section, option) -> the last regular and the last saved entry.
    index: std::collections::HashMap<(String, String), (Option<usize>, Option<usize>)>,
    /// Included files read so far (bounded by [`MAX_INCLUDED_FILES`]).
    files: usize,
    /// Their bytes (bounded by [`MAX_INCLUDED_BYTES`]).
    bytes: usize,
    /// The line of the SAVE_CONFIG block's header, if there is a block.
    header_line: Option<usize>,
}

/// The most bytes the included files of one configuration may hold in all.
const MAX_INCLUDED_BYTES: usize = 64 << 20;

/// The most included files one configuration may read in all (a printer's
/// folder holds tens; includes that fan out could otherwise read millions).
pub const MAX_INCLUDED_FILES: usize = 1000;

/// The most files one chain of `[include]` may nest (the configuration
/// counted): Klipper itself has no limit of its own, but Python's recursion
/// limit stops its reader at about 480 nested files (measured with its
/// `configfile.py`); a file that includes itself is refused by name, as
/// Klipper refuses it.
pub const MAX_INCLUDE_DEPTH: usize = 400;

/// The files `[include spec]` in `file` names, as Klipper resolves them
/// (its `_resolve_include`): relative to the including file's directory; a
/// pattern (`*`, `?`, `[`) expanded by Python's `glob.glob` ([`glob`]) and
/// sorted, an empty match allowed; a plain name must exist.
fn included_files(file: &Path, spec: &str) -> Result<Vec<PathBuf>> {
    let path = file.parent().unwrap_or(Path::new(".")).join(spec);
    if !has_magic(&path.to_string_lossy()) {
        if std::fs::symlink_metadata(&path).is_err() {
            invalid!("the included file {} does not exist", path.display());
        }
        return Ok(vec![path]);
    }
    let mut found = glob(&path);
    // Sorted as Python sorts the names (by code point: the bytes of UTF-8).
    found.sort_by(|a, b| {
        a.as_os_str()
            .as_encoded_bytes()
            .cmp(b.as_os_str().as_encoded_bytes())
    });
    Ok(found)
}

/// Whether a path is a pattern for Python's `glob` (`glob.has_magic`).
fn has_magic(s: &str) -> bool {
    s.contains(['*', '?', '['])
}

/// One element of a pattern, as Python's `fnmatch.translate` reads it.
#[derive(Debug, Clone, PartialEq)]
enum Tok {
    /// `?`.
    Any,
    /// `*`.
    Star,
    /// `[…]` (`[!…]` negated): its characters and ranges.
    Class(bool, Vec<(char, char)>),
    Lit(char),
}

/// A pattern's elements, as Python's `fnmatch.translate` reads them: `*`,
/// `?`, `[…]` with `!` for negation, a `]` first in the class literal, `a-z`
/// ranges (a reversed one matching nothing), an unclosed `[` literal.
fn translate(pattern: &str) -> Vec<Tok> {
    let p: Vec<char> = pattern.chars().collect();
    let mut out = vec![];
    let mut i = 0;
    while i < p.len() {
        let c = p[i];
        i += 1;
        match c {
            '*' => {
                if out.last() != Some(&Tok::Star) {
                    out.push(Tok::Star);
                }
            }
            '?' => out.push(Tok::Any),
            '[' => {
                let mut j = i;
                if p.get(j) == Some(&'!') {
                    j += 1;
                }
                if p.get(j) == Some(&']') {
                    j += 1;
                }
                while j < p.len() && p[j] != ']' {
                    j += 1;
                }
                if j >= p.len() {
                    out.push(Tok::Lit('['));
                    continue;
                }
                let mut body = &p[i..j];
                i = j + 1;
                let negated = body.first() == Some(&'!');
                if negated {
                    body = &body[1..];
                }
                let mut items = vec![];
                let mut k = 0;
                while k < body.len() {
                    if k + 2 < body.len() && body[k + 1] == '-' {
                        if body[k] <= body[k + 2] {
                            items.push((body[k], body[k + 2]));
                        }
                        k += 3;
                    } else {
                        items.push((body[k], body[k]));
                        k += 1;
                    }
                }
                out.push(Tok::Class(negated, items));
            }
            c => out.push(Tok::Lit(c)),
        }
    }
    out
}

/// Whether `name` matches the pattern `toks` whole (the classic two-pointer
/// match: linear, backtracking only to the last `*`).
fn fnmatch(toks: &[Tok], name: &str) -> bool {
    let n: Vec<char> = name.chars().collect();
    let one = |t: &Tok, c: char| match t {
        Tok::Any => true,
        Tok::Lit(l) => *l == c,
        Tok::Class(neg, items) => items.iter().any(|&(a, b)| a <= c && c <= b) != *neg,
        Tok::Star => false,
    };
    let (mut ti, mut ni) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while ni < n.len() {
        if ti < toks.len() && toks[ti] == Tok::Star {
            star = Some((ti, ni));
            ti += 1;
        } else if ti < toks.len() && one(&toks[ti], n[ni]) {
            ti += 1;
            ni += 1;
        } else if let Some((st, sn)) = star {
            ti = st + 1;
            ni = sn + 1;
            star = Some((st, sn + 1));
        } else {
            return false;
        }
    }
    while ti < toks.len() && toks[ti] == Tok::Star {
        ti += 1;
    }
    ti == toks.len()
}

/// Python's `glob.glob(pattern)` (3.11, not recursive, hidden files only by
/// a pattern that starts with `.`; `.` and `..` never listed): each
/// component with magic matched in its directory (directories only but for
/// the last), a literal one kept when it exists. Unreadable directories
/// give nothing, as in Python.
fn glob(pattern: &Path) -> Vec<PathBuf> {
    use std::path::Component;
    let mut bases: Vec<PathBuf> = vec![PathBuf::new()];
    let parts: Vec<Component<'_>> = pattern.components().collect();
    for (k, part) in parts.iter().enumerate() {
        let last = k + 1 == parts.len();
        let name = part.as_os_str().to_string_lossy();
        let mut next = vec![];
        for base in &bases {
            let dir = if base.as_os_str().is_empty() {
                Path::new(".")
            } else {
                base.as_path()
            };
            if !matches!(part, Component::Normal(_)) || !has_magic(&name) {
                let p = base.join(part.as_os_str());
                let keep = if last {
                    std::fs::symlink_metadata(&p).is_ok()
                } else {
                    p.is_dir()
                };
                if keep {
                    next.push(p);
                }
                continue;
            }
            let toks = translate(&name);
            let hidden = name.starts_with('.');
            let Ok(entries) = std::fs::read_dir(dir) else {
                continue;
            };
            for e in entries.flatten() {
                let file = e.file_name();
                let text = file.to_string_lossy();
                if (text.starts_with('.') && !hidden) || !fnmatch(&toks, &text) {
                    continue;
                }
                let p = base.join(&file);
                if last || p.is_dir() {
                    next.push(p);
                }
            }
        }
        bases = next;
        if bases.is_empty() {
            break;
        }
    }
    bases
}

impl Ini {
    /// The value of `key` in `[section]` as Klipper reads it: the last
    /// definition in the regular part (its includes at their place) wins, and
    /// the SAVE_CONFIG block's only when the regular part has none (Klipper
    /// comments out the block's duplicates at start, `_strip_duplicates`).
    pub(crate) fn get(&self, section: &str, key: &str) -> Option<&Entry> {
        let &(regular, saved) = self.index.get(&(section.to_string(), key.to_string()))?;
        regular.or(saved).map(|i| &self.entries[i])
    }

    /// Index the entries by option: the last regular and the last saved
    /// definition of each (lookups in constant time: a block of 20,000
    /// probe results is read in linear time).
    fn build_index(&mut self) {
        self.index.clear();
        for (i, e) in self.entries.iter().enumerate() {
            let slot = self
                .index
                .entry((e.section.clone(), e.key.clone()))
                .or_insert((None, None));
            if e.autosave {
                slot.1 = Some(i);
            } else {
                slot.0 = Some(i);
            }
        }
    }

    /// A length (mm) that must be positive and below 100 m, with its place
    /// in an error.
    pub(crate) fn length(&self, section: &str, key: &str, positive: bool) -> Result<Option<f64>> {
        let Some(v) = self.number(section, key)? else {
            return Ok(None);
        };
        let e = self.get(section, key).expect("a number has an entry");
        if v.abs() > MAX_KLIPPER_LENGTH_MM || (positive && v <= 0.0) {
            refuse!(
                e.file,
                Some((e.line) as u64),
                "[{section}] {key} = {} mm must be {}at most {MAX_KLIPPER_LENGTH_MM:e} mm in size",
                e.value.trim(),
                if positive { "positive and " } else { "" }
            );
        }
        Ok(Some(v))
    }

    pub(crate) fn has_section(&self, section: &str) -> bool {
        self.entries.iter().any(|e| e.section == section)
    }

    /// A number, with the place it came from in an error.
    pub(crate) fn number(&self, section: &str, key: &str) -> Result<Option<f64>> {
        let Some(e) = self.get(section, key) else {
            return Ok(None);
        };
        let Ok(v) = e.value.trim().parse::<f64>() else {
            refuse!(
                e.file,
                Some(e.line as u64),
                "[{section}] {key} = `{}` is not a number",
                e.value
            );
        };
        if !v.is_finite() {
            refuse!(
                e.file,
                Some((e.line) as u64),
                "[{section}] {key} must be finite"
            );
        }
        Ok(Some(v))
    }

    /// Three numbers `x,y,z` (a stable position).
    pub(crate) fn triple(&self, section: &str, key: &str) -> Result<[f64; 3]> {
        let Some(e) = self.get(section, key) else {
            refuse!(self.file, None, "[{section}] has no `{key}`");
        };
        let v: Vec<f64> = e
            .value
            .split(',')
            .map(|s| s.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .ok()
            .filter(|v: &Vec<f64>| v.len() == 3 && v.iter().all(|x| x.is_finite()))
            .ok_or_else(|| {
                Error::at(
                    Path::new(&e.file),
                    Some(e.line as u64),
                    format!(
                        "[{section}] {key} = `{}` must be three numbers `a,b,c` (steps from each tower's endstop)",
                        e.value
                    ),
                )
            })?;
        Ok([v[0], v[1], v[2]])
    }
}

/// Klipper's SAVE_CONFIG header, as its `configfile.py` finds it: these
/// three lines after a line end.
const AUTOSAVE_HEADER_LINES: &str = "\n#*# <---------------------- SAVE_CONFIG ---------------------->\n#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n";

/// A configuration split as Klipper's `_find_autosave_data` splits it.
struct Split {
    /// The regular part (line ends `\n`).
    regular: String,
    /// The SAVE_CONFIG block: each line's number in the file and its text
    /// without the `#*# ` prefix; `None` when there is no block.
    block: Option<Vec<(usize, String)>>,
    /// The line of the block's header, when there is a block.
    header_line: Option<usize>,
}

/// The line (from 1) of byte `pos` of `data`.
fn line_at(data: &str, pos: usize) -> usize {
    data[..pos].matches('\n').count() + 1
}

/// Split a configuration as Klipper does (`_find_autosave_data`, its line
/// ends `\r\n` read as `\n`): the regular part before the header's three
/// lines, the block after them. Whatever makes Klipper ignore the whole
/// block (and start from the regular part alone: a `#*# ` line above the
/// header or without one, a second header, a blank line or a line not
/// starting `#*# ` inside the block) is refused, naming its line: pkmcal
/// would otherwise read, and write, values the printer does not run.
fn split_autosave(text: &str, file: &Path) -> Result<Split> {
    let data = text.replace("\r\n", "\n");
    let ignored = "Klipper ignores the whole SAVE_CONFIG block then (its configfile.py: \"autosave state corrupted\" or \"modifications after header\") and runs the values above it alone";
    let fix = "restore the block as SAVE_CONFIG wrote it (or run SAVE_CONFIG in Klipper to rewrite it) and read the file again";
    let (regular, autosave, start) = match data.find(AUTOSAVE_HEADER_LINES) {
        Some(pos) => {
            let after = pos + AUTOSAVE_HEADER_LINES.len();
            let rest = &data[after..];
            // Python's `strip()`: white space off both ends.
            let body = rest.trim_matches(|c: char| c.is_whitespace());
            let start =
                after + (rest.len() - rest.trim_start_matches(|c: char| c.is_whitespace()).len());
            (&data[..pos], Some(body), start)
        }
        None => (data.as_str(), None, 0),
    };
    if let Some(k) = regular.find("\n#*# ") {
        let line = line_at(&data, k + 1);
        let what = if autosave.is_some() {
            "a `#*# ` line above the SAVE_CONFIG block's header"
        } else if data[k + 1..].starts_with(AUTOSAVE_HEADER) {
            "the SAVE_CONFIG header not followed by Klipper's two lines (`#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.` and `#*#`)"
        } else {
            "a `#*# ` line without the SAVE_CONFIG block's header above it"
        };
        refuse!(file, Some(line as u64), "{what}, so {ignored}; {fix}");
    }
    let Some(body) = autosave else {
        return Ok(Split {
            regular: data,
            block: None,
            header_line: None,
        });
    };
    if let Some(k) = body.find(AUTOSAVE_HEADER_LINES) {
        refuse!(
            file,
            Some(line_at(&data, start + k + 1) as u64),
            "a second SAVE_CONFIG header inside the block, so {ignored}; {fix}"
        );
    }
    let first = line_at(&data, start);
    let mut lines = vec![];
    if !body.is_empty() {
        for (i, l) in body.split('\n').enumerate() {
            let n = l.chars().count();
            if !l.starts_with("#*#") || (n >= 4 && !l.starts_with("#*# ")) {
                refuse!(
                    file,
                    Some((first + i) as u64),
                    "{} inside the SAVE_CONFIG block, so {ignored}; {fix}",
                    if l.trim().is_empty() {
                        "a blank line".to_string()
                    } else {
                        format!("`{}`, a line that does not start with `#*# `,", l.trim())
                    }
                );
            }
            lines.push((first + i, l.chars().skip(4).collect::<String>()));
        }
    }
    Ok(Split {
        header_line: Some(line_at(&data, regular.len() + 1)),
        regular: regular.to_string(),
        block: Some(lines),
    })
}

/// A line without its comment, as Klipper reads it: cut at the first `#`
/// anywhere (its `_parse_config`), then at a `;` that starts the line or
/// follows white space (configparser's inline comments).
fn strip_comment(line: &str) -> &str {
    let line = &line[..line.find('#').unwrap_or(line.len())];
    let b = line.as_bytes();
    for (i, c) in b.iter().enumerate() {
        if *c == b';' && (i == 0 || b[i - 1].is_ascii_whitespace()) {
            return &line[..i];
        }
    }
    line
}

/// `path` made absolute and normalised as Python's `os.path.abspath` makes
/// it (`..` taken lexically, links not followed), as Klipper knows the files
/// it is reading.
fn abspath(path: &Path) -> PathBuf {
    use std::path::Component;
    let full = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut out = PathBuf::new();
    for c in full.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            c => out.push(c.as_os_str()),
        }
    }
    out
}

/// Parse one file's lines (each with its number in the file) into `ini`,
/// following `[include …]` when `chain` is given (the files being read, to
/// refuse one that includes itself as Klipper does): the SAVE_CONFIG block's
/// lines are read without (an `[include]` there is a section to Klipper).
fn parse_into(
    run: &crate::Run<'_>,
    ini: &mut Ini,
    lines: &mut dyn Iterator<Item = (usize, &str)>,
    file: &Path,
    mut chain: Option<&mut Vec<PathBuf>>,
    autosave: bool,
) -> Result<()> {
    let name = file.display().to_string();
    let depth = chain.as_ref().map_or(0, |c| c.len().saturating_sub(1));
    let mut section: Option<String> = None;
    let mut last: Option<usize> = None;
    for (no, raw) in lines {
        if no == 1 && raw.starts_with('\u{feff}') {
            invalid!(
                "{name}:1: the file starts with a byte-order mark (a UTF-8 BOM), which Klipper does not read (its first line would be outside any section); save the file as UTF-8 without BOM"
            );
        }
        let line = strip_comment(raw.trim_end_matches('\r'));
        if line.trim().is_empty() {
            continue;
        }
        if line.starts_with(char::is_whitespace) {
            // A continuation of the previous value.
            match last {
                Some(k) => {
                    let e = &mut ini.entries[k];
                    e.value.push('\n');
                    e.value.push_str(line.trim());
                }
                None => refuse!(name, Some(no as u64), "an indented line outside any option"),
            }
            continue;
        }
        let t = line.trim();
        if let Some(s) = t.strip_prefix('[') {
            let Some(s) = s.strip_suffix(']') else {
                refuse!(name, Some(no as u64), "`{t}` lacks its closing `]`");
            };
            let s = s.trim();
            if let (Some(inc), Some(chain)) = (s.strip_prefix("include "), chain.as_deref_mut()) {
                let inc = inc.trim();
                for path in included_files(file, inc)
                    .map_err(|e| e.context(format!("{name}:{no}: [include {inc}]")))?
                {
                    ini.files += 1;
                    if ini.files > MAX_INCLUDED_FILES {
                        refuse!(
                            name,
                            Some(no as u64),
                            "[include {inc}]: more than {MAX_INCLUDED_FILES} included files are read in all (files included many times over?)"
                        );
                    }
                    let key = abspath(&path);
                    if chain.contains(&key) {
                        refuse!(
                            name,
                            Some(no as u64),
                            "[include {inc}] includes {} again while it is being read (a file that includes itself), which Klipper refuses too (\"Recursive include\"); remove the include",
                            path.display()
                        );
                    }
                    if chain.len() >= MAX_INCLUDE_DEPTH {
                        refuse!(
                            name,
                            Some(no as u64),
                            "[include {inc}]: includes nest more than {MAX_INCLUDE_DEPTH} files deep (Klipper's own reader stops near 480); include the files from fewer levels"
                        );
                    }
                    let text = run
                        .files
                        .read_to_string(&path, crate::output::InputKind::Description)
                        .map_err(|e| e.named("included file").context(format!("{name}:{no}")))?;
                    ini.bytes += text.len();
                    if ini.bytes > MAX_INCLUDED_BYTES {
                        refuse!(
                            name,
                            Some(no as u64),
                            "[include {inc}]: the included files hold more than {} MiB in all (files included many times over?)",
                            MAX_INCLUDED_BYTES >> 20
                        );
                    }
                    chain.push(key);
                    // Klipper reads an included file whole (its comments
                    // cut, `\r\n` as `\n`), SAVE_CONFIG lines as comments.
                    let mut lines = text.split('\n').enumerate().map(|(i, l)| (i + 1, l));
                    parse_into(run, ini, &mut lines, &path, Some(chain), false)?;
                    chain.pop();
                }
                section = None;
            } else {
                section = Some(s.to_string());
            }
            last = None;
            continue;
        }
        let Some(sec) = &section else {
            refuse!(name, Some(no as u64), "`{t}` is outside any [section]");
        };
        let Some(sep) = t.find([':', '=']) else {
            refuse!(name, Some(no as u64), "`{t}` is not `key: value`");
        };
        ini.entries.push(Entry {
            section: sec.clone(),
            key: t[..sep].trim().to_lowercase(),
            value: t[sep + 1..].trim().to_string(),
            line: no,
            file: name.clone(),
            included: depth > 0,
            autosave,
        });
        last = Some(ini.entries.len() - 1);
    }
    Ok(())
}

/// A `printer.cfg`'s text and its options, as Klipper reads them (with its
/// includes).
pub fn read_config(run: &crate::Run<'_>, path: &Path) -> Result<(String, Ini)> {
    let text = run
        .files
        .read_to_string(path, crate::output::InputKind::Description)
        .map_err(|e| e.named("Klipper configuration"))?;
    let ini = parse_config(run, &text, path)?;
    Ok((text, ini))
}

/// Read a Klipper configuration as Klipper does: the regular part (with its
/// includes), then the SAVE_CONFIG block (split as [`split_autosave`]
/// splits it, refusing a block Klipper would ignore); every line numbered
/// from the file.
pub fn parse_config(run: &crate::Run<'_>, text: &str, file: &Path) -> Result<Ini> {
    let split = split_autosave(text, file)?;
    let mut ini = Ini {
        file: file.display().to_string(),
        header_line: split.header_line,
        ..Ini::default()
    };
    let mut chain = vec![abspath(file)];
    let mut lines = split
        .regular
        .split('\n')
        .enumerate()
        .map(|(i, l)| (i + 1, l));
    parse_into(run, &mut ini, &mut lines, file, Some(&mut chain), false)?;
    if let Some(block) = &split.block {
        let mut lines = block.iter().map(|(n, l)| (*n, l.as_str()));
        parse_into(run, &mut ini, &mut lines, file, None, true).map_err(|e| {
            e.context(format!(
                "in the SAVE_CONFIG block of {} (from line {})",
                file.display(),
                split.header_line.unwrap_or(1)
            ))
        })?;
    }
    ini.build_index();
    Ok(ini)
}

/// A probe result: the height measured with the carriages at `steps`.
#[derive(Debug, Clone)]
pub struct Probe {
    /// `height{N}` or `manual_height{N}`.
    pub name: String,
    /// The height (mm).
    pub height: f64,
    /// Steps from each tower's endstop.
    pub steps: [f64; 3],
}

/// A distance measured on Klipper's calibration object (`DELTA_ANALYZE`),
/// saved as `distance{N}` between two stable positions.
#[derive(Debug, Clone)]
pub struct Distance {
    /// `distance{N}`.
    pub name: String,
    /// The measured distance (mm).
    pub distance: f64,
    /// Steps from each tower's endstop at the two ends.
    pub steps: [[f64; 3]; 2],
}

/// A Klipper linear delta: its geometry and its saved probe results.

#[derive(Debug, Clone)]
pub struct KlipperDelta {
    /// `delta_radius` (mm).
    pub radius: f64,
    /// Tower `angle`s (degrees).
    pub angles: [f64; 3],
    /// `arm_length`s (mm).
    pub arms: [f64; 3],
    /// `position_endstop`s (mm).
    pub endstops: [f64; 3],
    /// Step distances (mm): `rotation_distance / (full_steps · microsteps ·
    /// gear ratio)`.
    pub step_distances: [f64; 3],
    /// `[delta_calibrate] radius` (mm): the probed circle.
    pub probe_radius: f64,
    /// The saved probe results.
    pub probes: Vec<Probe>,
    /// The saved distances measured on the calibration object.
    pub distances: Vec<Distance>,
}

impl KlipperDelta {
    /// `√(arm² − radius²)`: a carriage's height above the nozzle at the
    /// centre.
    fn rise(arm: f64, radius: f64) -> f64 {
        (arm * arm - radius * radius).sqrt()
    }

    /// The carriage heights (mm) of a stable position.
    pub fn carriage_heights(&self, steps: &[f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| {
            self.endstops[i] + Self::rise(self.arms[i], self.radius)
                - steps[i] * self.step_distances[i]
        })
    }

    /// The spatial description of this printer (TOML), in the names of
    /// `examples/linear-delta`.
    pub fn mechanism_toml(&self) -> String {
        self.description_toml(
            "a Klipper printer.cfg by `pkmcal klipper`",
            "[stepper_a], [stepper_b], [stepper_c]",
            "Klipper",
        )
    }

    /// [`KlipperDelta::mechanism_toml`] saying where it came from.
    pub fn description_toml(&self, origin: &str, towers: &str, firmware: &str) -> String {
        self.description_toml_with(origin, towers, firmware, false)
    }

    /// [`KlipperDelta::description_toml`], with one diagonal rod length
    /// `diagonal` shared by the three towers when `shared_arm` (the firmware
    /// keeps one, as RepRapFirmware's 7- and 9-factor calibrations fit it;
    /// the first arm's length).
    pub fn description_toml_with(
        &self,
        origin: &str,
        towers: &str,
        firmware: &str,
        shared_arm: bool,
    ) -> String {
        let arm = |t: &str| {
            if shared_arm {
                SHARED_ARM.to_string()
            } else {
                format!("arm_{t}")
            }
        };
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# A linear delta printer read from {origin}\n\
             # (towers a, b, c = {towers}; commands are\n\
             # carriage heights in mm; da, db, dc are endstop errors in carriage height).\n\
             type = \"spatial\"\nname = \"Linear delta printer (from {firmware})\"\n\
             free = [{}]\n\n[platform]\nmotion = \"translation\"\n",
            KLIPPER_FREE.map(|n| format!("\"{n}\"")).join(", ")
        );
        for t in TOWERS {
            let _ = writeln!(
                s,
                "[[leg]]\nname = \"tower_{t}\"\nangle = \"angle_{t}\"\n[[leg.joint]]\n\
                 name = \"{t}\"\nkind = \"prismatic\"\nat = [\"delta_radius\", 0.0, 0.0]\n\
                 axis = [0.0, 0.0, 1.0]\nactuated = true\nstiffness = {CARRIAGE_STIFFNESS:?}   # N/mm\n\
                 [leg.end]\nkind = \"rod\"\nlength = \"{}\"\nplatform = [0.0, 0.0, 0.0]\n",
                arm(t)
            );
        }
        let _ = writeln!(s, "[parameters]\ndelta_radius = {:?}", self.radius);
        for (i, t) in TOWERS.iter().enumerate() {
            let _ = writeln!(
                s,
                "angle_{t} = {:?}   # {}°",
                self.angles[i].to_radians(),
                self.angles[i]
            );
        }
        if shared_arm {
            let _ = writeln!(s, "{SHARED_ARM} = {:?}", self.arms[0]);
        } else {
            for (i, t) in TOWERS.iter().enumerate() {
                let _ = writeln!(s, "arm_{t} = {:?}", self.arms[i]);
            }
        }
        let _ = writeln!(s, "\n[assembly]\npose = [0.0, 0.0, 10.0]");
        for (i, t) in TOWERS.iter().enumerate() {
            let _ = writeln!(
                s,
                "{t} = {:?}",
                10.0 + Self::rise(self.arms[i], self.radius)
            );
        }
        let r = (1.1 * self.probe_radius).max(10.0);
        let _ = writeln!(
            s,
            "\n[workspace]   # the probed region\nx = [{:?}, {r:?}]\ny = [{:?}, {r:?}]\nz = [-10.0, 50.0]",
            -r, -r
        );
        s
    }

    /// Klipper's values for identified parameters of the description.
    pub fn identified(&self, spec: &pkmcal::Spec, p: &Params) -> Result<KlipperDelta> {
        let radius = p.get(spec, "delta_radius")?;
        let mut out = self.clone();
        out.radius = radius;
        for (i, t) in TOWERS.iter().enumerate() {
            let arm = p.get(spec, &format!("arm_{t}"))?;
            out.angles[i] = p.get(spec, &format!("angle_{t}"))?.to_degrees();
            out.arms[i] = arm;
            out.endstops[i] = self.endstops[i]
                + p.get(spec, &format!("d{t}"))?
                + Self::rise(self.arms[i], self.radius)
                - Self::rise(arm, radius);
            if arm.is_nan() || arm <= radius {
                invalid!(
                    "the identified arm_{t} = {arm:.3} mm is not longer than delta_radius = {radius:.3} mm; the probe data cannot support this parameter set (use fewer free parameters)"
                );
            }
        }
        Ok(out)
    }
}

/// The delta printer of a configuration.
pub fn delta_from_config(ini: &Ini) -> Result<KlipperDelta> {
    match ini.get("printer", "kinematics") {
        Some(e) if e.value.trim() == "delta" => {}
        Some(e) => refuse!(
            e.file,
            Some((e.line) as u64),
            "[printer] kinematics is `{}`; Klipper's delta printers are read (kinematics: delta or rotary_delta)",
            e.value
        ),
        None => refuse!(
            ini.file,
            None,
            "[printer] has no `kinematics`; Klipper's delta printers are read (kinematics: delta or rotary_delta)"
        ),
    }
    let Some(radius) = ini.length("printer", "delta_radius", true)? else {
        refuse!(ini.file, None, "[printer] needs a positive `delta_radius`");
    };
    let sec = |t: &str| format!("stepper_{t}");
    let Some(arm_a) = ini.length("stepper_a", "arm_length", true)? else {
        refuse!(ini.file, None, "[stepper_a] needs `arm_length`");
    };
    let Some(end_a) = ini.length("stepper_a", "position_endstop", false)? else {
        refuse!(ini.file, None, "[stepper_a] needs `position_endstop`");
    };
    let mut d = KlipperDelta {
        radius,
        angles: DEFAULT_ANGLES,
        arms: [arm_a; 3],
        endstops: [end_a; 3],
        step_distances: [0.0; 3],
        probe_radius: radius,
        probes: vec![],
        distances: vec![],
    };
    for (i, t) in TOWERS.iter().enumerate() {
        let s = sec(t);
        if !ini.has_section(&s) {
            refuse!(ini.file, None, "the configuration has no [{s}] section");
        }
        if let Some(a) = ini.number(&s, "angle")? {
            d.angles[i] = a;
        }
        if let Some(a) = ini.length(&s, "arm_length", true)? {
            d.arms[i] = a;
        }
        if d.arms[i] <= radius {
            refuse!(
                ini.file,
                None,
                "[{s}] arm_length = {} must be longer than delta_radius = {radius} (Klipper's own rule)",
                d.arms[i]
            );
        }
        if let Some(e) = ini.length(&s, "position_endstop", false)? {
            d.endstops[i] = e;
        }
        let Some(rotation) = ini.number(&s, "rotation_distance")?.filter(|v| *v > 0.0) else {
            refuse!(
                ini.file,
                None,
                "[{s}] needs a positive `rotation_distance` (mm)"
            );
        };
        let steps = steps_per_rotation(ini, &s)?;
        d.step_distances[i] = rotation / steps;
    }
    if let Some(r) = ini.number("delta_calibrate", "radius")? {
        d.probe_radius = r;
    }
    (d.probes, d.distances) = saved_results(ini)?;
    if d.probes.len() < KLIPPER_FREE.len() {
        refuse!(
            ini.file,
            None,
            "[delta_calibrate] holds {} probe results (height0, height0_pos, …); at least {} are needed: run DELTA_CALIBRATE in Klipper, then SAVE_CONFIG, and read the saved printer.cfg",
            d.probes.len(),
            KLIPPER_FREE.len()
        );
    }
    Ok(d)
}

/// A stepper's (micro)steps per rotation of its last gear, as Klipper
/// reads them: `full_steps_per_rotation` (200 by default, a whole multiple
/// of 4) times `microsteps` times the `gear_ratio` pairs `a:b` (1 by
/// default).
pub(crate) fn steps_per_rotation(ini: &Ini, s: &str) -> Result<f64> {
    let Some(micro) = ini.number(s, "microsteps")?.filter(|v| *v >= 1.0) else {
        refuse!(ini.file, None, "[{s}] needs `microsteps`");
    };
    let full = ini.number(s, "full_steps_per_rotation")?.unwrap_or(200.0);
    if !(full >= 1.0 && full.fract() == 0.0 && full % 4.0 == 0.0) {
        let e = ini
            .get(s, "full_steps_per_rotation")
            .expect("a number has an entry");
        refuse!(
            e.file,
            Some((e.line) as u64),
            "[{s}] full_steps_per_rotation = {full} must be a positive whole multiple of 4 (Klipper's own rule)"
        );
    }
    let mut gear = 1.0;
    if let Some(e) = ini.get(s, "gear_ratio") {
        for pair in e.value.split(',') {
            let v: Vec<f64> = pair
                .split(':')
                .filter_map(|x| x.trim().parse().ok())
                .collect();
            if v.len() != 2 || !(v[0] > 0.0 && v[1] > 0.0 && (v[0] / v[1]).is_finite()) {
                refuse!(
                    e.file,
                    Some((e.line) as u64),
                    "[{s}] gear_ratio = `{}` must be pairs `a:b` of positive numbers separated by commas",
                    e.value
                );
            }
            gear *= v[0] / v[1];
        }
    }
    Ok(full * micro * gear)
}

/// The probe results and calibration-object distances that
/// `DELTA_CALIBRATE` and `DELTA_ANALYZE` saved in `[delta_calibrate]`
/// (`manual_height{N}`, `height{N}` with their `_pos`, `distance{N}` with
/// `_pos1`, `_pos2`), in Klipper's order.
pub(crate) fn saved_results(ini: &Ini) -> Result<(Vec<Probe>, Vec<Distance>)> {
    let mut probes = vec![];
    let mut distances = vec![];
    for prefix in ["manual_height", "height"] {
        for n in 0.. {
            let key = format!("{prefix}{n}");
            let Some(h) = ini.number("delta_calibrate", &key)? else {
                break;
            };
            let steps = ini.triple("delta_calibrate", &format!("{key}_pos"))?;
            probes.push(Probe {
                name: key,
                height: h,
                steps,
            });
        }
    }
    for n in 0.. {
        let key = format!("distance{n}");
        let Some(v) = ini.number("delta_calibrate", &key)? else {
            break;
        };
        let steps = [
            ini.triple("delta_calibrate", &format!("{key}_pos1"))?,
            ini.triple("delta_calibrate", &format!("{key}_pos2"))?,
        ];
        distances.push(Distance {
            name: key,
            distance: v,
            steps,
        });
    }
    Ok((probes, distances))
}

/// The values `klipper` writes: (section, option, value).
fn klipper_values(new: &KlipperDelta) -> Vec<(String, String, String)> {
    let mut values: Vec<(String, String, String)> = vec![(
        "printer".into(),
        "delta_radius".into(),
        format!("{:.6}", new.radius),
    )];
    for (i, t) in TOWERS.iter().enumerate() {
        let s = format!("stepper_{t}");
        values.push((s.clone(), "angle".into(), format!("{:.6}", new.angles[i])));
        values.push((
            s.clone(),
            "arm_length".into(),
            format!("{:.6}", new.arms[i]),
        ));
        values.push((
            s,
            "position_endstop".into(),
            format!("{:.6}", new.endstops[i]),
        ));
    }
    values
}

/// The option name of a regular line, as Klipper's `_strip_duplicates`
/// reads it: the line cut at its first `#` or `;`, then the leading word
/// characters, lower case (configparser's option names).
fn option_name(pruned: &str) -> String {
    pruned
        .chars()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
        .collect::<String>()
        .to_lowercase()
}

/// The configuration text with Klipper's values replaced by `new`, as
/// Klipper's SAVE_CONFIG would make them take effect: set in the SAVE_CONFIG
/// block (created if missing), the same options in the regular part
/// commented out (with their continuation lines). Every other byte comes
/// out as it went in: other options, multi-line values (saved bed meshes,
/// scanner models), comments, line endings. An option that an included file
/// defines is refused, as Klipper's SAVE_CONFIG refuses it (the new value
/// would be ignored at the next start).
pub fn updated_config(text: &str, new: &KlipperDelta, ini: &Ini) -> Result<String> {
    updated_config_values(text, &klipper_values(new), ini)
}

/// [`updated_config`] with the options `values` (section, option, value).
pub(crate) fn updated_config_values(
    text: &str,
    values: &[(String, String, String)],
    ini: &Ini,
) -> Result<String> {
    for (sec, key, _) in values {
        if let Some(e) = ini
            .entries
            .iter()
            .find(|e| e.included && !e.autosave && e.section == *sec && e.key == *key)
        {
            refuse!(
                e.file,
                Some((e.line) as u64),
                "[{sec}] {key} is set in an included file, where a saved value cannot override it (Klipper's SAVE_CONFIG refuses it too); remove it there, or set the new value there by hand (and do not write the configuration)"
            );
        }
    }
    let eol = if text.contains("\r\n") { "\r\n" } else { "\n" };
    // The block from its header's line on, where Klipper found it.
    let header = ini.header_line.map(|h| {
        text.split_inclusive('\n')
            .take(h - 1)
            .map(str::len)
            .sum::<usize>()
    });
    let (regular, block) = match header {
        Some(pos) => (&text[..pos], Some(&text[pos..])),
        None => (text, None),
    };
    // The regular part: the saved options commented out.
    let set = |sec: &str, key: &str| values.iter().any(|(s, k, _)| s == sec && k == key);
    let mut out = String::with_capacity(text.len() + 1024);
    let mut section = String::new();
    let mut dup = false;
    for line in regular.split_inclusive('\n') {
        let pruned = line[..line.find(['#', ';']).unwrap_or(line.len())].trim_end();
        if pruned.is_empty() {
            out.push_str(line);
            continue;
        }
        if pruned.starts_with(char::is_whitespace) {
            if dup {
                out.push('#');
            }
            out.push_str(line);
            continue;
        }
        dup = false;
        if let Some(s) = pruned.strip_prefix('[') {
            section = s.strip_suffix(']').unwrap_or(s).trim().to_string();
        } else if set(&section, &option_name(pruned)) {
            dup = true;
            out.push('#');
        }
        out.push_str(line);
    }
    let Some(block) = block else {
        // No block yet: one written as Klipper writes it.
        let mut data = out.trim_end().to_string();
        data.push_str(eol);
        data.push_str(eol);
        data.push_str(AUTOSAVE_HEADER);
        data.push_str(eol);
        data.push_str("#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.");
        data.push_str(eol);
        data.push_str("#*#");
        data.push_str(eol);
        let mut sections: Vec<&str> = vec![];
        for (s, _, _) in values {
            if !sections.contains(&s.as_str()) {
                sections.push(s);
            }
        }
        for s in sections {
            let _ = write!(data, "#*# [{s}]{eol}");
            for (_, k, v) in values.iter().filter(|(x, _, _)| x == s) {
                let _ = write!(data, "#*# {k} = {v}{eol}");
            }
            let _ = write!(data, "#*#{eol}");
        }
        return read_back(data, ini);
    };
    out.push_str(&updated_block(block, values, eol));
    read_back(out, ini)
}

/// A written configuration, checked to hold a SAVE_CONFIG block Klipper
/// reads (never one it would ignore, losing the values).
fn read_back(text: String, ini: &Ini) -> Result<String> {
    match split_autosave(&text, Path::new(&ini.file)) {
        Ok(s) if s.block.is_some() => Ok(text),
        Ok(_) => invalid!("the written configuration has no SAVE_CONFIG block (a pkmcal bug); nothing was written"),
        Err(e) => Err(e.context("the written configuration's SAVE_CONFIG block would be ignored by Klipper (a pkmcal bug); nothing was written")),
    }
}

/// The SAVE_CONFIG block (from its header line on) with `values` set, line
/// by line: each definition of a set option replaced (its continuation lines
/// dropped), a missing option added at the end of its section, a missing
/// section added at the end; every other line as it was.
fn updated_block(block: &str, values: &[(String, String, String)], eol: &str) -> String {
    #[derive(PartialEq)]
    enum Kind {
        Other,
        Section(String),
        Option(String),
        Continuation,
    }
    let lines: Vec<&str> = block.split_inclusive('\n').collect();
    let kinds: Vec<Kind> = lines
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let l = l.trim_end_matches(['\n', '\r']);
            let Some(c) = l.strip_prefix("#*#") else {
                return Kind::Other;
            };
            let c = c.strip_prefix(' ').unwrap_or(c);
            let pruned = c[..c.find(['#', ';']).unwrap_or(c.len())].trim_end();
            if i == 0 || pruned.is_empty() {
                Kind::Other
            } else if pruned.starts_with(char::is_whitespace) {
                Kind::Continuation
            } else if let Some(s) = pruned.strip_prefix('[') {
                Kind::Section(s.strip_suffix(']').unwrap_or(s).trim().to_string())
            } else {
                Kind::Option(option_name(pruned))
            }
        })
        .collect();
    // Each line's section, and what replaces or follows it.
    let mut section_of = vec![String::new(); lines.len()];
    let mut current = String::new();
    for (i, k) in kinds.iter().enumerate() {
        if let Kind::Section(s) = k {
            current = s.clone();
        }
        section_of[i] = current.clone();
    }
    let mut replace: Vec<Option<String>> = vec![None; lines.len()];
    let mut drop = vec![false; lines.len()];
    let mut after: Vec<Vec<String>> = vec![vec![]; lines.len()];
    let mut appended: Vec<(String, Vec<String>)> = vec![];
    for (sec, key, value) in values {
        let mut found = false;
        let mut in_option = false;
        for i in 0..lines.len() {
            match &kinds[i] {
                Kind::Option(k) if section_of[i] == *sec && k == key => {
                    let l = lines[i].trim_end_matches(['\n', '\r']);
                    let c = l["#*#".len()..].trim_start();
                    let name: String = c
                        .chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect();
                    let end = &lines[i][l.len()..];
                    replace[i] = Some(format!("#*# {name} = {value}{end}"));
                    found = true;
                    in_option = true;
                }
                Kind::Continuation if in_option => drop[i] = true,
                Kind::Continuation | Kind::Other => {}
                _ => in_option = false,
            }
        }
        if found {
            continue;
        }
        // The last option or continuation line of the section's last
        // occurrence; a new section at the end if there is none.
        let last = (0..lines.len()).rev().find(|&i| {
            section_of[i] == *sec
                && matches!(
                    kinds[i],
                    Kind::Option(_) | Kind::Continuation | Kind::Section(_)
                )
        });
        let line = format!("#*# {key} = {value}{eol}");
        match last {
            Some(i) => after[i].push(line),
            None => match appended.iter_mut().find(|(s, _)| s == sec) {
                Some((_, l)) => l.push(line),
                None => appended.push((sec.clone(), vec![line])),
            },
        }
    }
    let mut out = String::with_capacity(block.len() + 1024);
    for (i, l) in lines.iter().enumerate() {
        if drop[i] {
            continue;
        }
        // A last line without its end of line gets one before anything follows.
        let text = replace[i].as_deref().unwrap_or(l);
        out.push_str(text);
        if !after[i].is_empty() && !text.ends_with('\n') {
            out.push_str(eol);
        }
        for a in &after[i] {
            out.push_str(a);
        }
    }
    if !appended.is_empty() {
        // Blank lines after the block stay after it: inside it, they would
        // make Klipper ignore the whole block.
        let body = out.trim_end_matches(|c: char| c.is_whitespace()).len();
        let body = out[body..].find('\n').map_or(out.len(), |k| body + k + 1);
        let tail = out.split_off(body);
        if !out.ends_with('\n') {
            out.push_str(eol);
        }
        // Sections are separated by an empty `#*#` line, as Klipper writes them.
        if !out.trim_end().ends_with("\n#*#") {
            let _ = write!(out, "#*#{eol}");
        }
        for (s, l) in appended {
            let _ = write!(out, "#*# [{s}]{eol}");
            for x in l {
                out.push_str(&x);
            }
            let _ = write!(out, "#*#{eol}");
        }
        out.push_str(&tail);
    }
    out
}

/// The files a printer's mechanism directory holds.
pub const OUT_DIR_FILES: [&str; 3] = ["mechanism.toml", "probes.csv", "calibration.toml"];
/// And the distances, when the configuration saves any.
pub const DISTANCES_FILE: &str = "distances.csv";

/// The files of a calibrated printer's model as pkmcal files, for the
/// other commands, each under `dir` with its bytes (to stage together):
/// the printer as a mechanism ([`Firmware::description`]), its probe
/// heights as data (in the base frame, the carriages' commands and the
/// probe's reading), the distances measured on the calibration object
/// where it has any, and the identified parameters, whose header names
/// `config`, the configuration they came from.
pub fn out_dir_files(
    printer: &dyn Firmware,
    calibrated: &super::PrinterCalibration,
    config: &Path,
    dir: &Path,
) -> Vec<(PathBuf, Vec<u8>)> {
    use pkmcal::Mechanism as _;
    let spec = calibrated.mech.spec();
    let readings = &calibrated.readings;
    let names = spec.actuated_names();
    let mut csv = format!("# frame: base\n{},probe\n", names.join(","));
    for m in &readings.poses {
        let _ = writeln!(
            csv,
            "{:?},{:?},{:?},{:?}",
            m.commands[0], m.commands[1], m.commands[2], m.measured[0]
        );
    }
    let [m_file, d_file, p_file] = OUT_DIR_FILES;
    let mut files = vec![
        (dir.join(m_file), printer.description().into_bytes()),
        (dir.join(d_file), csv.into_bytes()),
    ];
    if !readings.distances.is_empty() {
        let ends = |end: &str| {
            names
                .iter()
                .map(|n| format!("{n}_{end}"))
                .collect::<Vec<_>>()
                .join(",")
        };
        let mut csv = format!("{},{},distance\n", ends("1"), ends("2"));
        for m in &readings.distances {
            let b = m.partner.as_deref().unwrap_or_default();
            let _ = writeln!(
                csv,
                "{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
                m.commands[0], m.commands[1], m.commands[2], b[0], b[1], b[2], m.measured[0]
            );
        }
        files.push((dir.join(DISTANCES_FILE), csv.into_bytes()));
    }
    files.push((
        dir.join(p_file),
        crate::params::params_to_string(
            spec,
            &calibrated.calibration().params,
            &format!(
                "pkmcal klipper: identified from the probe heights of {}",
                config.display()
            ),
        )
        .into_bytes(),
    ));
    files
}

/// The weight of the heights in Klipper's extended calibration: its cost
/// `z_weight · Σ heights² + Σ distances²` with `z_weight = n_distances /
/// (0.5 · n_probed)`, which weighs them as variances `σ_height² /
/// σ_distance² = 1 / z_weight`.
pub fn klipper_z_weight(delta: &KlipperDelta) -> f64 {
    z_weight(&delta.probes, &delta.distances)
}

/// [`klipper_z_weight`] of saved probe results and distances.
pub(crate) fn z_weight(probes: &[Probe], distances: &[Distance]) -> f64 {
    let probed = probes
        .iter()
        .filter(|p| !p.name.starts_with("manual"))
        .count()
        .max(1);
    distances.len() as f64 / (KLIPPER_MEASURE_WEIGHT * probed as f64)
}

/// The probe heights and calibration-object distances Klipper saved, as
/// readings of its printer (linear or rotary: `commands` turns a probe's
/// steps from the endstops into the mechanism's commands). With Klipper's
/// weighting and distances, its cost `z_weight · Σ heights² + Σ distances²`
/// is given as known standard deviations: σ_distance 1 (in mm; only the
/// ratio acts), σ_height 1/√z_weight.
pub(super) fn saved_readings(
    spec: &pkmcal::Spec,
    probes: &[Probe],
    saved: &[Distance],
    commands: impl Fn(&[f64; 3]) -> [f64; 3],
    weighting: Weighting,
    z_weight: f64,
) -> Result<Readings> {
    let origin = |i: usize, distance: bool| {
        Some(pkmcal::Origin {
            pose: i + 1,
            line: None,
            distance,
        })
    };
    let mut poses: Vec<pkmcal::Measurement> = probes
        .iter()
        .enumerate()
        .map(|(i, p)| pkmcal::Measurement {
            point: None,
            target: None,
            commands: commands(&p.steps).to_vec(),
            partner: None,
            measured: vec![p.height],
            sigma: vec![],
            origin: origin(i, false),
        })
        .collect();
    let mut distances: Vec<pkmcal::Measurement> = saved
        .iter()
        .enumerate()
        .map(|(i, d)| pkmcal::Measurement {
            point: None,
            target: None,
            commands: commands(&d.steps[0]).to_vec(),
            partner: Some(commands(&d.steps[1]).to_vec()),
            measured: vec![d.distance],
            sigma: vec![],
            origin: origin(i, true),
        })
        .collect();
    if weighting == Weighting::Klipper && !saved.is_empty() {
        for m in &mut poses {
            m.sigma = vec![Some(1.0 / z_weight.sqrt())];
        }
        for m in &mut distances {
            m.sigma = vec![Some(1.0)];
        }
    }
    Ok(Readings {
        measurement: MeasurementModel::probe(spec)?,
        poses,
        distances,
    })
}

/// With the shrunk weighting and distances: Klipper's ratio
/// (`z_weight`) as the stated one, its scale estimated.
pub(super) fn configure_weighting(
    request: &mut Request,
    readings: &Readings,
    weighting: Weighting,
    z_weight: f64,
) {
    if let Weighting::Shrunk(readings_worth) = weighting
        && !readings.distances.is_empty()
    {
        request.stated_noise = Some(1.0 / z_weight.sqrt());
        request.stated_distance_noise = Some(1.0);
        request.stated_readings = readings_worth;
        request.stated_relative = true;
    }
}

/// A Klipper printer: its configuration's text and path, as read, and the
/// weighting of its heights against its calibration object's distances.
pub struct KlipperPrinter {
    /// The configuration file.
    pub path: PathBuf,
    /// Its text.
    pub text: String,
    /// Its options, as Klipper reads them.
    pub ini: Ini,
    /// The printer.
    pub delta: KlipperDelta,
    /// How heights and distances are weighed.
    pub weighting: Weighting,
}

impl KlipperPrinter {
    /// Read a `printer.cfg` (with its includes) as Klipper reads it.
    pub fn read(run: &crate::Run<'_>, path: &Path, weighting: Weighting) -> Result<Self> {
        let (text, ini) = read_config(run, path)?;
        Self::from_parsed(path, text, ini, weighting)
    }

    /// This configuration with `previous`'s saved probe results and
    /// calibration-object distances in place of its own: an earlier
    /// `DELTA_CALIBRATE`'s readings as this configuration reads them. The
    /// saved positions are steps from the endstop switches, which belong to
    /// the printer; the configured geometry only labels them, and a
    /// recalibration changes it. Read with one configuration, two sets of
    /// readings of an unchanged printer fit the same printer (`--physical
    /// --previous`: with each file's own geometry, the fits' unseen parts sat
    /// at different tolerance centres and the drift test saw a change).
    pub fn with_readings_of(mut self, previous: KlipperPrinter) -> Self {
        self.delta.probes = previous.delta.probes;
        self.delta.distances = previous.delta.distances;
        self
    }

    /// A `printer.cfg` read ([`read_config`]), as Klipper reads it.
    pub fn from_parsed(path: &Path, text: String, ini: Ini, weighting: Weighting) -> Result<Self> {
        let delta = delta_from_config(&ini)?;
        Ok(KlipperPrinter {
            path: path.to_path_buf(),
            text,
            ini,
            delta,
            weighting,
        })
    }
}

impl Firmware for KlipperPrinter {
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
        let delta = &self.delta;
        saved_readings(
            spec,
            &delta.probes,
            &delta.distances,
            |steps| delta.carriage_heights(steps),
            self.weighting,
            klipper_z_weight(delta),
        )
    }

    fn default_free(&self, spec: &pkmcal::Spec, readings: &Readings) -> Vec<String> {
        let mut default: Vec<String> = spec.default_free.clone();
        if !readings.distances.is_empty() {
            default.extend(KLIPPER_EXTENDED.map(String::from));
        }
        default
    }

    fn configure(&self, request: &mut Request, readings: &Readings) {
        configure_weighting(
            request,
            readings,
            self.weighting,
            klipper_z_weight(&self.delta),
        );
    }

    fn values(
        &self,
        spec: &pkmcal::Spec,
        params: &Params,
        _instrument: &[f64],
    ) -> Result<Vec<FirmwareValue>> {
        let new = self.delta.identified(spec, params)?;
        let old = &self.delta;
        let mut out = vec![FirmwareValue {
            name: "[printer] delta_radius".into(),
            before: old.radius,
            after: new.radius,
            unit: "mm",
            sigma: None,
        }];
        for (i, t) in TOWERS.iter().enumerate() {
            for (key, a, b, unit) in [
                ("angle", old.angles[i], new.angles[i], "°"),
                ("arm_length", old.arms[i], new.arms[i], "mm"),
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
        let new = self.delta.identified(spec, params)?;
        updated_config(&self.text, &new, &self.ini)
    }

    fn linear_delta(&self) -> Result<Option<super::physical::LinearDelta>> {
        Ok(Some(super::physical::LinearDelta {
            delta: self.delta.clone(),
            probe_offset: probe_offset(&self.ini)?,
            firmware: super::Flavour::Klipper,
            values: KLIPPER_VALUES.map(String::from).to_vec(),
            corrects_bed_tilt: false,
            print_radius: match self.ini.length("printer", "print_radius", true)? {
                Some(r) => r,
                None => self.delta.probe_radius,
            },
            probe_height: probe_height(&self.ini, &self.delta.probes)?,
            homed_height: self
                .delta
                .endstops
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min),
        }))
    }

    fn mesh_layout(
        &self,
        radius: f64,
        count: Option<usize>,
    ) -> Result<Option<super::height_map::MeshLayout>> {
        super::height_map::klipper_layout(&self.ini, radius, count).map(Some)
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
