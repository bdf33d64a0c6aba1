//! What the mechanism descriptions share: values given as numbers or named
//! parameters, parameter names checked as they are declared, actuator and
//! stiffness names, and the workspace box of a `[workspace]` table.

use crate::error::{Error, Result};
use crate::units::Unit;
use serde::Deserialize;
use std::collections::BTreeMap;

/// A number of the geometry: a value, or the name of a parameter whose value
/// is in [`PlanarDescription::parameters`].
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum Value {
    /// A value; the parameter gets a derived name.
    Number(f64),
    /// A named parameter.
    Name(String),
}

/// Collects parameter names and nominal values in order of first use.
pub(crate) struct Names<'a> {
    pub(crate) names: Vec<String>,
    pub(crate) values: Vec<f64>,
    pub(crate) units: Vec<Unit>,
    pub(crate) given: &'a BTreeMap<String, f64>,
}

impl<'a> Names<'a> {
    /// No parameter yet; `given` are the description's `[parameters]`.
    pub(crate) fn new(given: &'a BTreeMap<String, f64>) -> Self {
        Names {
            names: vec![],
            values: vec![],
            units: vec![],
            given,
        }
    }

    /// Every named parameter of `[parameters]` must be used (by `what`).
    pub(crate) fn check_used(&self, what: &str) -> Result<()> {
        for n in self.given.keys() {
            if !self.names.contains(n) {
                return bad(format!("[parameters]: `{n}` is not used by {what}"));
            }
        }
        Ok(())
    }

    pub(crate) fn add(&mut self, v: &Value, derived: String, unit: Unit) -> Result<usize> {
        let (name, value) = match v {
            Value::Number(x) => (derived, *x),
            Value::Name(n) => {
                let x = *self.given.get(n).ok_or_else(|| {
                    Error::InvalidMechanism(format!(
                        "parameter `{n}` has no value; add `{n} = …` to [parameters]"
                    ))
                })?;
                (n.clone(), x)
            }
        };
        if !value.is_finite() {
            return Err(Error::InvalidMechanism(format!(
                "parameter `{name}` = {value} must be a finite number"
            )));
        }
        if let Some(i) = self.names.iter().position(|n| *n == name) {
            if matches!(v, Value::Number(_)) {
                return Err(Error::InvalidMechanism(format!(
                    "the derived parameter name `{name}` is already used; rename that parameter"
                )));
            }
            if self.units[i] != unit {
                return Err(Error::InvalidMechanism(format!(
                    "parameter `{name}` is used as a length (mm) and as an angle (rad); give the two numbers different names"
                )));
            }
            return Ok(i);
        }
        self.names.push(name);
        self.values.push(value);
        self.units.push(unit);
        Ok(self.names.len() - 1)
    }
}

pub(crate) fn bad<T>(m: String) -> Result<T> {
    Err(Error::InvalidMechanism(m))
}

/// Stiffness parameter name of an actuated joint: `k` + the name without a
/// leading `q`.
pub fn stiffness_name(joint: &str) -> String {
    match joint.strip_prefix('q') {
        Some(rest) if !rest.is_empty() => format!("k{rest}"),
        _ => format!("k{joint}"),
    }
}

/// The narrowest interval of a workspace box (mm or rad): a box thinner
/// than this along an axis is a typing mistake, and lattices over it would
/// be all rows and no columns.
pub const MIN_BOX_WIDTH: f64 = 1e-6;

/// The workspace box of a described mechanism: one `[min, max]` per tool
/// axis from the description's `[workspace]` table, in axis order.
pub(crate) fn box_from_description(
    axes: &[String],
    given: &std::collections::BTreeMap<String, [f64; 2]>,
) -> Result<Vec<[f64; 2]>> {
    let bad = |m: String| Err(Error::InvalidMechanism(m));
    if let Some(k) = given.keys().find(|k| !axes.contains(k)) {
        return bad(format!(
            "[workspace]: unknown tool axis `{k}` (axes: {})",
            axes.join(", ")
        ));
    }
    let mut out = Vec::with_capacity(axes.len());
    for a in axes {
        let Some(r) = given.get(a) else {
            return bad(format!(
                "[workspace] needs `{a} = [min, max]` (one interval per tool axis: {})",
                axes.join(", ")
            ));
        };
        if !(r[0].is_finite() && r[1].is_finite() && r[0] < r[1]) {
            return bad(format!(
                "[workspace]: `{a}` must be [min, max] with min < max"
            ));
        }
        if r[1] - r[0] < MIN_BOX_WIDTH {
            return bad(format!(
                "[workspace]: `{a}` = [{}, {}] is narrower than {MIN_BOX_WIDTH:e} (mm or rad); give the range the tool moves over",
                r[0], r[1]
            ));
        }
        out.push(*r);
    }
    Ok(out)
}
