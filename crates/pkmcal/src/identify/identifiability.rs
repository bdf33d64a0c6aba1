//! Identifiability: the column-scaled identification Jacobian's SVD, rank,
//! condition number and observability indices, the unidentifiable directions
//! named as combinations of parameters (and which parameter to fix), and the
//! correlations.

use crate::lm;
use crate::measurement::MeasurementModel;
use crate::mechanism::Spec;
use crate::units::{ParamKind, Unit};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// Singular values below this fraction of the largest (of the column-scaled
/// identification Jacobian) count as unidentifiable directions.
pub const RANK_TOL: f64 = 1e-8;
/// A Jacobian column whose effect is below this fraction of the largest counts
/// as zero (the parameter does not act on the tool at all).
pub const ZERO_COLUMN: f64 = 1e-10;
/// Correlations above this are reported.
pub const CORRELATION_REPORT: f64 = 0.9;
/// Components below this are left out of a named unidentifiable combination.
const COMBINATION_CUTOFF: f64 = 0.05;

/// Observability indices of the column-scaled identification Jacobian with
/// singular values σ₁ ≥ … ≥ σ_L over m poses (Sun & Hollerbach, "Observability
/// index selection for robot calibration", ICRA 2008, which collects them):
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct Observability {
    /// O1 = (σ₁⋯σ_L)^(1/L) / √m (Borm & Menq 1991): the volume of the error ellipsoid.
    pub o1: f64,
    /// O2 = σ_L / σ₁ (Driels & Pathre 1990): inverse condition number.
    pub o2: f64,
    /// O3 = σ_L (Nahvi, Hollerbach & Hayward 1994): minimum singular value.
    pub o3: f64,
    /// O4 = σ_L² / σ₁ (Nahvi & Hollerbach 1996): noise amplification index.
    pub o4: f64,
    /// O5 = 1 / Σ 1/σ_i (Sun & Hollerbach 2008): inverse of the summed variances.
    pub o5: f64,
}

/// A direction in parameter space the data cannot see.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct Unidentifiable {
    /// The combination, e.g. `0.71·l11 − 0.71·B1x` (column-scaled units).
    pub combination: String,
    /// `(name, coefficient)` of the combination.
    pub terms: Vec<(String, f64)>,
    /// The parameter fixed to remove it (when fixing automatically).
    pub fixed: Option<String>,
}

/// A pair of strongly correlated parameters.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct Correlation {
    /// First parameter.
    pub a: String,
    /// Second parameter.
    pub b: String,
    /// Correlation coefficient.
    pub r: f64,
}

/// A number, or `"inf"` for +∞ (JSON has no infinity).
fn number_or_inf<S: serde::Serializer>(v: &f64, s: S) -> std::result::Result<S::Ok, S::Error> {
    if *v == f64::INFINITY {
        s.serialize_str("inf")
    } else {
        s.serialize_f64(*v)
    }
}

/// A number, or `"inf"` as [`number_or_inf`] writes +∞.
fn number_or_inf_de<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    #[derive(serde::Deserialize)]
    #[serde(untagged)]
    enum NumberOrText {
        Number(f64),
        Text(String),
    }
    match NumberOrText::deserialize(d)? {
        NumberOrText::Number(v) => Ok(v),
        NumberOrText::Text(t) if t == "inf" => Ok(f64::INFINITY),
        NumberOrText::Text(t) => Err(serde::de::Error::custom(format!(
            "expected a number or \"inf\", got \"{t}\""
        ))),
    }
}

/// Identifiability of the free parameters from the poses.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct Identifiability {
    /// Free parameters analysed (names).
    pub free: Vec<String>,
    /// Singular values of the column-scaled Jacobian (descending).
    pub singular_values: Vec<f64>,
    /// Numerical rank.
    pub rank: usize,
    /// σ₁ / σ_L (infinite when rank deficient; written `"inf"` in JSON,
    /// which has no infinity, rather than a `null` that reads as missing).
    #[serde(
        serialize_with = "number_or_inf",
        deserialize_with = "number_or_inf_de"
    )]
    pub condition_number: f64,
    /// Observability indices O1–O5 (over the identifiable part).
    pub observability: Observability,
    /// Unidentifiable directions.
    pub unidentifiable: Vec<Unidentifiable>,
    /// Pairs of free parameters correlated above 0.9.
    pub correlations: Vec<Correlation>,
    /// Directions the data alone cannot see but the parameters' tolerances
    /// bound: identified, held by their priors (docs/model.md eq. 13).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub held: Vec<Unidentifiable>,
}

