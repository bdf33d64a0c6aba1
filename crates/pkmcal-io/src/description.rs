//! Mechanism descriptions (TOML): the mechanism of its `type`, and the
//! tables the other readers use (`[[target]]`, `[ballbar]`, `[units]`,
//! `[tolerances]`), each checked where the file is read so that a mistake
//! names it. The text is parsed once; each part is taken from the one
//! table. A ball-bar setup file has the `[ballbar]` table's keys.

use crate::error::{Error, Result, Within};
use crate::invalid;
use pkmcal::apply::budget::Tolerance;
use pkmcal::{AnyMechanism, JeongKim2Dof, Mechanism};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The mechanism the front ends work on.
pub type Mech = AnyMechanism;

/// The mechanism kinds a description file can give in `type`.
pub const MECHANISM_TYPES: &str = "jeong-kim-2dof, planar, gough-stewart, spatial";

/// A mechanism description, read and parsed once per command: the mechanism
/// and every table the other readers use.
pub struct Description {
    /// The file; `None` for the built-in reference mechanism.
    pub path: Option<PathBuf>,
    /// The mechanism.
    pub mech: Mech,
    /// The target points (`[[target]]`, tool frame, mm); empty without.
    pub targets: Vec<Vec<f64>>,
    /// The ball-bar setup of its `[ballbar]` table, if any.
    pub ballbar: Option<pkmcal::Setup>,
    /// The data-file units of its `[units]` table, if any.
    pub units: Option<pkmcal::PartialUnits>,
    /// Where it came from, as a complete calibration record keeps it.
    pub source: crate::record::MechanismSource,
    /// Its `[tolerances]` table: parameter name and tolerance, by name.
    pub tolerances: Vec<(String, Tolerance)>,
}

/// A description's parts from its text (what [`read_description`] reads).
pub struct DescriptionParts {
    /// The mechanism.
    pub mech: Mech,
    /// `[[target]]` points.
    pub targets: Vec<Vec<f64>>,
    /// `[ballbar]`.
    pub ballbar: Option<pkmcal::Setup>,
    /// `[units]`.
    pub units: Option<pkmcal::PartialUnits>,
    /// `[tolerances]`.
    pub tolerances: Vec<(String, Tolerance)>,
    /// Parameters its tables name by a name they had before.
    pub renamed: Vec<pkmcal::Renamed>,
}

impl Description {
    /// The built-in reference mechanism.
    pub fn reference() -> Self {
        Description {
            path: None,
            mech: JeongKim2Dof::new().into(),
            targets: vec![],
            ballbar: None,
            units: None,
            source: crate::record::MechanismSource::Reference,
            tolerances: vec![],
        }
    }
}

/// Every part of a mechanism description's text, each checked, from one
/// parse of the text.
pub fn description_from_str(text: &str) -> Result<DescriptionParts> {
    let mut table: toml::Table = match text.parse() {
        Ok(t) => t,
        Err(e) => invalid!("invalid mechanism description: {e}"),
    };
    let kind = match table.remove("type") {
        Some(toml::Value::String(s)) => s,
        Some(_) => invalid!("`type` must be a string ({MECHANISM_TYPES})"),
        None => invalid!("the description needs `type = \"…\"` ({MECHANISM_TYPES})"),
    };
    let ballbar = table.remove("ballbar");
    let target = table.remove("target");
    let units = table.remove("units");
    let tolerances = table.remove("tolerances");
    let mech = mechanism_of(&kind, table)?;
    let targets = targets_of(target)?;
    let ballbar = match ballbar {
        Some(v) => Some(setup_of(v).within(|| "in the [ballbar] table".to_string())?),
        None => None,
    };
    let units = units_of(units)?;
    let tolerances = tolerances_of(tolerances)?;
    // Every name is one of the mechanism's parameters, each σ positive.
    pkmcal::apply::budget::resolve_tolerances(mech.spec(), &tolerances)
        .within(|| "in the [tolerances] table".to_string())?;
    let renamed = mech
        .spec()
        .renamed_among(tolerances.iter().map(|(n, _)| n.as_str()));
    Ok(DescriptionParts {
        mech,
        targets,
        ballbar,
        units,
        tolerances,
        renamed,
    })
}

/// The mechanism of a description's text (its other tables checked too).
pub fn mechanism_from_str(text: &str) -> Result<Mech> {
    Ok(description_from_str(text)?.mech)
}

