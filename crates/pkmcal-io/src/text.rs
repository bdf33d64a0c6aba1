//! Reports as text: the summary of a calibration, accuracy tables, noise
//! groups, identifiability, a tolerance budget, a drift test. Pure
//! functions from results to text; where a text points at something only
//! a front end can name (an option, a keyword, where the full list is
//! kept), the front end passes its [`Wording`].

/// `writeln!` into a `String` (which cannot fail).
macro_rules! outln {
    ($o:expr) => {{
        $o.push('\n');
    }};
    ($o:expr, $($t:tt)*) => {{
        use std::fmt::Write as _;
        let _ = writeln!($o, $($t)*);
    }};
}

use crate::record::Report;
use pkmcal::apply::budget::Budget;
use pkmcal::identify::{Drift, Identifiability};
use pkmcal::{Calibration, ErrorStats, Frame, MeasurementModel};

/// Display factor and symbol of an error column: lengths in mm, angles in
/// mrad (so that micro-radian errors do not print as 0.0000).
pub fn column_unit(u: pkmcal::Unit) -> (f64, &'static str) {
    match u {
        pkmcal::Unit::Radian => (1e3, "mrad"),
        u => (1.0, u.symbol()),
    }
}

/// Width of the one-line table of [`write_stats`] for these axes: beyond
/// [`MAX_TABLE_WIDTH`] (a 6-DOF tool: 250 characters) each row's ranges per
/// axis go on lines of their own under it.
fn table_width(units: &[pkmcal::Unit]) -> usize {
    26 + 22 * units.len()
        + if units.contains(&pkmcal::Unit::Millimetre) {
            44
        } else {
            0
        }
        + if units.contains(&pkmcal::Unit::Radian) {
            22
        } else {
            0
        }
}

/// The widest accuracy table printed on one line per row.
const MAX_TABLE_WIDTH: usize = 140;

pub fn write_stats_header(out: &mut String, axes: &[String], units: &[pkmcal::Unit]) {
    let mut h = format!("  {:<24}", "errors");
    let stacked = table_width(units) > MAX_TABLE_WIDTH;
    for (a, u) in axes.iter().zip(units).filter(|_| !stacked) {
        let a = a.to_uppercase();
        let sym = column_unit(*u).1;
        h.push_str(&format!(
            " {:>10} {:>10}",
            format!("{a}min {sym}"),
            format!("{a}max {sym}")
        ));
    }
    let lengths = units.contains(&pkmcal::Unit::Millimetre);
    if lengths {
        for t in ["dmin", "dmean", "drms", "dmax"] {
            h.push_str(&format!(" {:>10}", format!("{t} mm")));
        }
    }
    if units.contains(&pkmcal::Unit::Radian) {
        for t in ["arms", "amax"] {
            h.push_str(&format!(" {:>10}", format!("{t} mrad")));
        }
    }
    if stacked {
        h.push_str("   (range of each axis below each row)");
    }
    outln!(out, "{h}");
}

pub fn write_stats(out: &mut String, label: &str, s: &ErrorStats) {
    write_stats_of(out, label, s, None);
}

/// [`write_stats`] with the axes' names (for the ranges printed under a
/// row of a wide table); `None` names them X, Y, … by position.
pub fn write_stats_of(out: &mut String, label: &str, s: &ErrorStats, axes: Option<&[String]>) {
    let stacked = table_width(&s.axis_units) > MAX_TABLE_WIDTH;
    let mut row = format!("  {label:<24}");
    if !stacked {
        for ((a, b), u) in s.axis_min.iter().zip(&s.axis_max).zip(&s.axis_units) {
            let f = column_unit(*u).0;
            row.push_str(&format!(" {:>10.4} {:>10.4}", a * f, b * f));
        }
    }
    if s.axis_units.contains(&pkmcal::Unit::Millimetre) {
        for v in [
            s.distance_min,
            s.distance_mean,
            s.distance_rms,
            s.distance_max,
        ] {
            row.push_str(&format!(" {v:>10.4}"));
        }
    }
    if let (Some(r), Some(m)) = (s.angle_rms, s.angle_max) {
        row.push_str(&format!(" {:>10.4} {:>10.4}", r * 1e3, m * 1e3));
    }
    outln!(out, "{row}");
    if stacked {
        // One line per unit: the lengths, then the angles.
        for unit in [pkmcal::Unit::Millimetre, pkmcal::Unit::Radian] {
            let (f, sym) = column_unit(unit);
            let parts: Vec<String> = (0..s.axis_units.len())
                .filter(|&k| s.axis_units[k] == unit)
                .map(|k| {
                    let name = axes
                        .and_then(|a| a.get(k))
                        .map_or_else(|| format!("axis {}", k + 1), |a| a.to_uppercase());
                    format!("{name} {:.4} … {:.4}", s.axis_min[k] * f, s.axis_max[k] * f)
                })
                .collect();
            // At most three axes a line (a tracker's three target points
            // give nine length axes).
            let lines = parts.len().div_ceil(3);
            for (k, chunk) in parts.chunks(3).enumerate() {
                let end = if k + 1 == lines {
                    format!(" {sym}")
                } else {
                    String::new()
                };
                outln!(out, "    {}{end}", chunk.join("   "));
            }
        }
    }
}

