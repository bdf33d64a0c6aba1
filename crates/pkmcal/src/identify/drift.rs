//! Drift told from noise: two calibrations of one machine (or one against
//! its nominal values) compared parameter by parameter, each change against
//! what both covariances allow, with the multiple-comparison rule stated.
//!
//! For a parameter identified in both, the change `Δ = b − a` has, when the
//! machine did not change, the standard deviation `σ = √(σ_a² + σ_b²)` (two
//! calibrations from independent measurements). `z = Δ/σ` is then standard
//! normal, and its two-sided p-value `P(|Z| ≥ |z|)`. Many parameters tested
//! at once would raise false alarms: the Holm–Bonferroni rule keeps the
//! chance of any false alarm among them at `alpha` (familywise): sorted by
//! p-value, the k-th smallest (from 0) is a drift when it and every smaller
//! one are below `alpha / (m − k)`. The joint test takes the correlations
//! into account: `Δᵀ (C_a + C_b)⁺ Δ` is χ² with as many degrees of freedom
//! as the rank of `C_a + C_b`.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor, StudentsT};

/// The familywise false-alarm rate of a drift test unless told otherwise.
pub const DEFAULT_ALPHA: f64 = 0.05;

/// Relative eigenvalue below which `C_a + C_b` is taken as singular in the
/// joint test.
const RANK_TOL: f64 = 1e-12;

/// One calibration as the drift test reads it: each parameter's value, and
/// the covariance of the identified ones (names, matrix).
#[derive(Debug, Clone, PartialEq)]
pub struct Compared {
    /// Every parameter's value, by name.
    pub values: Vec<(String, f64)>,
    /// Names of the identified parameters (rows of `covariance`).
    pub names: Vec<String>,
    /// Their covariance.
    pub covariance: Vec<Vec<f64>>,
    /// Degrees of freedom of the noise level the covariance was scaled by
    /// (the calibration's redundancy); `None`: known exactly (nominal
    /// values, or not recorded).
    pub dof: Option<f64>,
}

/// One parameter's change.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParameterDrift {
    /// Its name.
    pub name: String,
    /// The first calibration's value.
    pub before: f64,
    /// The second's.
    pub after: f64,
    /// `after − before`.
    pub change: f64,
    /// What the two covariances allow: `√(σ_a² + σ_b²)`.
    pub sigma: f64,
    /// `change / sigma`.
    pub z: f64,
    /// Two-sided p-value of `z`.
    pub p_value: f64,
    /// Whether Holm–Bonferroni at the test's `alpha` calls it a drift.
    pub drifted: bool,
}

/// What the test found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Drift {
    /// The familywise false-alarm rate.
    pub alpha: f64,
    /// The parameters identified in both, smallest p-value first.
    pub parameters: Vec<ParameterDrift>,
    /// The joint statistic `Δᵀ (C_a + C_b)⁺ Δ`.
    pub chi2: f64,
    /// Its degrees of freedom (the rank of `C_a + C_b`).
    pub dof: usize,
    /// Its p-value.
    pub p_joint: f64,
    /// Degrees of freedom of the noise levels (the two redundancies added),
    /// when known: the tests are then Student's t and Fisher's F.
    pub noise_dof: Option<f64>,
    /// Whether the joint test calls the whole a drift (`p_joint < alpha`).
    pub joint_drift: bool,
    /// Parameters identified in only one of the two (not tested).
    pub untested: Vec<String>,
    /// The change at the tool over the workspace, when the mechanism was
    /// at hand ([`crate::apply::tooldrift::workspace_drift`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub workspace: Option<WorkspaceDrift>,
}

/// The change of the predicted tool pose at one workspace target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TargetDrift {
    /// The target (tool axes, mm and rad).
    pub target: Vec<f64>,
    /// The second calibration's predicted pose minus the first's, at the
    /// target's nominal commands.
    pub change: Vec<f64>,
    /// The length of the change's position part (mm).
    pub distance: f64,
    /// `changeᵀ C⁺ change`, `C` the change's covariance from both
    /// calibrations' (first order).
    pub statistic: f64,
    /// Its degrees of freedom (the rank of `C`).
    pub dof: usize,
    /// Its p-value (χ², or F with the noise levels' degrees of freedom).
    pub p_value: f64,
}

