//! Measurement noise per group of like coordinates, and its estimation from
//! the residuals (variance-component estimation).
//!
//! Each measured coordinate has a standard deviation σ: given (a `sigma_*`
//! column) or unknown. Unknown ones are grouped by unit (all lengths of the
//! data one group, all angles another: mm and rad never share a σ) and each
//! group's σ is estimated from its residuals after a weighted fit,
//!
//! ```text
//! σ_g² = Σ_{i∈g} r_i²  /  Σ_{i∈g} (1 − h_ii)
//! ```
//!
//! with `h_ii` the leverages of the weighted Jacobian (`Σ (1 − h_ii)` is the
//! group's share of the redundancy `m − n`, Förstner's estimator), then the
//! fit is repeated with the new weights until the σ settle. Weighting by
//! 1/σ makes the fit the maximum-likelihood one whatever the units.

use crate::measurement::MeasurementModel;
use crate::measurement::data::{Measurement, Noise};
use crate::units::Unit;
use nalgebra::DMatrix;
use serde::Serialize;

/// Relative change of every group σ below which the estimation stops.
pub const VCE_TOL: f64 = 1e-3;
/// Most refits of the variance-component estimation.
pub const VCE_MAX_ROUNDS: usize = 12;

/// A group of like coordinates and its noise level.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct NoiseGroup {
    /// Unit of the coordinates (and of `sigma`, `residual_rms`).
    pub unit: Unit,
    /// Names of the measured axes in the group.
    pub axes: Vec<String>,
    /// Number of measured coordinates in the group.
    pub count: usize,
    /// Whether σ was estimated from the residuals (`false`: given in the
    /// data; `sigma` is then the root mean square of the given values).
    pub estimated: bool,
    /// Standard deviation of one coordinate.
    pub sigma: f64,
    /// Root mean square of the group's residuals at the solution.
    pub residual_rms: f64,
    /// The group's share of the redundancy, `Σ (1 − h_ii)`: the degrees of
    /// freedom its σ was estimated with (`None` when σ was given).
    pub redundancy: Option<f64>,
    /// The instrument's stated σ, a prior of the estimate worth
    /// `stated_readings` readings (`None`: estimated from the data alone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stated: Option<f64>,
    /// How many readings the stated σ was worth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stated_readings: Option<f64>,
    /// Whether only the stated σ's ratios to the other groups' were stated
    /// (a weighing rule such as Klipper's): `stated` is then the stated
    /// share of a common scale estimated from every stated group's
    /// residuals, and no adequacy test holds the group to it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub stated_relative: bool,
}

/// The ratio of two groups' variances, `σ_a² / σ_b²`, with its confidence
/// interval: each σ² estimated with its group's redundancy ν as degrees of
/// freedom, so the ratio of estimates over the ratio of true variances
/// follows Fisher's F(ν_a, ν_b) (Gaussian noise; the redundancy rounded
/// down to whole degrees).
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct VarianceRatio {
    /// The estimated ratio.
    pub ratio: f64,
    /// The interval's lower end.
    pub low: f64,
    /// Its upper end.
    pub high: f64,
    /// Its confidence level (e.g. 0.95).
    pub level: f64,
}

/// [`VarianceRatio`] of groups `a` and `b` at confidence `level`; `None`
/// when either σ was given or leans on a stated one (it is then not the
/// data's estimate alone), or either group has less than one degree of
/// freedom left.
pub fn variance_ratio(a: &NoiseGroup, b: &NoiseGroup, level: f64) -> Option<VarianceRatio> {
    use statrs::distribution::{ContinuousCDF, FisherSnedecor};
    if a.stated.is_some() || b.stated.is_some() {
        return None;
    }
    let (na, nb) = (a.redundancy?.floor(), b.redundancy?.floor());
    if !(na >= 1.0 && nb >= 1.0 && b.sigma > 0.0 && level > 0.0 && level < 1.0) {
        return None;
    }
    let ratio = (a.sigma / b.sigma).powi(2);
    let f = FisherSnedecor::new(na, nb).ok()?;
    let tail = 0.5 * (1.0 - level);
    Some(VarianceRatio {
        ratio,
        low: ratio / f.inverse_cdf(1.0 - tail),
        high: ratio / f.inverse_cdf(tail),
        level,
    })
}

