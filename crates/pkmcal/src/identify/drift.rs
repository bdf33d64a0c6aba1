//! Drift told from noise: two calibrations of one machine (or one against
//! its nominal values) compared parameter by parameter, each change against
//! what both covariances allow, with the multiple-comparison rule stated
//! (docs/model.md §6, "Drift").
//!
//! What is compared is what the data tell. Two calibrations with the same
//! priors share them: a direction the data see weakly is held near the
//! prior's centre in both, and a real change there is shrunk by the prior
//! in each. So with priors, each calibration's data-only estimate is
//! compared, `p̃ = p̂ + A⁺ P (p̂ − μ)` with covariance `A⁺`, where
//! `A = C⁻¹ − P` is the information the data added to the priors' `P`
//! (without priors, `p̃ = p̂` and `A⁺ = C`). Directions the data alone do
//! not see (`A`'s null space in either calibration, such as a stiffness
//! where the actuators do not fight) are not compared; a parameter that
//! lies in one is listed untested.
//!
//! Every quantity is taken in a scaled basis, each parameter divided by its
//! combined standard deviation `√(σ_a² + σ_b²)`, so that no unit swamps
//! another when a rank is decided (a stiffness's 10⁸ (N/mm)² beside mm²).
//!
//! For a parameter, the change `Δ = p̃_b − p̃_a` has, when the machine did
//! not change, the standard deviation `σ = √(V_a + V_b)` (two calibrations
//! from independent measurements). `z = Δ/σ` is then standard normal (or
//! Student's t with the noise levels' degrees of freedom), and its
//! two-sided p-value `P(|Z| ≥ |z|)`. Many parameters tested at once would
//! raise false alarms: the Holm–Bonferroni rule keeps the chance of any
//! false alarm among them at `alpha` (familywise): sorted by p-value, the
//! k-th smallest (from 0) is a drift when it and every smaller one are
//! below `alpha / (m − k)`. The joint test, the verdict, takes the
//! correlations into account: `Δᵀ (V_a + V_b)⁺ Δ` is χ² (Fisher's F with
//! the noise levels' degrees of freedom) with as many degrees of freedom as
//! the rank of `V_a + V_b` in correlation form.

use crate::error::{Error, Result};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};

/// The familywise false-alarm rate of a drift test unless told otherwise.
pub const DEFAULT_ALPHA: f64 = 0.05;

/// Relative eigenvalue below which a covariance in correlation form is
/// taken as singular in the joint test.
const RANK_TOL: f64 = 1e-12;

/// A direction whose data-only information (scaled) is below this fraction
/// of the largest posterior information is one the data alone do not see.
const SEEN_TOL: f64 = 1e-9;

/// A direction is unseen when the mean of the two calibrations' projectors
/// onto what their data do not see gives it more than this (½: unseen by
/// one of them; near 1: by both).
const UNSEEN_MERGE: f64 = 0.25;

/// A parameter whose unit vector has more than this squared share in a
/// direction the data do not see is not tested alone.
const UNSEEN_SHARE: f64 = 1e-6;

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
    /// The priors the calibration was fitted with: what the data added to
    /// them is compared. Empty: the calibration as it is.
    pub priors: Vec<super::prior::PriorTerm>,
    /// Names among `names` that are not compared but integrated out: the
    /// instrument's parameters (its frame, a bed's plane), which may differ
    /// between two sessions without the machine changing. Their priors are
    /// removed with the others' before they are integrated out, so that
    /// what the instrument's tolerances hold in both is not counted twice.
    /// Empty: every name is compared (a record keeps only the mechanism's
    /// marginal covariance).
    pub nuisance: Vec<String>,
}