/// Read a mechanism file, every part of it, once; the built-in reference
/// when `path` is `None`.
pub fn read_description(run: &crate::Run<'_>, path: Option<&Path>) -> Result<Description> {
    let Some(path) = path else {
        return Ok(Description::reference());
    };
    let text = run
        .files
        .read_to_string(path, crate::output::InputKind::Description)
        .map_err(|e| e.named("mechanism file"))?;
    let p =
        description_from_str(&text).within(|| format!("in mechanism file {}", path.display()))?;
    if !p.renamed.is_empty() {
        run.note(crate::Note::Renamed {
            place: format!("the [tolerances] table of {}", path.display()),
            renamed: p.renamed.clone(),
        });
    }
    Ok(Description {
        path: Some(path.to_path_buf()),
        mech: p.mech,
        targets: p.targets,
        ballbar: p.ballbar,
        units: p.units,
        tolerances: p.tolerances,
        source: crate::record::MechanismSource::Description(text),
    })
}

/// The mechanism of `kind` from the description's table (without the
/// tables the other readers take); its nominal assembly must close.
fn mechanism_of(kind: &str, table: toml::Table) -> Result<Mech> {
    let mech: Mech = match kind {
        "jeong-kim-2dof" => jeong_kim_of(table)?.into(),
        "planar" => {
            let d: pkmcal::PlanarDescription = table.try_into().map_err(|e| {
                Error::Content(format!(
                    "invalid planar linkage description (docs/mechanisms.md shows the format): {e}"
                ))
            })?;
            pkmcal::PlanarLinkage::new(&d)?.into()
        }
        "gough-stewart" => {
            let d: pkmcal::GoughStewartDescription = table.try_into().map_err(|e| {
                Error::Content(format!(
                    "invalid Gough–Stewart description (docs/mechanisms.md shows the format): {e}"
                ))
            })?;
            pkmcal::GoughStewart::new(&d)?.into()
        }
        "spatial" => {
            let d: pkmcal::SpatialDescription = table.try_into().map_err(|e| {
                Error::Content(format!(
                    "invalid spatial mechanism description (docs/mechanisms.md shows the format): {e}"
                ))
            })?;
            pkmcal::SpatialMechanism::new(&d)?.into()
        }
        other => invalid!("unknown mechanism type `{other}`; supported: {MECHANISM_TYPES}"),
    };
    // The nominal assembly must close.
    pkmcal::reference_configuration(&mech, &mech.spec().nominal[..mech.spec().n_geometric()])?;
    Ok(mech)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ReferenceFile {
    name: Option<String>,
    #[serde(default)]
    nominal: BTreeMap<String, f64>,
    assembly: Option<Assembly>,
    #[serde(default)]
    workspace: BTreeMap<String, [f64; 2]>,
    free: Option<Vec<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Assembly {
    reference_q: Vec<f64>,
}

/// The paper's mechanism with the description's nominal values, assembly,
/// workspace and default free set.
fn jeong_kim_of(table: toml::Table) -> Result<JeongKim2Dof> {
    let file: ReferenceFile = table
        .try_into()
        .map_err(|e| Error::Content(format!("invalid mechanism description: {e}")))?;
    let mut spec = JeongKim2Dof::default_spec();
    if let Some(name) = file.name {
        spec.name = name;
    }
    for (name, value) in &file.nominal {
        let i = spec.param_index(name)?;
        spec.nominal[i] = *value;
    }
    for (i, name) in spec.geometric.iter().enumerate() {
        if name.starts_with('l') || name.starts_with('D') {
            let v = spec.nominal[i];
            if v.is_nan() || v <= 0.0 {
                invalid!("length `{name}` = {v} must be positive");
            }
        }
    }
    if let Some(a) = file.assembly {
        spec.reference_q = a.reference_q;
    }
    for (axis, range) in file.workspace {
        let Some(k) = spec.tool_axes.iter().position(|a| *a == axis) else {
            invalid!("[workspace]: unknown tool axis `{axis}` (axes: x, y)");
        };
        if range[0].is_nan() || range[1].is_nan() || range[0] >= range[1] {
            invalid!("[workspace]: `{axis}` must be [min, max] with min < max");
        }
        if range[1] - range[0] < pkmcal::kinds::description::MIN_BOX_WIDTH {
            invalid!(
                "[workspace]: `{axis}` = [{}, {}] is narrower than {:e} mm; give the range the tool moves over",
                range[0],
                range[1],
                pkmcal::kinds::description::MIN_BOX_WIDTH
            );
        }
        spec.workspace_box[k] = range;
    }
    if let Some(free) = file.free {
        spec.default_free = free;
    }
    Ok(JeongKim2Dof::with_spec(spec)?)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TargetEntry {
    at: Vec<f64>,
}

/// The target points of a description's `[[target]]` array.
fn targets_of(v: Option<toml::Value>) -> Result<Vec<Vec<f64>>> {
    let Some(v) = v else {
        return Ok(vec![]);
    };
    let targets: Vec<TargetEntry> = v.try_into().map_err(|e| {
        Error::Content(format!(
            "each [[target]] needs `at = [x, y, z]` (tool frame, mm; `[x, y]` on a planar tool): {e}"
        ))
    })?;
    for (k, t) in targets.iter().enumerate() {
        if !(matches!(t.at.len(), 2 | 3) && t.at.iter().all(|v| v.is_finite())) {
            invalid!(
                "[[target]] {}: `at = {:?}` must be 2 or 3 finite coordinates (tool frame, mm)",
                k + 1,
                t.at
            );
        }
    }
    Ok(targets.into_iter().map(|t| t.at).collect())
}

/// A measurement-setup file (or the `[ballbar]` table of a mechanism file).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SetupFile {
    /// Socket centres in the base frame, mm: `[[x, y], …]`.
    pub sockets: Vec<Vec<f64>>,
    /// Bar reading minus true distance, mm.
    #[serde(default)]
    pub bar_offset: f64,
}

/// A ball-bar setup from its table, checked.
fn setup_of(v: toml::Value) -> Result<pkmcal::Setup> {
    let f: SetupFile = v.try_into().map_err(|e| {
        Error::Content(format!(
            "expected `sockets = [[x, y], …]` and optional `bar_offset`: {e}"
        ))
    })?;
    let setup = pkmcal::Setup {
        sockets: f.sockets,
        bar_offset: f.bar_offset,
    };
    let dim = setup.sockets.first().map_or(2, Vec::len).clamp(2, 3);
    setup.validate(dim)?;
    Ok(setup)
}

/// The ball-bar setup: from the setup file `setup`, else from the
/// description's `[ballbar]` table; `None` when neither gives one.
pub fn read_setup(
    run: &crate::Run<'_>,
    setup: Option<&Path>,
    description: &Description,
) -> Result<Option<pkmcal::Setup>> {
    let Some(p) = setup else {
        return Ok(description.ballbar.clone());
    };
    let text = run
        .files
        .read_to_string(p, crate::output::InputKind::Description)
        .map_err(|e| e.named("setup file"))?;
    let table: toml::Value = match text.parse::<toml::Table>() {
        Ok(t) => toml::Value::Table(t),
        Err(e) => {
            return Err(Error::Content(format!(
                "expected `sockets = [[x, y], …]` and optional `bar_offset`: {e}"
            ))
            .context(format!("in setup file {}", p.display())));
        }
    };
    Ok(Some(
        setup_of(table).within(|| format!("in ball-bar setup {}", p.display()))?,
    ))
}

/// The `[units]` table, checked; `None` without.
fn units_of(v: Option<toml::Value>) -> Result<Option<pkmcal::PartialUnits>> {
    let Some(v) = v else {
        return Ok(None);
    };
    let u: pkmcal::PartialUnits = v.try_into().map_err(|e| {
        Error::Content(format!(
            "[units] takes angle = \"rad\" | \"deg\", length = \"mm\" | \"m\" | \"um\", counts_per_rev, counts_per_mm: {e}"
        ))
    })?;
    pkmcal::FileUnits::default().with(&u).validate()?;
    Ok(Some(u))
}

/// The `[tolerances]` table: `name = σ` (one standard deviation in the
/// parameter's unit) or `name = "20%"` (of its nominal value), by name;
/// empty without the table.
fn tolerances_of(v: Option<toml::Value>) -> Result<Vec<(String, Tolerance)>> {
    let Some(v) = v else {
        return Ok(vec![]);
    };
    let toml::Value::Table(t) = v else {
        invalid!("`tolerances` must be a table: [tolerances] then `name = σ` or `name = \"20%\"`");
    };
    t.iter()
        .map(|(name, v)| {
            let tol = match v {
                toml::Value::Float(f) => Tolerance::parse(&f.to_string()),
                toml::Value::Integer(i) => Tolerance::parse(&i.to_string()),
                toml::Value::String(s) => Tolerance::parse(s),
                other => invalid!(
                    "[tolerances] `{name}` = {other}: give σ in the parameter's unit (0.05) or a percentage of its nominal value (\"20%\")"
                ),
            }
            .within(|| format!("in the [tolerances] table, `{name}`"))?;
            Ok((name.clone(), tol))
        })
        .collect()
}

/// A mechanism's [`pkmcal::MechanismSummary`] as JSON (pretty, ending in a
/// newline): what a summary of the parameters prints and Python's
/// `Mechanism.summary` reads.
pub fn summary_json(spec: &pkmcal::Spec) -> String {
    serde_json::to_string_pretty(&pkmcal::summary(spec)).expect("plain data serialises") + "\n"
}