pub(crate) fn observability(sv: &[f64], poses: usize) -> Observability {
    let l = sv.len().max(1) as f64;
    let last = sv.last().copied().unwrap_or(0.0);
    let first = sv.first().copied().unwrap_or(0.0);
    let logsum: f64 = sv.iter().map(|s| s.ln()).sum();
    Observability {
        o1: (logsum / l).exp() / (poses as f64).sqrt(),
        o2: if first > 0.0 { last / first } else { 0.0 },
        o3: last,
        o4: if first > 0.0 {
            last * last / first
        } else {
            0.0
        },
        o5: 1.0 / sv.iter().map(|s| 1.0 / s).sum::<f64>(),
    }
}

/// The columns of an identification Jacobian: each parameter's name, unit,
/// kind and typical size (its nominal value, for judging whether a column
/// acts at all).
#[derive(Debug, Clone, PartialEq)]
pub struct Columns {
    /// Names, in column order.
    pub names: Vec<String>,
    /// Units.
    pub units: Vec<Unit>,
    /// Kinds.
    pub kinds: Vec<ParamKind>,
    /// Nominal values.
    pub nominal: Vec<f64>,
}

impl Columns {
    /// The mechanism's parameters.
    pub fn of(spec: &Spec) -> Self {
        let n = spec.n_params();
        Self {
            names: spec.param_names().iter().map(|s| s.to_string()).collect(),
            units: (0..n).map(|i| spec.param_unit(i)).collect(),
            kinds: (0..n).map(|i| spec.param_kind(i)).collect(),
            nominal: spec.nominal.clone(),
        }
    }

    /// The mechanism's parameters, then the measurement model's (`values`:
    /// theirs at the start).
    pub fn with_measurement(spec: &Spec, measurement: &MeasurementModel, values: &[f64]) -> Self {
        let mut c = Self::of(spec);
        c.names.extend(measurement.param_names().iter().cloned());
        c.units.extend(measurement.param_units());
        c.kinds
            .extend(std::iter::repeat_n(ParamKind::Instrument, values.len()));
        c.nominal.extend(values);
        c
    }
}

pub(super) fn correlations(
    names: &[String],
    free: &[usize],
    cov: &DMatrix<f64>,
) -> Vec<Correlation> {
    let mut out = vec![];
    for a in 0..free.len() {
        for b in a + 1..free.len() {
            let d = (cov[(a, a)] * cov[(b, b)]).sqrt();
            if d > 0.0 {
                let r = cov[(a, b)] / d;
                if r.abs() > CORRELATION_REPORT {
                    out.push(Correlation {
                        a: names[free[a]].to_string(),
                        b: names[free[b]].to_string(),
                        r,
                    });
                }
            }
        }
    }
    out
}