/// One parameter's change.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParameterDrift {
    /// Its name.
    pub name: String,
    /// The first calibration's value compared: what its data alone give
    /// where it had priors ([`Drift::data_only`]), else its value.
    pub before: f64,
    /// The second's.
    pub after: f64,
    /// `after − before`.
    pub change: f64,
    /// What the two covariances allow: `√(σ_a² + σ_b²)` (of the data-only
    /// estimates, with priors).
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
    /// Parameters identified in only one of the two, or that the data
    /// alone do not see (held by their tolerances): not tested alone.
    pub untested: Vec<String>,
    /// Whether what the data added to the priors was compared (either
    /// calibration had priors): `before`, `after` and the covariances are
    /// the data-only estimates'.
    #[serde(default)]
    pub data_only: bool,
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
    match dof {
        Some(n) => super::uncertainty::Scale::Estimated { dof: n }.two_sided(z),
        None => super::uncertainty::Scale::Known.two_sided(z),
    }
}

/// One calibration's data-only estimate and covariance over the tested
/// parameters, in the scaled basis `d` (each parameter over `d_i`): the
/// values, the covariance, and an orthonormal basis of the directions the
/// data alone do not see (columns; none without priors). The first `m`
/// entries are the tested parameters, the rest the calibration's nuisance
/// ([`Compared::nuisance`]): every prior is removed over all of them, then
/// the nuisance is integrated out of the data's information (its Schur
/// complement).
fn data_only(
    values: &DVector<f64>,
    cov: &DMatrix<f64>,
    prior: &[Option<(f64, f64)>],
    d: &[f64],
    m: usize,
) -> (DVector<f64>, DMatrix<f64>, DMatrix<f64>) {
    let n = values.len();
    let p_s = DVector::from_fn(n, |i, _| values[i] / d[i]);
    let c_s = DMatrix::from_fn(n, n, |i, j| cov[(i, j)] / (d[i] * d[j]));
    let held: Vec<(usize, f64, f64)> = prior
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.map(|(mu, s)| (i, mu, s)))
        .filter(|&(i, _, _)| cov[(i, i)] > 0.0)
        .collect();
    if held.is_empty() {
        return (
            p_s.rows(0, m).into_owned(),
            c_s.view((0, 0), (m, m)).into_owned(),
            DMatrix::zeros(m, 0),
        );
    }
    // The posterior information, and what the data added to the priors'.
    let eig = c_s.clone().symmetric_eigen();
    let top = eig.eigenvalues.iter().fold(0.0f64, |x, v| x.max(*v));
    let mut info = DMatrix::zeros(n, n);
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l > RANK_TOL * top {
            let v = eig.eigenvectors.column(k);
            info += v * v.transpose() / l;
        }
    }
    let largest = info.diagonal().max();
    let mut pull = DVector::zeros(n);
    for &(i, mu, s) in &held {
        let w = (d[i] / s).powi(2);
        info[(i, i)] -= w;
        pull[i] = w * (values[i] - mu) / d[i];
    }
    let seen_inverse = |a: DMatrix<f64>| {
        let k = a.nrows();
        let e = a.symmetric_eigen();
        let mut inverse = DMatrix::zeros(k, k);
        let mut unseen: Vec<DVector<f64>> = vec![];
        for (j, &l) in e.eigenvalues.iter().enumerate() {
            let v = e.eigenvectors.column(j).into_owned();
            if l > SEEN_TOL * largest {
                inverse += &v * v.transpose() / l;
            } else {
                unseen.push(v);
            }
        }
        (inverse, unseen)
    };
    let (estimate, inverse, unseen) = if n == m {
        let (inverse, unseen) = seen_inverse(info);
        (&p_s + &inverse * pull, inverse, unseen)
    } else {
        // The data's estimate of everything, then the tested parameters'
        // information with the nuisance integrated out.
        let (all, _) = seen_inverse(info.clone());
        let estimate = (&p_s + &all * pull).rows(0, m).into_owned();
        let (nuisance, _) = seen_inverse(info.view((m, m), (n - m, n - m)).into_owned());
        let cross = info.view((0, m), (m, n - m));
        let schur = info.view((0, 0), (m, m)) - cross * nuisance * cross.transpose();
        let (inverse, unseen) = seen_inverse(schur);
        (estimate, inverse, unseen)
    };
    let basis = if unseen.is_empty() {
        DMatrix::zeros(m, 0)
    } else {
        DMatrix::from_columns(&unseen)
    };
    (estimate, inverse, basis)
}

