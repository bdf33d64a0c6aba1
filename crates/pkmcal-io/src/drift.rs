//! `drift`: two saved calibrations of one machine compared (or one against
//! the nominal values), each change against what both covariances allow
//! ([`pkmcal::identify::drift`]).

use crate::io::{read_calibration_record_dof, read_description};
use anyhow::{Context, Result};
use pkmcal::Mechanism;
use pkmcal::identify::{Compared, Drift};
use std::path::PathBuf;

/// Arguments of `drift`, already parsed by clap.
pub struct DriftConfig {
    pub mechanism: Option<PathBuf>,
    /// The earlier calibration; `None`: the nominal values.
    pub old: Option<PathBuf>,
    /// The later calibration.
    pub new: PathBuf,
    pub alpha: f64,
    pub out: Option<PathBuf>,
    /// Workspace targets where the change at the tool is judged (0: none).
    pub grid: usize,
}

pub fn run_drift(run: &crate::Run<'_>, c: DriftConfig) -> Result<()> {
    let description = read_description(run, c.mechanism.as_deref())?;
    let spec = description.mech.spec();
    let read = |p: &PathBuf| -> Result<Compared> {
        let (r, dof) = read_calibration_record_dof(run, p)?;
        r.check(spec)
            .map_err(anyhow::Error::from)
            .with_context(|| format!("{}: it cannot be compared on {}", p.display(), spec.name))?;
        Ok(Compared::from_record(&r, dof))
    };
    let new = read(&c.new)?;
    let (old, old_name) = match &c.old {
        Some(p) => (read(p)?, p.display().to_string()),
        None => (Compared::nominal(spec), "the nominal values".to_string()),
    };
    if !(c.alpha > 0.0 && c.alpha < 1.0) {
        return crate::output::usage(format!(
            "--alpha {}: give a false-alarm rate between 0 and 1 (0.05 is usual)",
            c.alpha
        ));
    }
    let mut d = pkmcal::identify::drift(&old, &new, c.alpha)?;
    if c.grid > 0 {
        let mech = &description.mech;
        let targets = pkmcal::apply::budget::budget_targets(mech, c.grid)?;
        d.workspace = Some(pkmcal::apply::tooldrift::workspace_drift(
            mech, &old, &new, &targets, c.alpha,
        )?);
    }
    print!(
        "{}",
        drift_words(Some(spec), &d, &old_name, &c.new.display().to_string())
    );
    if let Some(o) = &c.out {
        run.files
            .stage(o, serde_json::to_string_pretty(&d)?.as_bytes())?;
        println!("drift -> {}", o.display());
    }
    Ok(())
}

/// The drift test in words: the rule, every tested parameter by
/// significance, the joint test.
pub fn drift_words(spec: Option<&pkmcal::Spec>, d: &Drift, old: &str, new: &str) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let drifted = d.parameters.iter().filter(|p| p.drifted).count();
    let _ = writeln!(
        o,
        "drift of {} from {old} to {new}: {} of {} parameters changed beyond what both covariances allow",
        spec.map_or("the mechanism", |s| s.name.as_str()),
        drifted,
        d.parameters.len()
    );
    let _ = writeln!(
        o,
        "  rule: z = change / √(σ_old² + σ_new²), two-sided p ({}); Holm–Bonferroni keeps the chance of any false alarm among the {} at {}",
        match d.noise_dof {
            Some(n) => format!(
                "Student's t with {n:.1} degrees of freedom, those of the estimated noise levels"
            ),
            None => "normal".into(),
        },
        d.parameters.len(),
        d.alpha
    );
    let width = d
        .parameters
        .iter()
        .map(|p| p.name.len())
        .fold(9, usize::max);
    let _ = writeln!(
        o,
        "\n  {:<width$} {:<7} {:>16} {:>16} {:>13} {:>11} {:>8} {:>10}  drift",
        "parameter", "unit", "old", "new", "change", "σ", "z", "p"
    );
    for p in &d.parameters {
        let unit = spec
            .and_then(|s| {
                s.param_index(&p.name)
                    .ok()
                    .map(|i| s.param_unit(i).symbol())
            })
            .unwrap_or("");
        let _ = writeln!(
            o,
            "  {:<width$} {:<7} {:>16.8} {:>16.8} {:>+13.4e} {:>11.3e} {:>8.2} {:>10.3e}  {}",
            p.name,
            unit,
            p.before,
            p.after,
            p.change,
            p.sigma,
            p.z,
            p.p_value,
            if p.drifted { "yes" } else { "no" },
        );
    }
    let _ = writeln!(
        o,
        "\n  joint test (correlations included): Δᵀ(C_old + C_new)⁺Δ = {:.2} over {} directions, p {:.3e} ({}): {}",
        d.chi2,
        d.dof,
        d.p_joint,
        if d.noise_dof.is_some() { "F" } else { "χ²" },
        if d.joint_drift {
            "the machine changed"
        } else {
            "no change beyond the noise"
        }
    );
    if !d.untested.is_empty() {
        let _ = writeln!(
            o,
            "  not compared (identified in one calibration only): {}",
            d.untested.join(" ")
        );
    }
    if let Some(w) = &d.workspace {
        let big = &w.targets[w.largest];
        let _ = writeln!(
            o,
            "  at the tool over {} workspace targets: the position moved up to {:.4} mm (target {}, p {:.3e}); beyond what both covariances allow at {} of them (each judged at {}; neighbouring targets share their parameters, so this is a map, the joint test is the verdict)",
            w.targets.len(),
            big.distance,
            big.target
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>()
                .join(","),
            big.p_value,
            w.beyond,
            w.alpha
        );
    }
    o
}