/// Analyse the identifiability of `free` from the full identification
/// Jacobian `jac` (weighted): scale every column to unit norm, take the SVD,
/// name each direction below [`RANK_TOL`]. With `auto_fix`, fix one parameter
/// per unidentifiable direction (the one that dominates it) until the rest
/// has full rank. Returns the analysis and the remaining free set.
pub fn analyze_identifiability(
    cols: &Columns,
    jac: &DMatrix<f64>,
    free: &[usize],
    poses: usize,
    auto_fix: bool,
) -> (Identifiability, Vec<usize>) {
    let names: Vec<&str> = cols.names.iter().map(String::as_str).collect();
    let mut free = free.to_vec();
    let mut unidentifiable = vec![];
    let mut first_sv: Option<Vec<f64>> = None;
    loop {
        if free.is_empty() {
            let ident = Identifiability {
                free: vec![],
                singular_values: first_sv.unwrap_or_default(),
                rank: 0,
                condition_number: f64::INFINITY,
                observability: observability(&[], poses),
                unidentifiable,
                correlations: vec![],
                held: vec![],
            };
            return (ident, free);
        }
        // A large Jacobian's free columns are read where they are, not
        // copied out ([`lm::LARGE_JACOBIAN`]).
        let large = jac.nrows().saturating_mul(free.len()) >= lm::LARGE_JACOBIAN
            && jac.nrows() >= free.len();
        let sub = (!large).then(|| jac.select_columns(&free));
        let norm = |k: usize| match &sub {
            Some(s) => s.column(k).norm(),
            None => jac.column(free[k]).norm(),
        };
        // A column counts as zero when its effect over a typical parameter
        // change (its nominal size, or 1 unit) is negligible next to the
        // largest one: round-off must not be scaled up into a direction.
        let effect: Vec<f64> = free
            .iter()
            .enumerate()
            .map(|(k, &i)| norm(k) * cols.nominal[i].abs().max(1.0))
            .collect();
        let biggest = effect.iter().copied().fold(0.0, f64::max);
        let norms: Vec<f64> = (0..free.len())
            .map(|k| {
                if effect[k] > ZERO_COLUMN * biggest {
                    norm(k)
                } else {
                    0.0
                }
            })
            .collect();
        let (singular_values, vt, factored) = match &sub {
            Some(sub) => scaled_svd(sub, &norms),
            None => {
                let (mut qr, _) =
                    lm::triangular_factor_of(jac, &free, None, &vec![0.0; jac.nrows()]);
                let (ipvt, rdiag, _) = lm::qrfac(&mut qr);
                pivoted_svd(qr, ipvt, rdiag, &norms)
            }
        };
        let mut order: Vec<usize> = (0..singular_values.len()).collect();
        order.sort_by(|&a, &b| singular_values[b].total_cmp(&singular_values[a]));
        let sv: Vec<f64> = order.iter().map(|&i| singular_values[i]).collect();
        if first_sv.is_none() {
            first_sv = Some(sv.clone());
        }
        let smax = sv.first().copied().unwrap_or(0.0);
        // Directions: zero columns, then small singular values.
        let mut dirs: Vec<Vec<f64>> = norms
            .iter()
            .enumerate()
            .filter(|(_, n)| **n == 0.0)
            .map(|(k, _)| {
                let mut v = vec![0.0; free.len()];
                v[k] = 1.0;
                v
            })
            .collect();
        if dirs.is_empty() {
            for &i in &order {
                if singular_values[i] <= RANK_TOL * smax {
                    dirs.push(vt.row(i).iter().copied().collect());
                }
            }
        }
        if dirs.is_empty() || !auto_fix {
            for d in &dirs {
                unidentifiable.push(direction(&names, &free, d, None));
            }
            let rank = sv.iter().filter(|s| **s > RANK_TOL * smax).count();
            let kept: Vec<f64> = sv[..rank].to_vec();
            let cov = if rank == free.len() {
                let (c, _) = match &factored {
                    Some((qr, ipvt, rdiag)) => {
                        lm::covariance_of(qr, ipvt, rdiag, lm::COVARIANCE_RANK_TOL)
                    }
                    None => lm::covariance(
                        sub.as_ref().expect("kept when not factorised"),
                        lm::COVARIANCE_RANK_TOL,
                    ),
                };
                correlations(&cols.names, &free, &c)
            } else {
                vec![]
            };
            let all_sv = first_sv.unwrap_or_default();
            let cond = if rank == all_sv.len() && rank > 0 {
                all_sv[0] / all_sv[rank - 1]
            } else {
                f64::INFINITY
            };
            let ident = Identifiability {
                free: free.iter().map(|&i| names[i].to_string()).collect(),
                rank: all_sv
                    .iter()
                    .filter(|s| **s > RANK_TOL * all_sv.first().copied().unwrap_or(0.0))
                    .count(),
                condition_number: cond,
                observability: observability(&kept, poses),
                singular_values: all_sv,
                unidentifiable,
                correlations: cov,
                held: vec![],
            };
            return (ident, free);
        }
        let k = fix_choice(cols, &free, &dirs);
        // Report the direction that fixing `k` removes: the one it takes the
        // most part in (with zero columns, that parameter alone).
        let d = dirs
            .iter()
            .reduce(|a, b| if b[k].abs() > a[k].abs() { b } else { a })
            .expect("non-empty");
        unidentifiable.push(direction(
            &names,
            &free,
            d,
            Some(names[free[k]].to_string()),
        ));
        free.remove(k);
    }
}

/// A pivoted QR of a Jacobian ([`lm::qrfac`]: factors, column order, R's
/// diagonal).
type Factored = (DMatrix<f64>, Vec<usize>, Vec<f64>);

/// The singular values and right singular vectors (`Vᵀ`, one row per
/// value) of `sub` with each column `k` divided by `norms[k]` (left as it is
/// where that is 0), and the pivoted QR they came from. With at least as
/// many rows as columns, from `sub`'s QR: `sub P = Q R` makes the scaled
/// matrix `Q (R D⁻¹) Pᵀ` (`D` the norms in pivot order), whose singular
/// values and right vectors are those of the square `R D⁻¹`, columns put
/// back in order — an SVD of `n × n` instead of `m × n`, and the QR serves
/// the covariance. With fewer rows, zero rows make the matrix square, so
/// that the SVD also gives the null space (as many zero singular values as
/// missing rows, each with its direction).
#[doc(hidden)] // public for the integration tests only
pub fn scaled_svd(sub: &DMatrix<f64>, norms: &[f64]) -> (Vec<f64>, DMatrix<f64>, Option<Factored>) {
    let (m, n) = sub.shape();
    let divisor = |k: usize| if norms[k] > 0.0 { norms[k] } else { 1.0 };
    if m < n {
        let mut scaled = sub.clone();
        for k in 0..n {
            scaled.column_mut(k).unscale_mut(divisor(k));
        }
        let scaled = scaled.insert_rows(m, n - m, 0.0);
        let svd = scaled.svd(false, true);
        let vt = svd.v_t.expect("requested");
        return (svd.singular_values.iter().copied().collect(), vt, None);
    }
    let mut qr = sub.clone();
    let (ipvt, rdiag, _) = lm::qrfac(&mut qr);
    pivoted_svd(qr, ipvt, rdiag, norms)
}