/// Two calibrations as the drift test compares them: the parameters
/// tested, their scale (combined σ), each calibration's data-only values
/// and covariance in that scale, an orthonormal basis of what either's data
/// do not see, and the parameters not tested.
pub(crate) struct Prepared {
    pub(crate) tested: Vec<String>,
    pub(crate) scale: Vec<f64>,
    pub(crate) a: (DVector<f64>, DMatrix<f64>),
    pub(crate) b: (DVector<f64>, DMatrix<f64>),
    pub(crate) unseen: DMatrix<f64>,
    /// An orthonormal basis of what `unseen` leaves (columns; empty when
    /// nothing is unseen: then all of it).
    pub(crate) seen: DMatrix<f64>,
    pub(crate) untested: Vec<String>,
    pub(crate) data_only: bool,
    pub(crate) nu: Option<f64>,
}

impl Prepared {
    /// Calibration `b`'s (`later`) or `a`'s data-only values and covariance
    /// in the parameters' units, what neither sees projected out.
    pub(crate) fn in_units(&self, later: bool) -> (Vec<f64>, DMatrix<f64>) {
        let (p, s) = if later { &self.b } else { &self.a };
        let m = self.tested.len();
        let keep = DMatrix::identity(m, m) - &self.unseen * self.unseen.transpose();
        let s = &keep * s * &keep;
        let d = &self.scale;
        (
            (0..m).map(|i| p[i] * d[i]).collect(),
            DMatrix::from_fn(m, m, |i, j| s[(i, j)] * d[i] * d[j]),
        )
    }
}

/// [`Prepared`] of `a` and `b`.
pub(crate) fn prepare(a: &Compared, b: &Compared) -> Result<Prepared> {
    let value = |c: &Compared, n: &str| c.values.iter().find(|(m, _)| m == n).map(|v| v.1);
    // Tested: identified in either with a value in both; a parameter only one
    // identified is tested when the other gives it without uncertainty
    // (nominal values), else it is listed untested.
    let mut tested: Vec<String> = vec![];
    let mut untested: Vec<String> = vec![];
    let nuisance = |n: &String| a.nuisance.contains(n) || b.nuisance.contains(n);
    let either: Vec<&String> = a
        .names
        .iter()
        .chain(b.names.iter().filter(|n| !a.names.contains(n)))
        .filter(|n| !nuisance(n))
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
    // Each calibration's parameters as `data_only` reads them: the tested
    // ones, then its own nuisance.
    let full_of = |c: &Compared| -> Vec<String> {
        tested
            .iter()
            .cloned()
            .chain(c.nuisance.iter().filter(|n| c.names.contains(n)).cloned())
            .collect()
    };
    let (full_a, full_b) = (full_of(a), full_of(b));
    let cov_of = |c: &Compared, full: &[String]| {
        let at: Vec<Option<usize>> = full
            .iter()
            .map(|x| c.names.iter().position(|n| n == x))
            .collect();
        DMatrix::from_fn(full.len(), full.len(), |i, j| match (at[i], at[j]) {
            (Some(x), Some(y)) => c.covariance[x][y],
            _ => 0.0,
        })
    };
    let values_of = |c: &Compared, full: &[String]| {
        DVector::from_iterator(
            full.len(),
            full.iter().map(|n| value(c, n).unwrap_or(f64::NAN)),
        )
    };
    let prior_of = |c: &Compared, full: &[String]| -> Vec<Option<(f64, f64)>> {
        full.iter()
            .map(|n| {
                c.priors
                    .iter()
                    .find(|t| &t.name == n && !t.constraint)
                    .map(|t| (t.centre, t.sigma))
            })
            .collect()
    };
    let (ca, cb) = (cov_of(a, &full_a), cov_of(b, &full_b));
    let (va, vb) = (values_of(a, &full_a), values_of(b, &full_b));
    for (i, n) in tested.iter().enumerate() {
        let s = ca[(i, i)] + cb[(i, i)];
        if !(va[i].is_finite() && vb[i].is_finite() && s.is_finite() && s >= 0.0) {
            return Err(Error::InvalidRequest(format!(
                "`{n}` has no finite value or standard deviation in both calibrations; they cannot be compared"
            )));
        }
    }
    // The scaled basis: each parameter over its combined σ (a nuisance
    // parameter over its own).
    let d: Vec<f64> = (0..m)
        .map(|i| {
            let s = (ca[(i, i)] + cb[(i, i)]).sqrt();
            if s > 0.0 { s } else { 1.0 }
        })
        .collect();
    let scale_of = |c: &DMatrix<f64>| -> Vec<f64> {
        d.iter()
            .copied()
            .chain((m..c.nrows()).map(|i| {
                let s = c[(i, i)].sqrt();
                if s > 0.0 && s.is_finite() { s } else { 1.0 }
            }))
            .collect()
    };
    let (pa, sa, na) = data_only(&va, &ca, &prior_of(a, &full_a), &scale_of(&ca), m);
    let (pb, sb, nb) = data_only(&vb, &cb, &prior_of(b, &full_b), &scale_of(&cb), m);
    let data_only = [a, b].iter().any(|c| {
        c.priors
            .iter()
            .any(|t| tested.contains(&t.name) || c.nuisance.contains(&t.name))
    });
    // What either calibration's data do not see, orthonormal: the
    // directions the two projectors onto the unseen share on average
    // ([`unseen_of_either`]).
    let (unseen, seen) = unseen_of_either(&na, &nb, m);
    Ok(Prepared {
        tested,
        scale: d,
        a: (pa, sa),
        b: (pb, sb),
        unseen,
        seen,
        untested,
        data_only,
        nu,
    })
}

