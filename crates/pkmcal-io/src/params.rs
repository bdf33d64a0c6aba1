//! Parameter files: flat TOML, `name = value` (mm, rad, N·mm/rad…), names
//! not given nominal; written back with every parameter, in vector order,
//! each with its unit.

use crate::error::{Result, Within};
use crate::invalid;
use pkmcal::{Mechanism, Params, Spec};
use std::path::Path;

/// Read a parameter file for `mech` and check the values
/// ([`pkmcal::check_params`]: finite, in range, lengths positive, the
/// mechanism still assembles), naming the file.
pub fn read_params<M: Mechanism>(run: &crate::Run<'_>, path: &Path, mech: &M) -> Result<Params> {
    let text = run
        .files
        .read_to_string(path, crate::output::InputKind::Description)
        .map_err(|e| e.named("parameter file"))?;
    let (p, renamed) = params_from_str_noting(&text, mech.spec())
        .within(|| format!("in parameter file {}", path.display()))?;
    if !renamed.is_empty() {
        run.note(crate::Note::Renamed {
            place: format!("parameter file {}", path.display()),
            renamed,
        });
    }
    pkmcal::check_params(mech, &p).within(|| {
        format!(
            "in parameter file {}: the values cannot describe this mechanism",
            path.display()
        )
    })?;
    Ok(p)
}

/// The parameter values of a parameter file's text: `name = value`, dotted
/// names as keys or tables (`P.y = 0`, `"P.y" = 0`), every name the
/// mechanism's (or one it had before: [`params_from_str_noting`] says
/// which).
pub fn params_from_str(text: &str, spec: &Spec) -> Result<Params> {
    params_from_str_noting(text, spec).map(|(p, _)| p)
}

/// [`params_from_str`], with the parameters named by an old name.
pub fn params_from_str_noting(text: &str, spec: &Spec) -> Result<(Params, Vec<pkmcal::Renamed>)> {
    let table: toml::Table = match toml::from_str(text) {
        Ok(t) => t,
        Err(e) => invalid!("TOML syntax error: {e}"),
    };
    // `P.y = 0` (a dotted key, i.e. a table) and `"P.y" = 0` both name `P.y`.
    fn flatten(prefix: &str, t: &toml::Table, out: &mut Vec<(String, f64)>) -> Result<()> {
        for (key, value) in t {
            let name = if prefix.is_empty() {
                key.clone()
            } else {
                format!("{prefix}.{key}")
            };
            match value {
                toml::Value::Float(f) => out.push((name, *f)),
                toml::Value::Integer(i) => out.push((name, *i as f64)),
                toml::Value::Table(inner) => flatten(&name, inner, out)?,
                other => invalid!(
                    "parameter `{name}` must be a number, found {}",
                    other.type_str()
                ),
            }
        }
        Ok(())
    }
    let mut named = Vec::new();
    flatten("", &table, &mut named)?;
    for (name, _) in &named {
        spec.param_index(name)?;
    }
    Ok(Params::from_named_noting(
        spec,
        named.iter().map(|(n, v)| (n.as_str(), *v)),
    )?)
}

/// Flat parameter file text with every parameter, in vector order.
pub fn params_to_string(spec: &Spec, params: &Params, header: &str) -> String {
    let mut out = String::new();
    for line in header.lines() {
        out.push_str(&format!("# {line}\n"));
    }
    for (i, (name, v)) in spec.param_names().iter().zip(&params.values).enumerate() {
        let bare = name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        let key = if bare {
            name.to_string()
        } else {
            format!("\"{name}\"")
        };
        out.push_str(&format!("{key} = {v:?}  # {}\n", spec.param_unit(i)));
    }
    out
}

/// The parameter values of a parameter file ([`read_params`]), or the
/// nominal ones without one.
pub fn params_or_nominal<M: Mechanism>(
    run: &crate::Run<'_>,
    path: Option<&Path>,
    mech: &M,
) -> Result<Params> {
    match path {
        Some(p) => read_params(run, p, mech),
        None => Ok(Params::nominal(mech.spec())),
    }
}
