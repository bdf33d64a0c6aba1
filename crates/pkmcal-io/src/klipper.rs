//! `klipper`: calibrate a linear delta printer from its Klipper `printer.cfg`
//! and write the values back in Klipper's keys.
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

use anyhow::{Context, Result, bail};
use pkmcal::{CalibrationOptions, MeasurementModel, Mechanism, Model, Params};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What `pkmcal klipper` is asked to do.
pub struct KlipperConfig {
    /// The printer's `printer.cfg`.
    pub config: PathBuf,
    /// Parameters to identify (names of the linear delta; `default` allowed).
    pub free: Option<String>,
    /// Parameters to keep fixed (removed from the free set).
    pub fix: Option<String>,
    /// Where to write the updated `printer.cfg`.
    pub out: Option<PathBuf>,
    /// Where to write the mechanism, the probe data and the parameters.
    pub out_dir: Option<PathBuf>,
    /// How heights and distances are weighed against each other.
    pub weighting: Weighting,
}

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
struct Entry {
    section: String,
    key: String,
    value: String,
    line: usize,
    file: String,
    /// Read from an included file (not the configuration named).
    included: bool,
    /// Read from the SAVE_CONFIG block.
    autosave: bool,
}

/// A Klipper configuration: every option, the SAVE_CONFIG block's last.
#[derive(Debug, Default)]
pub struct Ini {
    entries: Vec<Entry>,
    /// The configuration's own file (for messages about what it lacks).
    file: String,
    /// (section, option) -> the last regular and the last saved entry.
    index: std::collections::HashMap<(String, String), (Option<usize>, Option<usize>)>,
    /// Included files read so far (bounded by [`MAX_INCLUDED_FILES`]).
    files: usize,
    /// Their bytes (bounded by [`MAX_INCLUDED_BYTES`]).
    bytes: usize,
}

/// The most bytes the included files of one configuration may hold in all.
const MAX_INCLUDED_BYTES: usize = 64 << 20;

/// The most included files one configuration may read in all (a printer's
/// folder holds tens; includes that fan out could otherwise read millions).
const MAX_INCLUDED_FILES: usize = 1000;

/// The files `[include spec]` in `file` names, as Klipper resolves them:
/// relative to the including file's directory; a pattern (`*`, `?`, `[`)
/// expanded and sorted, an empty match allowed; a plain name must exist.
fn included_files(file: &Path, spec: &str) -> Result<Vec<PathBuf>> {
    let path = file.parent().unwrap_or(Path::new(".")).join(spec);
    if !spec.contains(['*', '?', '[']) {
        if !path.exists() {
            bail!("the included file {} does not exist", path.display());
        }
        return Ok(vec![path]);
    }
    let pattern = path.to_string_lossy().into_owned();
    // Python's glob, which Klipper uses: hidden files only by a leading dot.
    let options = glob::MatchOptions {
        case_sensitive: true,
        require_literal_separator: true,
        require_literal_leading_dot: true,
    };
    let mut found: Vec<PathBuf> = glob::glob_with(&pattern, options)
        .context("not a valid pattern")?
        .filter_map(std::result::Result::ok)
        .collect();
    // Sorted as Python sorts the names (by code point).
    found.sort_by(|a, b| a.to_string_lossy().cmp(&b.to_string_lossy()));
    Ok(found)
}

