//! Robust losses (Huber, Cauchy) and the outliers they find: residuals
//! standardised against their own noise group, judged by a threshold.

use crate::error::Origin;
use crate::error::{Error, Result};
use crate::measurement::MeasurementModel;
use crate::measurement::data::Measurement;
use crate::units::Unit;
use serde::Serialize;
use std::collections::BTreeMap;

/// How residuals are penalised (the robust loss; `ρ` is taken by the
/// parameters, hence `Loss`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase", tag = "kind", content = "scale")]
pub enum Loss {
    /// Ordinary least squares.
    Squared,
    /// Huber: quadratic within `k` robust standard deviations, linear beyond
    /// (k = 1.345 gives 95 % efficiency under Gaussian noise).
    Huber(f64),
    /// Cauchy: `log(1 + (u/c)²)` (c = 2.385 gives 95 % efficiency).
    Cauchy(f64),
}

impl Loss {
    /// Huber's default tuning constant (95 % efficiency under Gaussian noise).
    pub const HUBER_DEFAULT: f64 = 1.345;
    /// Cauchy's default tuning constant (95 % efficiency).
    pub const CAUCHY_DEFAULT: f64 = 2.385;

    /// The loss named `squared`, `huber` or `cauchy`, with the tuning
    /// constant `scale` (robust standard deviations; the default when
    /// `None`).
    pub fn named(name: &str, scale: Option<f64>) -> Result<Self> {
        if let Some(k) = scale
            && !(k.is_finite() && k > 0.0)
        {
            return Err(Error::InvalidRequest(format!(
                "the loss scale must be positive, got {k}"
            )));
        }
        match name {
            "squared" | "linear" => Ok(Loss::Squared),
            "huber" => Ok(Loss::Huber(scale.unwrap_or(Self::HUBER_DEFAULT))),
            "cauchy" => Ok(Loss::Cauchy(scale.unwrap_or(Self::CAUCHY_DEFAULT))),
            other => Err(Error::InvalidRequest(format!(
                "loss: unknown `{other}`; use \"squared\", \"huber\" or \"cauchy\""
            ))),
        }
    }

    /// IRLS weight `ψ(u)/u` of a standardised residual `u`.
    pub fn weight(self, u: f64) -> f64 {
        match self {
            Loss::Squared => 1.0,
            Loss::Huber(k) => {
                if u.abs() <= k {
                    1.0
                } else {
                    k / u.abs()
                }
            }
            Loss::Cauchy(c) => 1.0 / (1.0 + (u / c).powi(2)),
        }
    }
}

/// A pose whose residual is far beyond the noise.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct Outlier {
    /// Where the pose came from (pose number, line).
    #[serde(flatten)]
    pub origin: Origin,
    /// Residual vector, predicted minus measured (per measured coordinate).
    pub residual: Vec<f64>,
    /// Unit of each residual.
    pub units: Vec<Unit>,
    /// Largest standardised residual of the pose: `|r/σ|` over its group's
    /// robust scale.
    pub standardized: f64,
}

/// Reweighting rounds of the robust fit.
pub(super) const MAX_REWEIGHTS: usize = 20;

/// Residuals below this (mm) are never outliers: on noise-free data the
/// robust scale is round-off and would flag round-off.
pub const OUTLIER_FLOOR_MM: f64 = 1e-6;
/// [`OUTLIER_FLOOR_MM`] for angles (rad).
pub const OUTLIER_FLOOR_RAD: f64 = 1e-8;

/// Robust scale (1.4826 × median |r/σ|) of each group of residuals.
pub(super) fn group_scales(r: &[f64], sigma: &[f64], keys: &[usize]) -> BTreeMap<usize, f64> {
    let mut scale = BTreeMap::new();
    for &k in keys {
        if scale.contains_key(&k) {
            continue;
        }
        let mut v: Vec<f64> = r
            .iter()
            .zip(sigma)
            .zip(keys)
            .filter(|(_, g)| **g == k)
            .map(|((a, s), _)| (a / s).abs())
            .collect();
        v.sort_by(f64::total_cmp);
        scale.insert(k, 1.4826 * v[v.len() / 2]);
    }
    scale
}

/// `|r/σ| / s_g` with `s_g` the robust scale of the residual's group:
/// lengths and angles are judged each against their own.
pub(super) fn standardized(r: &[f64], sigma: &[f64], keys: &[usize]) -> Vec<f64> {
    let scale = group_scales(r, sigma, keys);
    r.iter()
        .zip(sigma)
        .zip(keys)
        .map(|((a, s), k)| {
            let g = scale[k];
            if g > 0.0 { (a / s).abs() / g } else { 0.0 }
        })
        .collect()
}

pub(super) fn find_outliers(
    measurement: &MeasurementModel,
    data: &[Measurement],
    r: &[f64],
    u: &[f64],
    threshold: f64,
) -> Vec<Outlier> {
    let mut offset = 0;
    data.iter()
        .filter_map(|m| {
            let n = measurement.row_len(m);
            let (ri, ui) = (&r[offset..offset + n], &u[offset..offset + n]);
            offset += n;
            let units: Vec<Unit> = (0..n).map(|a| measurement.row_unit(m, a)).collect();
            let floor = |k: usize| match units[k] {
                Unit::Radian => OUTLIER_FLOOR_RAD,
                _ => OUTLIER_FLOOR_MM,
            };
            let worst = (0..n)
                .filter(|&k| ri[k].abs() > floor(k))
                .map(|k| ui[k])
                .fold(0.0, f64::max);
            (worst > threshold && worst.is_finite()).then(|| Outlier {
                origin: m.origin.expect("numbered"),
                residual: ri.to_vec(),
                units,
                standardized: worst,
            })
        })
        .collect()
}