/// An orthonormal basis (columns) of what either calibration's data do
/// not see, from the bases `na` and `nb` of each one's unseen directions:
/// the eigenvectors of the mean of their projectors `(NₐNₐᵀ + N_bN_bᵀ)/2`
/// whose eigenvalue exceeds [`UNSEEN_MERGE`]. A direction unseen by one only
/// has eigenvalue ½ and is kept; two unseen directions at a small angle `θ`
/// (two fits at nearby solutions: the same direction but for rounding and
/// curvature) give `(1 ± cos θ)/2`, so one is kept and the sliver between
/// them, `θ²/4`, is not. Taking every direction of their union instead
/// (their columns' span) made a handful of such slivers "unseen" and left
/// the comparison on whatever the roundoff pointed at. Also the basis of
/// the rest (what both see), from the same eigenvectors.
fn unseen_of_either(
    na: &DMatrix<f64>,
    nb: &DMatrix<f64>,
    m: usize,
) -> (DMatrix<f64>, DMatrix<f64>) {
    if na.ncols() + nb.ncols() == 0 {
        return (DMatrix::zeros(m, 0), DMatrix::zeros(m, 0));
    }
    let mean = (na * na.transpose() + nb * nb.transpose()) / 2.0;
    let eig = mean.symmetric_eigen();
    let (unseen, seen): (Vec<usize>, Vec<usize>) =
        (0..m).partition(|&k| eig.eigenvalues[k] > UNSEEN_MERGE);
    (
        eig.eigenvectors.select_columns(&unseen),
        eig.eigenvectors.select_columns(&seen),
    )
}

/// The seen part of a covariance and of a change: `Qᵀ S Q` and `Qᵀ x`, `Q`
/// the basis `seen` of what the unseen directions leave (`S` and `x`
/// themselves when nothing is unseen). The joint test runs on these, not
/// on `S` with the unseen projected out: its zero directions, rescaled to
/// correlation form, were rounding errors counted as degrees of freedom.
fn seen_part(
    s: &DMatrix<f64>,
    x: &DVector<f64>,
    unseen: &DMatrix<f64>,
    seen: &DMatrix<f64>,
) -> (DMatrix<f64>, DVector<f64>) {
    if unseen.ncols() == 0 {
        return (s.clone(), x.clone());
    }
    (seen.transpose() * s * seen, seen.transpose() * x)
}