/// Which σ each residual (row-major, readings inner) takes.
#[derive(Debug, Clone)]
#[doc(hidden)] // public for the integration tests only
pub struct NoiseModel {
    /// Per residual: `Ok(σ)` given, `Err(g)` the estimated group `g`.
    assign: Vec<Result<f64, usize>>,
    /// Per residual: its unit and reading name (an index into `axes`: one
    /// string per name, not per reading).
    readings: Vec<(Unit, u32)>,
    /// The readings' names.
    axes: Vec<String>,
    /// Estimated groups: unit, whether they are distances between poses
    /// (another instrument, their own group), and axis names.
    groups: Vec<(Unit, bool, Vec<String>)>,
    /// Current σ of each estimated group.
    pub sigma: Vec<f64>,
    /// Each estimated group's redundancy `Σ (1 − h_ii)` at the last update.
    redundancy: Vec<f64>,
    /// Each estimated group's stated σ and the readings it is worth.
    stated: Vec<Option<(f64, f64)>>,
    /// Whether only the stated σ's ratios are known: they are then scaled
    /// by the common factor `scale` estimated from the residuals.
    relative: bool,
    /// The stated σ's common scale factor at the last update (1 unless
    /// `relative`).
    scale: f64,
}

impl NoiseModel {
    /// Assign every reading of `data` (the readings of `measurement`, or one
    /// distance for a row that pairs two poses).
    pub fn new(data: &[Measurement], measurement: &MeasurementModel) -> Self {
        let mut groups: Vec<(Unit, bool, Vec<String>)> = vec![];
        let mut assign = Vec::with_capacity(data.len() * measurement.len());
        let mut readings = Vec::with_capacity(data.len() * measurement.len());
        let mut axes: Vec<String> = vec![];
        for m in data {
            let pair = m.partner.is_some();
            for a in 0..measurement.row_len(m) {
                let (unit, axis) = (measurement.row_unit(m, a), measurement.row_axis(m, a));
                let name = match axes.iter().position(|n| n == axis) {
                    Some(i) => i,
                    None => {
                        axes.push(axis.to_string());
                        axes.len() - 1
                    }
                };
                readings.push((unit, name as u32));
                match m.sigma_of(a) {
                    Some(s) => assign.push(Ok(s)),
                    None => {
                        let g = match groups.iter().position(|(u, p, _)| *u == unit && *p == pair) {
                            Some(g) => g,
                            None => {
                                groups.push((unit, pair, vec![]));
                                groups.len() - 1
                            }
                        };
                        if !groups[g].2.iter().any(|n| n == axis) {
                            groups[g].2.push(axis.to_string());
                        }
                        assign.push(Err(g));
                    }
                }
            }
        }
        let n = groups.len();
        Self {
            assign,
            readings,
            axes,
            groups,
            sigma: vec![1.0; n],
            redundancy: vec![f64::NAN; n],
            stated: vec![None; n],
            relative: false,
            scale: 1.0,
        }
    }

    /// The stated noise as a prior of the estimated groups, worth
    /// `readings` readings: `noise` for the instrument's readings, `distances`
    /// (mm) for the distances between poses (another instrument: calipers, a
    /// ball bar). Each such group's σ² is then `(ν₀ σ₀² + Σ r²) / (ν₀ + Σ (1 −
    /// h))`, the data's estimate as far as their redundancy supports it
    /// (docs/model.md §6); with `ν₀` infinite, the stated σ₀. With
    /// `relative`, only the stated σ's ratios are known (a weighing rule):
    /// `σ₀` is the stated value times a common scale `τ`, with `τ² = Σ Σ r² /
    /// σ₀² / Σ Σ (1 − h)` over the stated groups, the pooled estimate under
    /// the stated ratios. The groups start from the stated σ.
    pub fn with_stated(
        mut self,
        noise: Option<Noise>,
        distances: Option<f64>,
        readings: f64,
        relative: bool,
    ) -> Self {
        for (g, (unit, pair, _)) in self.groups.iter().enumerate() {
            let s0 = match pair {
                false => noise.map(|n| n.for_unit(*unit)),
                true => distances.filter(|_| *unit == Unit::Millimetre),
            };
            if let Some(s0) = s0 {
                self.stated[g] = Some((s0, readings));
                self.sigma[g] = s0;
            }
        }
        self.relative = relative;
        self
    }

    /// Number of estimated groups.
    pub fn estimated_groups(&self) -> usize {
        self.groups.len()
    }

    /// Whether any σ is given in the data.
    pub fn any_given(&self) -> bool {
        self.assign.iter().any(Result::is_ok)
    }