/// Values with their units, each in a readable scale (µm, µrad…).
pub fn with_units(values: &[f64], units: &[pkmcal::Unit]) -> String {
    values
        .iter()
        .zip(units)
        .map(|(v, u)| {
            let (f, sym) = u.readable(*v);
            format!("{:.3} {sym}", v * f)
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The instrument frame in words, when the data were measured from one.
pub fn frame_text(
    cal: &Calibration,
    measurement: &MeasurementModel,
    wording: &Wording,
) -> Option<String> {
    cal.frame.as_ref()?;
    let names = &measurement.param_names()[measurement.frame_range()];
    let rows: Vec<String> = cal
        .parameters
        .iter()
        .filter(|p| p.kind == pkmcal::ParamKind::Instrument && names.contains(&p.name))
        .map(|p| {
            let (f, sym) = match p.unit {
                pkmcal::Unit::Radian => (1e3, "mrad"),
                u => (1.0, u.symbol()),
            };
            if p.free {
                format!(
                    "{} {:.4} ± {:.2e} {sym}",
                    p.name,
                    p.identified * f,
                    p.std_dev * f
                )
            } else {
                format!("{} {:.4} {sym} (fixed)", p.name, p.identified * f)
            }
        })
        .collect();
    Some(format!(
        "instrument frame in the base frame ({}): {}",
        if *measurement.frame() == Frame::Free {
            wording.frame_base
        } else {
            "given"
        },
        rows.join(", ")
    ))
}

/// A noise group in words: its σ (estimated or given) and residual RMS.
pub fn noise_text(g: &pkmcal::NoiseGroup) -> String {
    let (f, sym) = g.unit.readable(g.sigma);
    format!(
        "noise of {} ({}, {} coordinates): σ {:.3} {sym} {}; residual RMS {:.3} {sym}",
        g.unit.group_name(),
        g.axes.join(", "),
        g.count,
        g.sigma * f,
        match (g.estimated, g.stated, g.stated_readings) {
            (true, Some(s0), Some(nu)) if g.stated_relative => format!(
                "estimated from the residuals and its stated share {:.3} {sym} of their common scale (worth {nu} readings)",
                s0 * f
            ),
            (true, Some(s0), Some(nu)) => format!(
                "estimated from the residuals and the stated {:.3} {sym} (worth {nu} readings)",
                s0 * f
            ),
            (true, ..) => "estimated from the residuals".to_string(),
            _ => "given in the data".to_string(),
        },
        g.residual_rms * f
    )
}

/// How the uncertainties are scaled, in words: the one rule of
/// docs/model.md §6.
pub fn scale_text(scale: &pkmcal::identify::Scale) -> String {
    match scale {
        pkmcal::identify::Scale::Known => {
            "uncertainties: absolute (every σ known); 95 % intervals ±1.96 σ".into()
        }
        pkmcal::identify::Scale::Estimated { dof } if *dof > 0.0 => format!(
            "uncertainties: scaled by the σ estimated from the readings ({dof:.1} degrees of freedom); 95 % intervals ±{:.3} σ (Student's t)",
            scale.quantile(0.95)
        ),
        pkmcal::identify::Scale::Estimated { .. } => {
            "uncertainties: none (no reading is left over to estimate σ from)".into()
        }
    }
}

/// One line per noise group.
pub fn write_noise(out: &mut String, groups: &[pkmcal::NoiseGroup]) {
    for g in groups {
        outln!(out, "  {}", noise_text(g));
    }
}

/// The condition number in words: with unidentifiable directions, that of
/// the identifiable ones (the full one is infinite).
pub fn condition_text(id: &Identifiability) -> String {
    let n = id.singular_values.len();
    if id.rank == 0 || id.rank >= n {
        return format!("condition number {:.3e}", id.condition_number);
    }
    let c = id.singular_values[0] / id.singular_values[id.rank - 1];
    format!(
        "condition number {c:.3e} over the {} ({} unidentifiable)",
        pkmcal::error::count(id.rank, "identifiable direction", "identifiable directions"),
        n - id.rank
    )
}

/// The identifiability summary; `fixed` says what happened to the parameter
/// named for each unidentifiable direction ("fixed", "calibrate fixes").
pub fn write_identifiability(out: &mut String, id: &Identifiability, fixed: &str, all_in: &str) {
    outln!(
        out,
        "identifiability: rank {} of {} free, {}",
        id.rank,
        id.singular_values.len(),
        condition_text(id)
    );
    let o = &id.observability;
    outln!(
        out,
        "  observability O1 {:.4e}  O2 {:.4e}  O3 {:.4e}  O4 {:.4e}  O5 {:.4e}",
        o.o1,
        o.o2,
        o.o3,
        o.o4,
        o.o5
    );
    for u in &id.unidentifiable {
        match &u.fixed {
            Some(f) => outln!(out, "  unidentifiable: {}  -> {fixed} {f}", u.combination),
            None => outln!(out, "  unidentifiable: {}", u.combination),
        }
    }
    write_correlations(out, &id.correlations, "correlated", all_in);
}

/// Pairs of correlated parameters printed before the rest are only counted
/// (a hexapod with every joint centre free has over a hundred).
const PRINTED_CORRELATIONS: usize = 10;

/// The strongest correlations (largest |r| first), at most
/// [`PRINTED_CORRELATIONS`], and how many more the reports hold.
fn write_correlations(
    out: &mut String,
    all: &[pkmcal::identify::Correlation],
    label: &str,
    all_in: &str,
) {
    let mut sorted: Vec<&pkmcal::identify::Correlation> = all.iter().collect();
    sorted.sort_by(|a, b| b.r.abs().total_cmp(&a.r.abs()));
    for c in sorted.iter().take(PRINTED_CORRELATIONS) {
        outln!(out, "  {label}: {} and {} (r = {:+.3})", c.a, c.b, c.r);
    }
    if sorted.len() > PRINTED_CORRELATIONS {
        outln!(
            out,
            "  {label}: {} more pairs with |r| > {} (all of them in {all_in})",
            sorted.len() - PRINTED_CORRELATIONS,
            pkmcal::identify::CORRELATION_REPORT
        );
    }
}

/// The summary of a calibration as text, in `wording`'s words.
pub fn write_summary(
    out: &mut String,
    r: &Report,
    measurement: &MeasurementModel,
    wording: &Wording,
) {
    let (axes, units) = (measurement.axes(), measurement.units());
    let cal = r.calibration;
    outln!(
        out,
        "calibration of {} from {} ({} poses{}, {} model)",
        r.mechanism,
        r.data,
        cal.poses,
        if cal.distances > 0 {
            format!(" and {} distances between poses", cal.distances)
        } else {
            String::new()
        },
        cal.model.name()
    );
    outln!(
        out,
        "{} after {} iterations ({} evaluations){}",
        cal.termination_reason,
        cal.iterations,
        cal.evaluations,
        // Against σ known, how far the residuals are from it; with σ
        // estimated it is 1 by construction and says nothing.
        match cal.scale {
            pkmcal::identify::Scale::Known => {
                format!("; σ of unit weight {:.3}", cal.unit_weight_sigma)
            }
            pkmcal::identify::Scale::Estimated { .. } => String::new(),
        }
    );
    write_noise(out, &cal.noise);
    outln!(out, "  {}", scale_text(&cal.scale));
    outln!(out);
    let width = cal
        .parameters
        .iter()
        .filter(|p| p.free || p.note.is_some())
        .map(|p| p.name.chars().count())
        .fold(6, usize::max);
    // With priors: each one's tolerance and the share of the information
    // that came from the data.
    let priors = !cal.priors.is_empty();
    outln!(
        out,
        "  {:<width$} {:>14} {:>16} {:>14} {:>12} {:<8}{}",
        "param",
        "nominal",
        "identified",
        "change",
        "±σ",
        "unit",
        if priors {
            format!(" {:>10} {:>9}", "tolerance", "from data")
        } else {
            String::new()
        }
    );
    for p in &cal.parameters {
        if p.free || p.note.is_some() {
            let prior = match (priors, p.tolerance) {
                (false, _) => String::new(),
                (true, None) => format!(" {:>10} {:>9}", "", ""),
                (true, Some(t)) => format!(
                    " {:>10.3e} {:>9}",
                    t,
                    p.from_data
                        .map_or_else(String::new, |f| format!("{:.0} %", 100.0 * f))
                ),
            };
            outln!(
                out,
                "  {:<width$} {:>14.6} {:>16.8} {:>+14.6e} {:>12.3e} {:<8}{}{}",
                p.name,
                p.nominal,
                p.identified,
                p.change,
                p.std_dev,
                p.unit,
                prior,
                p.note
                    .as_deref()
                    .map(|n| format!(" ({n})"))
                    .unwrap_or_default()
            );
        }
    }
    let fixed: Vec<&str> = cal
        .parameters
        .iter()
        .filter(|p| !p.free && p.note.is_none())
        .map(|p| p.name.as_str())
        .collect();
    outln!(out, "  fixed: {}", fixed.join(" "));
    if let Some(text) = frame_text(cal, measurement, wording) {
        outln!(out, "  {text}");
    }
    outln!(out);
    write_identifiability(out, &cal.identifiability, "fixed", wording.all_correlations);
    write_correlations(
        out,
        &cal.correlations,
        "correlated at the solution",
        wording.all_correlations,
    );
    outln!(out);
    write_stats_header(out, axes, units);
    write_stats_of(out, "calibration, before", &r.accuracy.before, Some(axes));
    write_stats_of(out, "calibration, after", &r.accuracy.after, Some(axes));
    outln!(
        out,
        "  improvement: max {:.1} %, RMS {:.1} %",
        r.accuracy.improvement_max_percent,
        r.accuracy.improvement_rms_percent
    );
    if let Some(d) = &r.accuracy.distances {
        write_distances(out, d);
    }
    if let Some(v) = &r.validation {
        outln!(out, "  validation: {}", v.source);
        write_stats_of(out, "validation, before", &v.accuracy.before, Some(axes));
        write_stats_of(out, "validation, after", &v.accuracy.after, Some(axes));
        outln!(
            out,
            "  improvement: max {:.1} %, RMS {:.1} %",
            v.accuracy.improvement_max_percent,
            v.accuracy.improvement_rms_percent
        );
    }
    if let Some(cv) = &r.cross_validation {
        outln!(
            out,
            "  {}-fold cross-validation: held-out RMS per fold {}",
            cv.folds,
            cv.fold_rms
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        write_stats_of(out, "cross-validation pooled", &cv.pooled, Some(axes));
    }
    if cal.loss != pkmcal::Loss::Squared {
        outln!(out, "  loss {:?}", cal.loss);
    }
    for o in &cal.outliers {
        outln!(
            out,
            "  outlier: {} residual {} ({:.1} robust σ){}",
            o.origin,
            with_units(&o.residual, &o.units),
            o.standardized,
            if cal.dropped.contains(&o.origin) {
                ", dropped"
            } else {
                ""
            }
        );
    }
    for w in &cal.warnings {
        outln!(out, "warning: {}\n  hint: {}", w.message, (wording.hint)(w));
    }
}

/// Errors of the distances between poses, before and after.
pub fn write_distances(out: &mut String, d: &pkmcal::DistanceAccuracy) {
    outln!(
        out,
        "  {} distances between poses: error max {:.4} mm, RMS {:.4} mm before; max {:.4} mm, RMS {:.4} mm after",
        d.count,
        d.before_max,
        d.before_rms,
        d.after_max,
        d.after_rms
    );
}

/// How a front end words a summary: where it keeps what the text leaves
/// out, and its hints.
pub struct Wording {
    /// After an identified instrument frame: how to say the data are in the
    /// base frame.
    pub frame_base: &'static str,
    /// Where every correlated pair is listed.
    pub all_correlations: &'static str,
    /// A warning's hint.
    pub hint: fn(&pkmcal::identify::Warning) -> String,
    /// How an input is named where advice says to give it (an option, a
    /// keyword).
    pub input: fn(pkmcal::Field) -> String,
}

/// A value in a readable unit (µm, mrad…), to four significant digits.
fn readable(v: f64, unit: pkmcal::Unit) -> String {
    let (f, sym) = unit.readable(v);
    let x = v * f;
    let digits = if x == 0.0 || !x.is_finite() {
        0
    } else {
        (3 - x.abs().log10().floor() as i32).clamp(0, 6) as usize
    };
    format!("{x:.digits$} {sym}")
}

/// The budget in words: the error over the workspace, the tolerances by
/// share, and what the planned calibration (`plan`, its poses' source)
/// would leave.
pub fn budget_words(mechanism: &str, b: &Budget, plan: Option<String>) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let mm = pkmcal::Unit::Millimetre;
    let _ = writeln!(
        o,
        "tolerance budget of {mechanism} over {} workspace targets",
        b.targets
    );
    let axes = |s: &pkmcal::apply::budget::ErrorSpread| {
        b.axes
            .iter()
            .zip(&b.units)
            .zip(&s.axis_rms)
            .map(|((a, u), v)| format!("{a} {}", readable(*v, *u)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let _ = writeln!(
        o,
        "  first order: position error RMS {}, worst target {}; per axis {}",
        readable(b.first_order.position_rms, mm),
        readable(b.first_order.position_worst, mm),
        axes(&b.first_order)
    );
    if let Some(mc) = &b.monte_carlo {
        let _ = writeln!(
            o,
            "  {} machines drawn from the tolerances (exact model): position error RMS {} ({}); per axis {}",
            b.samples,
            readable(mc.position_rms, mm),
            match b.sampled_change() {
                Some(c) => format!("{:+.1} % from first order", 100.0 * c),
                None if mc.position_rms > pkmcal::apply::budget::NEGLIGIBLE_ERROR_MM => {
                    "first order has none: the tolerances act beyond it".into()
                }
                None => "none, as to first order".into(),
            },
            axes(mc)
        );
    }
    let width = b
        .tolerances
        .iter()
        .map(|t| t.name.len())
        .fold(9, usize::max);
    let _ = writeln!(
        o,
        "\n  {:<width$} {:>18} {:>8}{}",
        "parameter",
        "tolerance σ",
        "share",
        if plan.is_some() {
            format!(" {:>16}", "σ after")
        } else {
            String::new()
        }
    );
    for t in &b.tolerances {
        let _ = writeln!(
            o,
            "  {:<width$} {:>18} {:>7.1}%{}",
            t.name,
            readable(t.sigma, t.unit),
            100.0 * t.share,
            t.sigma_after
                .map(|s| format!(" {:>16}", readable(s, t.unit)))
                .unwrap_or_default()
        );
    }
    let _ = writeln!(
        o,
        "  (share: of the position error variance over the workspace; stiffness tolerances have none to first order at nominal, where the actuators do not fight)"
    );
    if let (Some(a), Some(p)) = (&b.after_calibration, plan) {
        let _ = writeln!(
            o,
            "\nafter a calibration measuring the tool at the poses of {p}: position error RMS {}, worst target {}; per axis {}",
            readable(a.position_rms, mm),
            readable(a.position_worst, mm),
            axes(a)
        );
    }
    o
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
    if d.data_only {
        let _ = writeln!(
            o,
            "  compared: what the data added to the tolerances (each calibration's data-only estimate), so that the prior they share does not hide a change; directions the data alone do not see are not compared"
        );
    }
    if !d.untested.is_empty() {
        let _ = writeln!(
            o,
            "  not compared (identified in one calibration only{}): {}",
            if d.data_only {
                ", or seen by the tolerances alone"
            } else {
                ""
            },
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