/// Compare `a` with `b` (the later calibration, or nominal values with no
/// covariance) at familywise false-alarm rate `alpha`.
pub fn drift(a: &Compared, b: &Compared, alpha: f64) -> Result<Drift> {
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(Error::InvalidRequest(format!(
            "the false-alarm rate is {alpha}; give a number between 0 and 1 (0.05 is usual)"
        )));
    }
    let Prepared {
        tested,
        scale: d,
        a: (pa, sa),
        b: (pb, sb),
        unseen,
        seen,
        mut untested,
        data_only,
        nu,
    } = prepare(a, b)?;
    let change_s = &pb - &pa;
    let s_sum = &sa + &sb;
    let mut parameters = vec![];
    for (i, n) in tested.iter().enumerate() {
        let hidden = unseen.row(i).norm_squared();
        if hidden > UNSEEN_SHARE {
            untested.push(n.clone());
            continue;
        }
        let (before, after) = (pa[i] * d[i], pb[i] * d[i]);
        let sigma = s_sum[(i, i)].max(0.0).sqrt() * d[i];
        let change = change_s[i] * d[i];
        let z = if sigma > 0.0 {
            change / sigma
        } else if change == 0.0 {
            0.0
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
            p_value: if sigma > 0.0 {
                two_sided(z, nu)
            } else if change == 0.0 {
                1.0
            } else {
                0.0
            },
            drifted: false,
        });
    }
    let k = parameters.len();
    parameters.sort_by(|x, y| x.p_value.total_cmp(&y.p_value));
    // Holm–Bonferroni, step down.
    for (j, p) in parameters.iter_mut().enumerate() {
        if p.p_value <= alpha / (k - j) as f64 {
            p.drifted = true;
        } else {
            break;
        }
    }
    // The joint test on what both see.
    let (s_seen, change_seen) = seen_part(&s_sum, &change_s, &unseen, &seen);
    let (chi2, dof, p_joint) = quadratic_test(&s_seen, &change_seen, nu)?;
    Ok(Drift {
        alpha,
        parameters,
        chi2,
        dof,
        p_joint,
        noise_dof: nu,
        joint_drift: p_joint < alpha,
        untested,
        data_only,
        workspace: None,
    })
}

/// The degrees of freedom of the two calibrations' noise levels together;
/// `None` (the normal and χ² limits) when every σ was given, or from
/// [`super::uncertainty::NORMAL_LIMIT_DOF`] on.
pub fn joint_noise_dof(a: &Compared, b: &Compared) -> Option<f64> {
    match (a.dof, b.dof) {
        (Some(x), Some(y)) => Some(x + y),
        (x, y) => x.or(y),
    }
    .filter(|n| n.is_finite() && *n > 0.0 && *n < super::uncertainty::NORMAL_LIMIT_DOF)
}

/// The joint test of a change `d` with covariance `c`: `dᵀ c⁺ d` in
/// correlation form (each coordinate over its standard deviation, so that
/// no unit swamps another), over the eigenvalues above [`RANK_TOL`] of the
/// largest; its degrees of freedom (that rank) and its p-value (χ², or
/// Fisher's F with `nu` when the noise levels were estimated). The one rule
/// of the parameter and workspace tests.
pub(crate) fn quadratic_test(
    c: &DMatrix<f64>,
    d: &DVector<f64>,
    nu: Option<f64>,
) -> Result<(f64, usize, f64)> {
    let n = d.len();
    let sd: Vec<f64> = (0..n).map(|i| c[(i, i)].max(0.0).sqrt()).collect();
    let top_sd = sd.iter().copied().fold(0.0, f64::max);
    // Coordinates with no variance at all carry no test.
    let live: Vec<usize> = (0..n)
        .filter(|&i| sd[i] > 1e-150 * top_sd.max(f64::MIN_POSITIVE))
        .collect();
    let r = DMatrix::from_fn(live.len(), live.len(), |a, b| {
        c[(live[a], live[b])] / (sd[live[a]] * sd[live[b]])
    });
    let x = DVector::from_fn(live.len(), |a, _| d[live[a]] / sd[live[a]]);
    let eig = r.symmetric_eigen();
    let top = eig.eigenvalues.iter().fold(0.0f64, |x, v| x.max(*v));
    let mut chi2 = 0.0;
    let mut dof = 0;
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l > RANK_TOL * top && l > 0.0 {
            let proj = eig.eigenvectors.column(k).dot(&x);
            chi2 += proj * proj / l;
            dof += 1;
        }
    }
    let p = match (dof, nu) {
        (0, _) => f64::NAN,
        (d, Some(n)) => FisherSnedecor::new(d as f64, n)
            .map_err(|e| Error::InvalidRequest(format!("F({d}, {n}): {e}")))?
            .sf(chi2 / d as f64),
        (d, None) => ChiSquared::new(d as f64)
            .map_err(|e| Error::InvalidRequest(format!("χ² with {d} degrees: {e}")))?
            .sf(chi2),
    };
    Ok((chi2, dof, p))
}