    /// σ of every residual under the current group estimates.
    pub fn sigmas(&self) -> Vec<f64> {
        self.assign
            .iter()
            .map(|a| match a {
                Ok(s) => *s,
                Err(g) => self.sigma[*g],
            })
            .collect()
    }

    /// New group σ from residuals `r` (unweighted) and leverages `h` of the
    /// weighted Jacobian; returns the largest relative change.
    pub fn update(&mut self, r: &[f64], h: &[f64]) -> f64 {
        let n = self.groups.len();
        let mut ss = vec![0.0; n];
        let mut red = vec![0.0; n];
        for ((a, ri), hi) in self.assign.iter().zip(r).zip(h) {
            if let Err(g) = a {
                ss[*g] += ri * ri;
                red[*g] += (1.0 - hi).max(0.0);
            }
        }
        let mut change: f64 = 0.0;
        self.redundancy.clone_from(&red);
        if self.relative {
            // The common scale of the stated σ: the pooled estimate under
            // the stated ratios.
            let (mut num, mut den) = (0.0, 0.0);
            for g in 0..n {
                if let Some((s0, _)) = self.stated[g] {
                    num += ss[g] / (s0 * s0);
                    den += red[g];
                }
            }
            if num > 0.0 && den > 0.0 {
                self.scale = (num / den).sqrt();
            }
        }
        for g in 0..n {
            if let Some((s0, nu)) = self.stated[g] {
                let s0 = s0 * self.scale;
                let s = if nu.is_infinite() {
                    s0
                } else {
                    ((nu * s0 * s0 + ss[g]) / (nu + red[g])).sqrt()
                };
                change = change.max((s / self.sigma[g] - 1.0).abs());
                self.sigma[g] = s;
            } else if red[g] > 0.0 && ss[g] > 0.0 {
                let s = (ss[g] / red[g]).sqrt();
                change = change.max((s / self.sigma[g] - 1.0).abs());
                self.sigma[g] = s;
            }
        }
        change
    }

    /// The groups as reported: estimated ones, then given ones by unit.
    pub fn report(&self, r: &[f64]) -> Vec<NoiseGroup> {
        let mut out: Vec<NoiseGroup> = self
            .groups
            .iter()
            .enumerate()
            .map(|(g, (unit, _, names))| {
                let v: Vec<f64> = self
                    .assign
                    .iter()
                    .zip(r)
                    .filter(|(a, _)| **a == Err(g))
                    .map(|(_, ri)| *ri)
                    .collect();
                NoiseGroup {
                    unit: *unit,
                    axes: names.clone(),
                    count: v.len(),
                    estimated: true,
                    sigma: self.sigma[g],
                    residual_rms: rms(&v),
                    redundancy: Some(self.redundancy[g]).filter(|r| !r.is_nan()),
                    stated: self.stated[g].map(|s| s.0 * self.scale),
                    stated_readings: self.stated[g].map(|s| s.1),
                    stated_relative: self.relative && self.stated[g].is_some(),
                }
            })
            .collect();
        // Per unit: axes, given σ, residuals.
        type Given = (Unit, Vec<String>, Vec<f64>, Vec<f64>);
        let mut given: Vec<Given> = vec![];
        for (k, (a, ri)) in self.assign.iter().zip(r).enumerate() {
            if let Ok(s) = a {
                let (unit, axis) = (self.readings[k].0, &self.axes[self.readings[k].1 as usize]);
                let e = match given.iter().position(|x| x.0 == unit) {
                    Some(e) => e,
                    None => {
                        given.push((unit, vec![], vec![], vec![]));
                        given.len() - 1
                    }
                };
                if !given[e].1.contains(axis) {
                    given[e].1.push(axis.clone());
                }
                given[e].2.push(*s);
                given[e].3.push(*ri);
            }
        }
        out.extend(given.into_iter().map(|(unit, names, s, v)| NoiseGroup {
            unit,
            axes: names,
            count: v.len(),
            estimated: false,
            sigma: rms(&s),
            residual_rms: rms(&v),
            redundancy: None,
            stated: None,
            stated_readings: None,
            stated_relative: false,
        }));
        out
    }

    /// Group key of each residual (for per-group robust scales): estimated
    /// groups by number, given σ by unit after them.
    pub fn keys(&self) -> Vec<usize> {
        let n = self.groups.len();
        self.assign
            .iter()
            .zip(&self.readings)
            .map(|(a, (unit, _))| match a {
                Err(g) => *g,
                Ok(_) => n + *unit as usize,
            })
            .collect()
    }
}

fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// Leverages `h_ii = J_i (JᵀJ)⁺ J_iᵀ` of a weighted Jacobian (rows: residuals,
/// columns: free parameters).
#[doc(hidden)] // public for the integration tests only
pub fn leverages(jac: &DMatrix<f64>) -> Vec<f64> {
    if is_large(jac) {
        let c = covariance_by_rows(jac, None);
        return leverages_by_rows(jac, None, &c);
    }
    let (c, _) = crate::lm::covariance(jac, crate::lm::COVARIANCE_RANK_TOL);
    leverages_with(jac, &c)
}

/// [`leverages`] with `(JᵀJ)⁺` already computed (a large Jacobian's by
/// blocks of rows, [`leverages_by_rows`]).
pub(crate) fn leverages_with(jac: &DMatrix<f64>, inverse: &DMatrix<f64>) -> Vec<f64> {
    if is_large(jac) {
        return leverages_by_rows(jac, None, inverse);
    }
    let jc = jac * inverse;
    (0..jac.nrows())
        .map(|i| jc.row(i).dot(&jac.row(i)))
        .collect()
}

/// Whether a Jacobian is large ([`crate::lm::LARGE_JACOBIAN`]): its statistics are
/// then computed row by row, without copies of it.
pub(crate) fn is_large(j: &DMatrix<f64>) -> bool {
    j.nrows().saturating_mul(j.ncols()) >= crate::lm::LARGE_JACOBIAN && j.nrows() >= j.ncols()
}

/// Rows of a large Jacobian read at a time.
const ROW_BLOCK: usize = 256;

/// `f(first row, rows)` for blocks of `j`'s rows, each row (row-major, `n`
/// entries) multiplied by `scale[i]` when given.
pub(crate) fn by_row_blocks(
    j: &DMatrix<f64>,
    scale: Option<&[f64]>,
    mut f: impl FnMut(usize, &[f64]),
) {
    let (m, n) = j.shape();
    let mut block = vec![0.0; ROW_BLOCK * n];
    let mut start = 0;
    while start < m {
        let b = ROW_BLOCK.min(m - start);
        for k in 0..n {
            let col = &j.as_slice()[k * m + start..k * m + start + b];
            for (t, v) in col.iter().enumerate() {
                block[t * n + k] = v * scale.map_or(1.0, |s| s[start + t]);
            }
        }
        f(start, &block[..b * n]);
        start += b;
    }
}

/// The triangular factor of `j` with row `i` multiplied by `scale[i]`
/// ([`crate::lm::triangular_factor_of`], no copy of `j`).
pub(crate) fn factor_by_rows(j: &DMatrix<f64>, scale: Option<&[f64]>) -> DMatrix<f64> {
    let all: Vec<usize> = (0..j.ncols()).collect();
    crate::lm::triangular_factor_of(j, &all, scale, &vec![0.0; j.nrows()]).0
}

/// `(JᵀJ)⁺` of `j` with row `i` multiplied by `scale[i]`, from its
/// triangular factor.
pub(crate) fn covariance_by_rows(j: &DMatrix<f64>, scale: Option<&[f64]>) -> DMatrix<f64> {
    let mut r = factor_by_rows(j, scale);
    let (ipvt, rdiag, _) = crate::lm::qrfac(&mut r);
    crate::lm::covariance_of(&r, &ipvt, &rdiag, crate::lm::COVARIANCE_RANK_TOL).0
}

/// [`leverages_with`] by blocks of rows: `h_i = j_i C j_iᵀ` with row `i`
/// multiplied by `scale[i]` when given (one product per block, no copy of
/// `j`).
pub(crate) fn leverages_by_rows(
    j: &DMatrix<f64>,
    scale: Option<&[f64]>,
    c: &DMatrix<f64>,
) -> Vec<f64> {
    let n = j.ncols();
    let mut h = Vec::with_capacity(j.nrows());
    by_row_blocks(j, scale, |_, rows| {
        // The block's rows as columns: `C Bᵀ`, then each column's dot with
        // its row.
        let bt = DMatrix::from_column_slice(n, rows.len() / n, rows);
        let cb = c * &bt;
        h.extend(
            bt.column_iter()
                .zip(cb.column_iter())
                .map(|(x, y)| x.dot(&y)),
        );
    });
    h
}