/// [`scaled_svd`] from the pivoted QR ([`lm::qrfac`]) of the matrix, or
/// of its triangular factor ([`lm::triangular_factor_of`]): `R`'s upper
/// triangle is all it reads.
fn pivoted_svd(
    qr: DMatrix<f64>,
    ipvt: Vec<usize>,
    rdiag: Vec<f64>,
    norms: &[f64],
) -> (Vec<f64>, DMatrix<f64>, Option<Factored>) {
    let n = qr.ncols();
    let divisor = |k: usize| if norms[k] > 0.0 { norms[k] } else { 1.0 };
    let rs = DMatrix::from_fn(n, n, |i, k| {
        let v = match i.cmp(&k) {
            std::cmp::Ordering::Less => qr[(i, k)],
            std::cmp::Ordering::Equal => rdiag[k],
            std::cmp::Ordering::Greater => 0.0,
        };
        v / divisor(ipvt[k])
    });
    let svd = rs.svd(false, true);
    let vt_pivoted = svd.v_t.expect("requested");
    let mut vt = DMatrix::zeros(vt_pivoted.nrows(), n);
    for (k, &c) in ipvt.iter().enumerate() {
        vt.set_column(c, &vt_pivoted.column(k));
    }
    let sv = svd.singular_values.iter().copied().collect();
    (sv, vt, Some((qr, ipvt, rdiag)))
}

/// Which free parameter (position in `free`) to fix for the unidentifiable
/// directions `dirs`: the mechanism's parameters before the instrument's (a
/// free instrument frame leaves the base frame to be defined by the
/// mechanism, e.g. `B2y = 0`), and among them the one that the space of
/// directions involves most (the largest row of an orthonormal basis of the
/// directions restricted to them; unlike "the largest entry of the first
/// direction", this does not depend on how the solver picked the basis, nor
/// on where the instrument stands).
fn fix_choice(cols: &Columns, free: &[usize], dirs: &[Vec<f64>]) -> usize {
    let preferred: Vec<usize> = (0..free.len())
        .filter(|&k| cols.kinds[free[k]] != ParamKind::Instrument)
        .collect();
    if !preferred.is_empty() {
        let d = DMatrix::from_fn(preferred.len(), dirs.len(), |r, c| dirs[c][preferred[r]]);
        let svd = d.svd(true, false);
        let smax = svd.singular_values.max();
        if smax > COMBINATION_CUTOFF {
            let u = svd.u.expect("requested");
            let keep: Vec<usize> = (0..svd.singular_values.len())
                .filter(|&j| svd.singular_values[j] > 1e-6 * smax)
                .collect();
            let weight = |r: usize| keep.iter().map(|&j| u[(r, j)].powi(2)).sum::<f64>();
            let r = (0..preferred.len())
                .max_by(|&a, &b| weight(a).total_cmp(&weight(b)))
                .expect("non-empty");
            return preferred[r];
        }
    }
    let d = &dirs[0];
    (0..d.len())
        .max_by(|&a, &b| d[a].abs().total_cmp(&d[b].abs()))
        .expect("non-empty")
}

fn direction(names: &[&str], free: &[usize], d: &[f64], fixed: Option<String>) -> Unidentifiable {
    let big = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let sign = d
        .iter()
        .find(|v| v.abs() == big)
        .map_or(1.0, |v| v.signum());
    let mut terms: Vec<(String, f64)> = d
        .iter()
        .enumerate()
        .filter(|(_, v)| v.abs() >= COMBINATION_CUTOFF * big)
        .map(|(k, v)| (names[free[k]].to_string(), sign * v))
        .collect();
    terms.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    let combination = terms
        .iter()
        .enumerate()
        .map(|(i, (n, c))| {
            let s = if *c < 0.0 {
                " − "
            } else if i > 0 {
                " + "
            } else {
                ""
            };
            format!("{s}{:.3}·{n}", c.abs())
        })
        .collect::<String>();
    Unidentifiable {
        combination,
        terms,
        fixed,
    }
}