impl Compared {
    /// A calibration record's values, covariance (the mechanism's
    /// identified parameters) and priors; its noise level's degrees of
    /// freedom from its `scale`, else `dof` (a record written before).
    pub fn from_record(r: &super::record::CalibrationRecord, dof: Option<f64>) -> Self {
        Compared {
            values: r
                .parameters
                .iter()
                .map(|p| (p.name.clone(), p.identified))
                .collect(),
            names: r.covariance.names.clone(),
            covariance: r.covariance.matrix.clone(),
            dof: r.scale.map_or(dof, |s| s.dof()),
            priors: r.priors.clone(),
            nuisance: vec![],
        }
    }

    /// A calibration's values, covariance and priors, with the degrees of
    /// freedom of its scale ([`super::uncertainty::Scale`]). Where the
    /// instrument's parameters had priors (a bed's tilt within its
    /// tolerance), they come as [`Compared::nuisance`] with their
    /// covariance: integrated out after their priors are removed, so that
    /// the instrument's tolerance, shared by both, is not counted as two
    /// independent errors (which made the test conservative: 2 false alarms
    /// in 200 at 5 % on a delta's physical model, 9 with them integrated
    /// out).
    pub fn from_calibration(c: &super::result::Calibration) -> Self {
        let mut names = c.parameter_covariance.names.clone();
        let mut covariance = c.parameter_covariance.matrix.clone();
        let np = c.params.values.len();
        let held = |i: usize| c.priors.iter().any(|t| t.index == i && !t.constraint);
        let instrument: Vec<usize> = (0..c.free.len()).filter(|&k| c.free[k] >= np).collect();
        let mut nuisance = vec![];
        if instrument.iter().any(|&k| held(c.free[k])) {
            // The mechanism's rows of the full covariance by name (a
            // constraint's parameter has none: not free).
            let at: Vec<Option<usize>> = names
                .iter()
                .map(|n| {
                    c.free
                        .iter()
                        .position(|&i| i < np && &c.parameters[i].name == n)
                })
                .collect();
            for row in &mut covariance {
                row.extend(std::iter::repeat_n(0.0, instrument.len()));
            }
            for (r, &x) in at.iter().enumerate() {
                if let Some(x) = x {
                    for (j, &k) in instrument.iter().enumerate() {
                        covariance[r][names.len() + j] = c.covariance[(x, k)];
                    }
                }
            }
            for &k in &instrument {
                let mut row: Vec<f64> = at
                    .iter()
                    .map(|x| x.map_or(0.0, |x| c.covariance[(k, x)]))
                    .collect();
                row.extend(instrument.iter().map(|&l| c.covariance[(k, l)]));
                covariance.push(row);
            }
            for &k in &instrument {
                let name = c.parameters[c.free[k]].name.clone();
                nuisance.push(name.clone());
                names.push(name);
            }
        }
        Compared {
            values: c
                .parameters
                .iter()
                .map(|p| (p.name.clone(), p.identified))
                .collect(),
            names,
            covariance,
            dof: c.scale.dof(),
            priors: c.priors.clone(),
            nuisance,
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
            priors: vec![],
            nuisance: vec![],
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