/// The change at the tool over the workspace: each target's predicted
/// change against what both covariances allow there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorkspaceDrift {
    /// Each target's change.
    pub targets: Vec<TargetDrift>,
    /// Index of the target where the position moved most.
    pub largest: usize,
    /// Targets whose change exceeds what the covariances allow at `alpha`
    /// (each judged alone: neighbouring targets share their parameters, so
    /// this is a map, not a familywise test; the joint parameter test is).
    pub beyond: usize,
    /// The rate each target is judged at.
    pub alpha: f64,
}

/// Two-sided p-value of `z`: standard normal, or Student's t with `dof`.
fn two_sided(z: f64, dof: Option<f64>) -> f64 {
    match dof.and_then(|n| StudentsT::new(0.0, 1.0, n).ok()) {
        Some(t) => 2.0 * (1.0 - t.cdf(z.abs())),
        None => statrs::function::erf::erfc(z.abs() / std::f64::consts::SQRT_2),
    }
}

/// Compare `a` with `b` (the later calibration, or nominal values with no
/// covariance) at familywise false-alarm rate `alpha`.
pub fn drift(a: &Compared, b: &Compared, alpha: f64) -> Result<Drift> {
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(Error::InvalidRequest(format!(
            "the false-alarm rate is {alpha}; give a number between 0 and 1 (0.05 is usual)"
        )));
    }
    let value = |c: &Compared, n: &str| c.values.iter().find(|(m, _)| m == n).map(|v| v.1);
    let var = |c: &Compared, n: &str| -> Option<f64> {
        let i = c.names.iter().position(|m| m == n)?;
        Some(c.covariance[i][i])
    };
    // Tested: identified in either with a value in both; a parameter only one
    // identified is tested when the other gives it without uncertainty
    // (nominal values), else it is listed untested.
    let mut tested: Vec<String> = vec![];
    let mut untested: Vec<String> = vec![];
    let either: Vec<&String> = a
        .names
        .iter()
        .chain(b.names.iter().filter(|n| !a.names.contains(n)))
        .collect();
    for n in either {
        let in_both = a.names.contains(n) && b.names.contains(n);
        let one_exact = (a.names.is_empty() || b.names.is_empty())
            && value(a, n).is_some()
            && value(b, n).is_some();
        if in_both || one_exact {
            tested.push(n.clone());
        } else {
            untested.push(n.clone());
        }
    }
    if tested.is_empty() {
        return Err(Error::InvalidRequest(
            "no parameter is identified in both calibrations; nothing to compare".into(),
        ));
    }
    let m = tested.len();
    let nu = joint_noise_dof(a, b);
    let cov = |c: &Compared, x: &str, y: &str| -> f64 {
        match (
            c.names.iter().position(|n| n == x),
            c.names.iter().position(|n| n == y),
        ) {
            (Some(i), Some(j)) => c.covariance[i][j],
            _ => 0.0,
        }
    };
    let mut parameters = vec![];
    for n in &tested {
        let (before, after) = (
            value(a, n).unwrap_or(f64::NAN),
            value(b, n).unwrap_or(f64::NAN),
        );
        let sigma = (var(a, n).unwrap_or(0.0) + var(b, n).unwrap_or(0.0)).sqrt();
        if !(before.is_finite() && after.is_finite() && sigma.is_finite()) {
            return Err(Error::InvalidRequest(format!(
                "`{n}` has no finite value or standard deviation in both calibrations; they cannot be compared"
            )));
        }
        let change = after - before;
        let z = if sigma > 0.0 {
            change / sigma
        } else {
            f64::INFINITY
        };
        parameters.push(ParameterDrift {
            name: n.clone(),
            before,
            after,
            change,
            sigma,
            z,
            p_value: if sigma > 0.0 { two_sided(z, nu) } else { 0.0 },
            drifted: false,
        });
    }
    parameters.sort_by(|x, y| x.p_value.total_cmp(&y.p_value));
    // Holm–Bonferroni, step down.
    for (k, p) in parameters.iter_mut().enumerate() {
        if p.p_value <= alpha / (m - k) as f64 {
            p.drifted = true;
        } else {
            break;
        }
    }
    // The joint test on the sum of the covariances (pseudo-inverse).
    let c = nalgebra::DMatrix::from_fn(m, m, |i, j| {
        cov(a, &tested[i], &tested[j]) + cov(b, &tested[i], &tested[j])
    });
    let d = nalgebra::DVector::from_iterator(
        m,
        tested
            .iter()
            .map(|n| value(b, n).unwrap_or(0.0) - value(a, n).unwrap_or(0.0)),
    );
    let (chi2, dof, p_joint) = quadratic_test(&c, &d, nu)?;
    Ok(Drift {
        alpha,
        parameters,
        chi2,
        dof,
        p_joint,
        noise_dof: nu,
        joint_drift: p_joint < alpha,
        untested,
        workspace: None,
    })
}