impl Ini {
    /// The value of `key` in `[section]` as Klipper reads it: the last
    /// definition in the regular part (its includes at their place) wins, and
    /// the SAVE_CONFIG block's only when the regular part has none (Klipper
    /// comments out the block's duplicates at start, `_strip_duplicates`).
    fn get(&self, section: &str, key: &str) -> Option<&Entry> {
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
    fn length(&self, section: &str, key: &str, positive: bool) -> Result<Option<f64>> {
        let Some(v) = self.number(section, key)? else {
            return Ok(None);
        };
        let e = self.get(section, key).expect("a number has an entry");
        if v.abs() > MAX_KLIPPER_LENGTH_MM || (positive && v <= 0.0) {
            bail!(
                "{}:{}: [{section}] {key} = {} mm must be {}at most {MAX_KLIPPER_LENGTH_MM:e} mm in size",
                e.file,
                e.line,
                e.value.trim(),
                if positive { "positive and " } else { "" }
            );
        }
        Ok(Some(v))
    }

    fn has_section(&self, section: &str) -> bool {
        self.entries.iter().any(|e| e.section == section)
    }

    /// A number, with the place it came from in an error.
    fn number(&self, section: &str, key: &str) -> Result<Option<f64>> {
        let Some(e) = self.get(section, key) else {
            return Ok(None);
        };
        let v: f64 = e.value.trim().parse().with_context(|| {
            format!(
                "{}:{}: [{section}] {key} = `{}` is not a number",
                e.file, e.line, e.value
            )
        })?;
        if !v.is_finite() {
            bail!("{}:{}: [{section}] {key} must be finite", e.file, e.line);
        }
        Ok(Some(v))
    }

    /// Three numbers `x,y,z` (a stable position).
    fn triple(&self, section: &str, key: &str) -> Result<[f64; 3]> {
        let e = self
            .get(section, key)
            .with_context(|| format!("{}: [{section}] has no `{key}`", self.file))?;
        let v: Vec<f64> = e
            .value
            .split(',')
            .map(|s| s.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .ok()
            .filter(|v: &Vec<f64>| v.len() == 3 && v.iter().all(|x| x.is_finite()))
            .with_context(|| {
                format!(
                    "{}:{}: [{section}] {key} = `{}` must be three numbers `a,b,c` (steps from each tower's endstop)",
                    e.file, e.line, e.value
                )
            })?;
        Ok([v[0], v[1], v[2]])
    }
}

/// Split a file into its regular part and its SAVE_CONFIG block (prefixes
/// removed); `None` for the block when there is none.
fn split_autosave(text: &str) -> (String, Option<String>) {
    match text.find(AUTOSAVE_HEADER) {
        None => (text.to_string(), None),
        Some(pos) => {
            // Line for line (the notice blanked), so that the block's
            // lines keep their numbers ([`parse_config`] adds the offset).
            let block = text[pos..]
                .lines()
                .skip(1)
                .map(|l| l.strip_prefix("#*#").unwrap_or(l))
                .map(|l| l.strip_prefix(' ').unwrap_or(l))
                .map(|l| if l.starts_with("DO NOT EDIT") { "" } else { l })
                .collect::<Vec<_>>()
                .join("\n");
            (text[..pos].to_string(), Some(block))
        }
    }
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

/// Parse one file's options into `ini` (following `[include …]`).
fn parse_into(
    run: &crate::Run<'_>,
    ini: &mut Ini,
    text: &str,
    file: &Path,
    depth: usize,
) -> Result<()> {
    if depth > 8 {
        bail!(
            "{}: [include] nests more than 8 deep (a file includes itself?)",
            file.display()
        );
    }
    let name = file.display().to_string();
    if text.starts_with('\u{feff}') {
        bail!(
            "{name}:1: the file starts with a byte-order mark (a UTF-8 BOM), which Klipper does not read (its first line would be outside any section); save the file as UTF-8 without BOM"
        );
    }
    let mut section: Option<String> = None;
    let mut last: Option<usize> = None;
    for (i, raw) in text.lines().enumerate() {
        let line = strip_comment(raw);
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
                None => bail!("{name}:{}: an indented line outside any option", i + 1),
            }
            continue;
        }
        let t = line.trim();
        if let Some(s) = t.strip_prefix('[') {
            let s = s
                .strip_suffix(']')
                .with_context(|| format!("{name}:{}: `{t}` lacks its closing `]`", i + 1))?
                .trim();
            if let Some(inc) = s.strip_prefix("include ") {
                let inc = inc.trim();
                for path in included_files(file, inc)
                    .with_context(|| format!("{name}:{}: [include {inc}]", i + 1))?
                {
                    ini.files += 1;
                    if ini.files > MAX_INCLUDED_FILES {
                        bail!(
                            "{name}:{}: [include {inc}]: more than {MAX_INCLUDED_FILES} included files are read in all (files included many times over?)",
                            i + 1
                        );
                    }
                    let text = run
                        .files
                        .read_to_string(&path, crate::output::InputKind::Description)
                        .with_context(|| {
                            format!("{name}:{}: cannot read included {}", i + 1, path.display())
                        })?;
                    ini.bytes += text.len();
                    if ini.bytes > MAX_INCLUDED_BYTES {
                        bail!(
                            "{name}:{}: [include {inc}]: the included files hold more than {} MiB in all (files included many times over?)",
                            i + 1,
                            MAX_INCLUDED_BYTES >> 20
                        );
                    }
                    parse_into(run, ini, &text, &path, depth + 1)?;
                }
                section = None;
            } else {
                section = Some(s.to_string());
            }
            last = None;
            continue;
        }
        let Some(sec) = &section else {
            bail!("{name}:{}: `{t}` is outside any [section]", i + 1);
        };
        let sep = t
            .find([':', '='])
            .with_context(|| format!("{name}:{}: `{t}` is not `key: value`", i + 1))?;
        ini.entries.push(Entry {
            section: sec.clone(),
            key: t[..sep].trim().to_lowercase(),
            value: t[sep + 1..].trim().to_string(),
            line: i + 1,
            file: name.clone(),
            included: depth > 0,
            autosave: false,
        });
        last = Some(ini.entries.len() - 1);
    }
    Ok(())
}

/// Read a Klipper configuration: the regular part (with its includes), then
/// the SAVE_CONFIG block.
pub fn parse_config(run: &crate::Run<'_>, text: &str, file: &Path) -> Result<Ini> {
    let (regular, block) = split_autosave(text);
    let mut ini = Ini {
        file: file.display().to_string(),
        ..Ini::default()
    };
    parse_into(run, &mut ini, &regular, file, 0)?;
    if let Some(b) = block {
        let mut saved = Ini::default();
        parse_into(run, &mut saved, &b, file, 0)
            .with_context(|| format!("in the SAVE_CONFIG block of {}", file.display()))?;
        // The block starts on the line after its header.
        let offset = regular.matches('\n').count() + 1;
        ini.entries.extend(saved.entries.into_iter().map(|e| Entry {
            autosave: true,
            line: e.line + offset,
            ..e
        }));
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
                bail!(
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
        Some(e) => bail!(
            "{}:{}: [printer] kinematics is `{}`; `pkmcal klipper` reads delta printers (kinematics: delta)",
            e.file,
            e.line,
            e.value
        ),
        None => bail!(
            "{}: [printer] has no `kinematics`; `pkmcal klipper` reads delta printers (kinematics: delta)",
            ini.file
        ),
    }
    let radius = ini
        .length("printer", "delta_radius", true)?
        .with_context(|| format!("{}: [printer] needs a positive `delta_radius`", ini.file))?;
    let sec = |t: &str| format!("stepper_{t}");
    let arm_a = ini
        .length("stepper_a", "arm_length", true)?
        .with_context(|| format!("{}: [stepper_a] needs `arm_length`", ini.file))?;
    let end_a = ini
        .length("stepper_a", "position_endstop", false)?
        .with_context(|| format!("{}: [stepper_a] needs `position_endstop`", ini.file))?;
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
            bail!("{}: the configuration has no [{s}] section", ini.file);
        }
        if let Some(a) = ini.number(&s, "angle")? {
            d.angles[i] = a;
        }
        if let Some(a) = ini.length(&s, "arm_length", true)? {
            d.arms[i] = a;
        }
        if d.arms[i] <= radius {
            bail!(
                "{}: [{s}] arm_length = {} must be longer than delta_radius = {radius} (Klipper's own rule)",
                ini.file,
                d.arms[i]
            );
        }
        if let Some(e) = ini.length(&s, "position_endstop", false)? {
            d.endstops[i] = e;
        }
        let rotation = ini
            .number(&s, "rotation_distance")?
            .filter(|v| *v > 0.0)
            .with_context(|| {
                format!(
                    "{}: [{s}] needs a positive `rotation_distance` (mm)",
                    ini.file
                )
            })?;
        let micro = ini
            .number(&s, "microsteps")?
            .filter(|v| *v >= 1.0)
            .with_context(|| format!("{}: [{s}] needs `microsteps`", ini.file))?;
        let full = ini.number(&s, "full_steps_per_rotation")?.unwrap_or(200.0);
        if !(full >= 1.0 && full.fract() == 0.0 && full % 4.0 == 0.0) {
            let e = ini
                .get(&s, "full_steps_per_rotation")
                .expect("a number has an entry");
            bail!(
                "{}:{}: [{s}] full_steps_per_rotation = {full} must be a positive whole multiple of 4 (Klipper's own rule)",
                e.file,
                e.line
            );
        }
        let mut gear = 1.0;
        if let Some(e) = ini.get(&s, "gear_ratio") {
            for pair in e.value.split(',') {
                let v: Vec<f64> = pair
                    .split(':')
                    .filter_map(|x| x.trim().parse().ok())
                    .collect();
                if v.len() != 2 || !(v[0] > 0.0 && v[1] > 0.0 && (v[0] / v[1]).is_finite()) {
                    bail!(
                        "{}:{}: [{s}] gear_ratio = `{}` must be pairs `a:b` of positive numbers separated by commas",
                        e.file,
                        e.line,
                        e.value
                    );
                }
                gear *= v[0] / v[1];
            }
        }
        d.step_distances[i] = rotation / (full * micro * gear);
    }
    if let Some(r) = ini.number("delta_calibrate", "radius")? {
        d.probe_radius = r;
    }
    for prefix in ["manual_height", "height"] {
        for n in 0.. {
            let key = format!("{prefix}{n}");
            let Some(h) = ini.number("delta_calibrate", &key)? else {
                break;
            };
            let steps = ini.triple("delta_calibrate", &format!("{key}_pos"))?;
            d.probes.push(Probe {
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
        d.distances.push(Distance {
            name: key,
            distance: v,
            steps,
        });
    }
    if d.probes.len() < KLIPPER_FREE.len() {
        bail!(
            "{}: [delta_calibrate] holds {} probe results (height0, height0_pos, …); at least {} are needed: run DELTA_CALIBRATE in Klipper, then SAVE_CONFIG, and read the saved printer.cfg",
            ini.file,
            d.probes.len(),
            KLIPPER_FREE.len()
        );
    }
    Ok(d)
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
    let values = klipper_values(new);
    for (sec, key, _) in &values {
        if let Some(e) = ini
            .entries
            .iter()
            .find(|e| e.included && !e.autosave && e.section == *sec && e.key == *key)
        {
            bail!(
                "{}:{}: [{sec}] {key} is set in an included file, where a saved value cannot override it (Klipper's SAVE_CONFIG refuses it too); remove it there, or set the new value there by hand, and run again without --out",
                e.file,
                e.line
            );
        }
    }
    let eol = if text.contains("\r\n") { "\r\n" } else { "\n" };
    let (regular, block) = match text.find(AUTOSAVE_HEADER) {
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
        for (s, _, _) in &values {
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
        return Ok(data);
    };
    out.push_str(&updated_block(block, &values, eol));
    Ok(out)
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
    }
    out
}

/// Height errors (mm) of every probe for the printer's parameters `p` and
/// the bed plane's `bed`: the predicted reading minus the probed one.
fn height_errors(
    mech: &pkmcal::AnyMechanism,
    measurement: &MeasurementModel,
    p: &Params,
    bed: &[f64],
    data: &[pkmcal::Measurement],
) -> Result<Vec<f64>> {
    use rayon::prelude::*;
    data.par_iter()
        .map(|m| {
            let pr = pkmcal::predict(mech, p, &m.commands, Model::Exact, &[])?;
            let mut y = [0.0];
            measurement.observe(&pr.x, bed, &mut y);
            Ok(y[0] - m.measured[0])
        })
        .collect()
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

/// What `pkmcal klipper` fits for a printer: its description, the probe
/// model, the readings (the probe heights as poses, then the distances
/// measured on the calibration object as pairs of poses), the fit's options
/// and the free parameters' names.
pub struct KlipperProblem {
    pub mech: crate::io::Mech,
    pub measurement: MeasurementModel,
    pub data: Vec<pkmcal::Measurement>,
    pub opts: CalibrationOptions,
    pub free_names: Vec<String>,
}

/// [`KlipperProblem`] of a printer, weighted by `weighting`, with the free
/// set `free` (`default` when `None`) less `fix`.
pub fn klipper_problem(
    delta: &KlipperDelta,
    weighting: Weighting,
    free: Option<&str>,
    fix: Option<&str>,
) -> Result<KlipperProblem> {
    let toml = delta.mechanism_toml();
    let mech = crate::io::mechanism_from_str(&toml)
        .context("the printer's geometry does not describe a delta that assembles")?;
    let spec = mech.spec();
    let data: Vec<pkmcal::Measurement> = delta
        .probes
        .iter()
        .enumerate()
        .map(|(i, p)| pkmcal::Measurement {
            target: None,
            commands: delta.carriage_heights(&p.steps).to_vec(),
            partner: None,
            measured: vec![p.height],
            sigma: vec![],
            origin: Some(pkmcal::Origin {
                pose: i + 1,
                line: None,
                distance: false,
            }),
        })
        .chain(
            delta
                .distances
                .iter()
                .enumerate()
                .map(|(i, d)| pkmcal::Measurement {
                    target: None,
                    commands: delta.carriage_heights(&d.steps[0]).to_vec(),
                    partner: Some(delta.carriage_heights(&d.steps[1]).to_vec()),
                    measured: vec![d.distance],
                    sigma: vec![],
                    origin: Some(pkmcal::Origin {
                        pose: i + 1,
                        line: None,
                        distance: true,
                    }),
                }),
        )
        .collect();
    let mut data = data;
    if weighting == Weighting::Klipper && !delta.distances.is_empty() {
        // Klipper's cost `z_weight · Σ heights² + Σ distances²` as known
        // standard deviations: σ_distance 1 (in mm; only the ratio acts),
        // σ_height 1/√z_weight.
        let z_weight = klipper_z_weight(delta);
        for m in &mut data {
            m.sigma = vec![Some(if m.partner.is_some() {
                1.0
            } else {
                1.0 / z_weight.sqrt()
            })];
        }
    }
    let measurement = MeasurementModel::probe(spec)?;
    let mut default: Vec<String> = spec.default_free.clone();
    if !delta.distances.is_empty() {
        default.extend(KLIPPER_EXTENDED.map(String::from));
    }
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    if let Weighting::Shrunk(readings) = weighting
        && !delta.distances.is_empty()
    {
        // Klipper's ratio as the stated one, its scale estimated.
        opts.stated_noise = Some(pkmcal::Noise::lengths(1.0 / klipper_z_weight(delta).sqrt()));
        opts.stated_distance_noise = Some(1.0);
        opts.stated_noise_readings = readings;
        opts.stated_noise_relative = true;
    }
    let free_names;
    (free_names, opts.free) = free_list(free, fix, &default, spec, &measurement)?;
    Ok(KlipperProblem {
        mech,
        measurement,
        data,
        opts,
        free_names,
    })
}

/// Run `pkmcal klipper`.
pub fn run_klipper(run: &crate::Run<'_>, c: KlipperConfig) -> Result<()> {
    let text = run
        .files
        .read_to_string(&c.config, crate::output::InputKind::Description)
        .with_context(|| format!("cannot read Klipper configuration {}", c.config.display()))?;
    let ini = parse_config(run, &text, &c.config)?;
    let delta = delta_from_config(&ini)?;
    let KlipperProblem {
        mech,
        measurement,
        data,
        opts,
        free_names,
    } = klipper_problem(&delta, c.weighting, c.free.as_deref(), c.fix.as_deref())?;
    let spec = mech.spec();
    let heights = &data[..delta.probes.len()];
    let nominal = Params::nominal(spec);
    // The study every front end runs: the heights as poses, the distances
    // measured on the calibration object as distances between poses.
    let (poses, distances) = data.split_at(delta.probes.len());
    let study = pkmcal::identify::study(
        &mech,
        &measurement,
        poses,
        distances.to_vec(),
        &nominal,
        &pkmcal::identify::StudyOptions {
            calibration: opts.clone(),
            validation: pkmcal::identify::ValidationPlan::None,
            kfold: None,
            seed: 0,
        },
        &|| {},
    )
    .map_err(|e| {
        let e = anyhow::Error::from(e.error);
        let name = match data_pose(&e) {
            Some((i, false)) => &delta.probes[i].name,
            Some((i, true)) => &delta.distances[i].name,
            None => return e,
        };
        e.context(format!("`{name}` of {}", c.config.display()))
    })?;
    let cal = &study.calibration;
    let before = height_errors(
        &mech,
        &measurement,
        &nominal,
        measurement.nominal(),
        heights,
    )?;
    let after = height_errors(&mech, &measurement, &cal.params, &cal.measurement, heights)?;
    let new = delta.identified(spec, &cal.params)?;
    println!(
        "{} probe heights{} from {} (Klipper), {} parameters free: {}",
        heights.len(),
        if delta.distances.is_empty() {
            String::new()
        } else {
            format!(
                " and {} distances measured on the calibration object",
                delta.distances.len()
            )
        },
        c.config.display(),
        free_names.len(),
        free_names.join(" ")
    );
    println!("{}", cal.termination.reason());
    println!(
        "height errors: before max {:.4} mm, RMS {:.4} mm; after max {:.4} mm, RMS {:.4} mm",
        max_abs(&before),
        rms(&before),
        max_abs(&after),
        rms(&after)
    );
    if !delta.distances.is_empty()
        && let Some(d) = &study.accuracy.distances
    {
        let weighing = match c.weighting {
            Weighting::Estimated => format!(
                "noise σ: heights {}, distances {}, estimated apart",
                noise_of(cal, "probe"),
                noise_of(cal, pkmcal::DISTANCE_AXIS)
            ),
            Weighting::Klipper => "heights and distances weighed as Klipper weighs them".into(),
            Weighting::Shrunk(n) => format!(
                "noise σ: heights {}, distances {}, estimated and shrunk towards Klipper's ratio with {n} pseudo-readings",
                noise_of(cal, "probe"),
                noise_of(cal, pkmcal::DISTANCE_AXIS)
            ),
        };
        println!(
            "distance errors: before max {:.4} mm, RMS {:.4} mm; after max {:.4} mm, RMS {:.4} mm ({weighing})",
            d.before_max, d.before_rms, d.after_max, d.after_rms,
        );
        // How well the data fix the weighting: the variance ratio with its
        // interval, against Klipper's fixed ratio.
        let group = |axis: &str| cal.noise.iter().find(|g| g.axes.iter().any(|a| a == axis));
        if let (Some(h), Some(dg), Weighting::Shrunk(n)) =
            (group("probe"), group(pkmcal::DISTANCE_AXIS), c.weighting)
        {
            println!(
                "variance ratio heights/distances: {:.3}, from the data's {:.1} and {:.1} degrees of freedom and Klipper's fixed {:.3} worth {n} readings a group",
                (h.sigma / dg.sigma).powi(2),
                h.redundancy.unwrap_or(f64::NAN),
                dg.redundancy.unwrap_or(f64::NAN),
                1.0 / klipper_z_weight(&delta)
            );
        }
        if let (Some(h), Some(dg)) = (group("probe"), group(pkmcal::DISTANCE_AXIS))
            && let Some(r) = pkmcal::variance_ratio(h, dg, VARIANCE_RATIO_LEVEL)
        {
            println!(
                "variance ratio heights/distances: {:.3} ({:.0} % interval {:.3} to {:.3}, from {:.1} and {:.1} degrees of freedom); Klipper's fixed weighting takes {:.3}",
                r.ratio,
                100.0 * r.level,
                r.low,
                r.high,
                h.redundancy.unwrap_or(f64::NAN),
                dg.redundancy.unwrap_or(f64::NAN),
                1.0 / klipper_z_weight(&delta)
            );
        }
    }
    for w in &cal.warnings {
        println!(
            "warning: {}\n  hint: {}",
            w.message,
            crate::calibrate::cli_hint(w)
        );
    }
    println!(
        "\n  {:<28} {:>14} {:>14}",
        "Klipper value", "before", "after"
    );
    println!(
        "  {:<28} {:>14.6} {:>14.6}",
        "[printer] delta_radius", delta.radius, new.radius
    );
    for (i, t) in TOWERS.iter().enumerate() {
        for (key, a, b) in [
            ("angle", delta.angles[i], new.angles[i]),
            ("arm_length", delta.arms[i], new.arms[i]),
            ("position_endstop", delta.endstops[i], new.endstops[i]),
        ] {
            println!(
                "  {:<28} {a:>14.6} {b:>14.6}",
                format!("[stepper_{t}] {key}")
            );
        }
    }
    for (i, n) in measurement.param_names().iter().enumerate() {
        if opts.free.contains(&(spec.n_params() + i)) {
            println!(
                "  {:<28} {:>14.6} {:>14.6}   ({}; not a Klipper value: level the bed or let Klipper's bed mesh take it)",
                n,
                measurement.nominal()[i],
                cal.measurement[i],
                measurement.param_units()[i]
            );
        }
    }
    if let Some(out) = &c.out {
        run.files
            .stage(out, updated_config(&text, &new, &ini)?.as_bytes())?;
        println!(
            "\nupdated configuration -> {} (values in its SAVE_CONFIG block)",
            out.display()
        );
    }
    if let Some(dir) = &c.out_dir {
        run.files.create_dir(dir)?;
        let mut csv = String::from("# frame: base\na,b,c,probe\n");
        for m in heights {
            let _ = writeln!(
                csv,
                "{:?},{:?},{:?},{:?}",
                m.commands[0], m.commands[1], m.commands[2], m.measured[0]
            );
        }
        let [m_file, d_file, p_file] = OUT_DIR_FILES;
        run.files
            .stage(&dir.join(m_file), delta.mechanism_toml().as_bytes())?;
        run.files.stage(&dir.join(d_file), csv.as_bytes())?;
        if !delta.distances.is_empty() {
            let mut csv = String::from("a_1,b_1,c_1,a_2,b_2,c_2,distance\n");
            for m in &data[heights.len()..] {
                let b = m.partner.as_deref().unwrap_or_default();
                let _ = writeln!(
                    csv,
                    "{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
                    m.commands[0], m.commands[1], m.commands[2], b[0], b[1], b[2], m.measured[0]
                );
            }
            run.files.stage(&dir.join(DISTANCES_FILE), csv.as_bytes())?;
        }
        run.files.stage(
            &dir.join(p_file),
            crate::io::params_to_string(
                spec,
                &cal.params,
                &format!(
                    "pkmcal klipper: identified from the probe heights of {}",
                    c.config.display()
                ),
            )
            .as_bytes(),
        )?;
        let dist = if delta.distances.is_empty() {
            String::new()
        } else {
            format!(" --distances {}/{DISTANCES_FILE}", dir.display())
        };
        println!(
            "mechanism, probe data and parameters -> {} (e.g. `pkmcal calibrate --mechanism {0}/mechanism.toml --data {0}/probes.csv{dist}`)",
            dir.display()
        );
    }
    Ok(())
}

/// A `--free` list of a firmware command (`default` standing for the
/// firmware's own default set `default`; `all` for every parameter): the
/// names, and their indices in the identification vector of `measurement`.
pub fn free_list(
    free: Option<&str>,
    fix: Option<&str>,
    default: &[String],
    spec: &pkmcal::Spec,
    measurement: &MeasurementModel,
) -> Result<(Vec<String>, Vec<usize>)> {
    let set = crate::calibrate::free_set_with_default(spec, measurement, default, free, fix)?;
    // In the order given (the default set's where it stands), each once.
    let all = measurement.all_names(spec);
    let mut names: Vec<String> = vec![];
    for n in free.unwrap_or("default").split(',').map(str::trim) {
        match n {
            "default" => names.extend(default.iter().cloned()),
            "all" => names.extend(set.iter().map(|&i| all[i].clone())),
            "" => {}
            _ => names.push(n.to_string()),
        }
    }
    let mut seen = std::collections::BTreeSet::new();
    names.retain(|n| seen.insert(n.clone()));
    // Those `fix` removes (checked above) out.
    names.retain(|n| {
        measurement
            .index_of(spec, n)
            .is_ok_and(|i| set.contains(&i))
    });
    let indices = names
        .iter()
        .map(|n| measurement.index_of(spec, n))
        .collect::<pkmcal::Result<Vec<usize>>>()?;
    Ok((names, indices))
}

/// The files `--out-dir` holds.
pub const OUT_DIR_FILES: [&str; 3] = ["mechanism.toml", "probes.csv", "calibration.toml"];
/// And the distances, when the configuration saves any.
pub const DISTANCES_FILE: &str = "distances.csv";

/// The row an error is about, if any: its index (from 0) among the probe
/// heights or (`true`) the distances.
fn data_pose(e: &anyhow::Error) -> Option<(usize, bool)> {
    e.chain()
        .find_map(|c| match c.downcast_ref::<pkmcal::Error>() {
            Some(pkmcal::Error::Pose { pose, distance, .. }) => Some((pose - 1, *distance)),
            _ => None,
        })
}

/// Confidence level of the printed height/distance variance ratio.
const VARIANCE_RATIO_LEVEL: f64 = 0.95;

/// The weight of the heights in Klipper's extended calibration: its cost
/// `z_weight · Σ heights² + Σ distances²` with `z_weight = n_distances /
/// (0.5 · n_probed)`, which weighs them as variances `σ_height² /
/// σ_distance² = 1 / z_weight`.
fn klipper_z_weight(delta: &KlipperDelta) -> f64 {
    let probed = delta
        .probes
        .iter()
        .filter(|p| !p.name.starts_with("manual"))
        .count()
        .max(1);
    delta.distances.len() as f64 / (KLIPPER_MEASURE_WEIGHT * probed as f64)
}

/// The noise σ of a group of readings, for the summary.
fn noise_of(cal: &pkmcal::Calibration, axis: &str) -> String {
    cal.noise
        .iter()
        .find(|g| g.axes.iter().any(|a| a == axis))
        .map_or("—".into(), |g| format!("{:.1} µm", g.sigma * 1e3))
}