/// The degrees of freedom of the two calibrations' noise levels together.
pub fn joint_noise_dof(a: &Compared, b: &Compared) -> Option<f64> {
    match (a.dof, b.dof) {
        (Some(x), Some(y)) => Some(x + y),
        (x, y) => x.or(y),
    }
    .filter(|n| n.is_finite() && *n > 0.0)
}

/// The joint test of a change `d` with covariance `c`: `dᵀ c⁺ d` over the
/// eigenvalues above [`RANK_TOL`] of the largest, its degrees of freedom
/// (that rank) and its p-value (χ², or Fisher's F with `nu` when the noise
/// levels were estimated). The one rule of the parameter and workspace
/// tests.
pub(crate) fn quadratic_test(
    c: &nalgebra::DMatrix<f64>,
    d: &nalgebra::DVector<f64>,
    nu: Option<f64>,
) -> Result<(f64, usize, f64)> {
    let eig = c.clone().symmetric_eigen();
    let top = eig.eigenvalues.iter().fold(0.0f64, |x, v| x.max(*v));
    let mut chi2 = 0.0;
    let mut dof = 0;
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l > RANK_TOL * top && l > 0.0 {
            let proj = eig.eigenvectors.column(k).dot(d);
            chi2 += proj * proj / l;
            dof += 1;
        }
    }
    let p = match (dof, nu) {
        (0, _) => f64::NAN,
        (d, Some(n)) => {
            1.0 - FisherSnedecor::new(d as f64, n)
                .map_err(|e| Error::InvalidRequest(format!("F({d}, {n}): {e}")))?
                .cdf(chi2 / d as f64)
        }
        (d, None) => {
            1.0 - ChiSquared::new(d as f64)
                .map_err(|e| Error::InvalidRequest(format!("χ² with {d} degrees: {e}")))?
                .cdf(chi2)
        }
    };
    Ok((chi2, dof, p))
}

impl Compared {
    /// A calibration record's values and covariance (the mechanism's
    /// identified parameters), its noise level estimated with `dof` degrees
    /// of freedom if known.
    pub fn from_record(r: &super::record::CalibrationRecord, dof: Option<f64>) -> Self {
        Compared {
            values: r
                .parameters
                .iter()
                .map(|p| (p.name.clone(), p.identified))
                .collect(),
            names: r.covariance.names.clone(),
            covariance: r.covariance.matrix.clone(),
            dof,
        }
    }

    /// A calibration's values and covariance, with its redundancy as the
    /// noise level's degrees of freedom (when a noise level was estimated).
    pub fn from_calibration(c: &super::result::Calibration) -> Self {
        Compared {
            values: c
                .parameters
                .iter()
                .map(|p| (p.name.clone(), p.identified))
                .collect(),
            names: c.parameter_covariance.names.clone(),
            covariance: c.parameter_covariance.matrix.clone(),
            dof: noise_dof(&c.noise),
        }
    }

    /// The nominal values of `spec`, exact.
    pub fn nominal(spec: &crate::mechanism::Spec) -> Self {
        Compared {
            values: spec
                .param_names()
                .iter()
                .zip(&spec.nominal)
                .map(|(n, v)| (n.to_string(), *v))
                .collect(),
            names: vec![],
            covariance: vec![],
            dof: None,
        }
    }
}

/// The degrees of freedom of a calibration's estimated noise levels: the
/// redundancy of its estimated groups; `None` when every σ was given.
pub fn noise_dof(groups: &[super::noise::NoiseGroup]) -> Option<f64> {
    let r: f64 = groups
        .iter()
        .filter(|g| g.estimated)
        .filter_map(|g| g.redundancy)
        .sum();
    (r > 0.0).then_some(r)
}
