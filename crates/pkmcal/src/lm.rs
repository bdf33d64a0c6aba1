//! Levenberg–Marquardt least squares, MINPACK style (Moré 1978; `lmder`,
//! `lmpar`, `qrfac`, `qrsolv`): a scaled trust region solved on the QR
//! factorisation with column pivoting of the Jacobian — never the normal
//! equations — with free/fixed parameter masks, residual weights, optional
//! bounds and a termination reason. Non-convergence is a [`Termination`], not
//! an error.
//!
//! (A long file: the solver and its MINPACK kernels are one job.)
//!
//! Written here because no Rust crate offers masks, bounds, covariance and a
//! rank-revealing QR together (the `levenberg-marquardt` crate has the MINPACK
//! core but neither masks, bounds nor covariance).

use nalgebra::{DMatrix, DVector};
use serde::Serialize;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A least-squares problem: residuals `r(x)` and their Jacobian, evaluated
/// together (one shared inner solve). Implement it to use [`minimize`].
pub trait Problem {
    /// Number of parameters (the full vector, free and fixed).
    fn n_params(&self) -> usize;
    /// Number of residuals.
    fn n_residuals(&self) -> usize;
    /// Residuals at `x`, and the Jacobian (`n_residuals × n_params`, full) when
    /// `jacobian` is true. `Err(reason)` when the model cannot be evaluated at
    /// `x` (the solver then shrinks its step).
    fn evaluate(
        &self,
        x: &[f64],
        jacobian: bool,
    ) -> Result<(DVector<f64>, Option<DMatrix<f64>>), String>;
    /// Residuals at `x` and the Jacobian's `free` columns with row `i`
    /// multiplied by `weights[i]` (the solver's working matrix). By default
    /// from [`Problem::evaluate`]; a problem with many residuals can write
    /// these columns directly, without the full Jacobian (the same numbers).
    fn jacobian_columns(
        &self,
        x: &[f64],
        free: &[usize],
        weights: Option<&[f64]>,
    ) -> Result<(DVector<f64>, DMatrix<f64>), String> {
        let (r, j) = self.evaluate(x, true)?;
        let mut j = j
            .ok_or_else(|| "the Jacobian cannot be evaluated".to_string())?
            .select_columns(free);
        if let Some(w) = weights {
            scale_rows(&mut j, w);
        }
        Ok((r, j))
    }
}

/// Jacobians with at least this many entries (readings × free parameters,
/// about 16 MB) are factorised by blocks of rows ([`triangular_factor`])
/// instead of in a copy: a calibration on tens of thousands of poses then
/// keeps one Jacobian, not three. Smaller ones take MINPACK's `qrfac` on a
/// copy, as they always have (the same numbers).
pub const LARGE_JACOBIAN: usize = 1 << 21;

/// Relative scaled step below which the Jacobian of the previous point is
/// reported as the final one (its change is of this order).
const FINAL_JACOBIAN_STEP: f64 = 1e-9;

/// Most Gauss–Newton steps of the final polish ([`polish`]).
const POLISH_STEPS: usize = 3;
/// Largest polish step relative to the scaled parameter norm: the polish
/// only settles the last digits, it never replaces the trust region.
const POLISH_MAX_STEP: f64 = 1e-6;
/// Relative increase of the sum of squares a polish step may bring (sums
/// of squares that differ by this much are equal to rounding on fits of
/// thousands of residuals).
const POLISH_SLACK: f64 = 1e-10;
/// Scaled polish step (relative) after which a further one would move the
/// point by rounding only.
const POLISH_SETTLED: f64 = 1e-12;
/// Pivots of R below this fraction of the largest give no polish step
/// (directions the data leave undetermined stay where the fit left them).
const POLISH_RANK_TOL: f64 = 1e-12;

/// Options of [`minimize`].
#[derive(Debug, Clone)]
pub struct Options {
    /// Which parameters are free (`None`: all).
    pub free: Option<Vec<bool>>,
    /// Residual weights (`1/σ`); `None`: all 1.
    pub weights: Option<Vec<f64>>,
    /// Lower bounds (full vector); the step is projected onto the box.
    pub lower: Option<Vec<f64>>,
    /// Upper bounds (full vector).
    pub upper: Option<Vec<f64>>,
    /// Relative reduction of the sum of squares below which the fit stops.
    pub ftol: f64,
    /// Relative step size below which the fit stops.
    pub xtol: f64,
    /// Cosine between residuals and Jacobian columns below which the fit stops.
    pub gtol: f64,
    /// Largest number of residual evaluations.
    pub max_evaluations: usize,
    /// Initial trust-region radius factor (MINPACK `factor`).
    pub factor: f64,
    /// Set from another thread to stop the fit before its next evaluation
    /// ([`Termination::Cancelled`]): a calibration fits speculatively while
    /// it analyses identifiability, and stops the fit when the analysis
    /// fixes a parameter.
    pub cancel: Option<Arc<AtomicBool>>,
}

impl Options {
    /// Refuse settings the solver cannot use: a tolerance that is negative
    /// or not a number, no evaluation allowed, or a factor that is not
    /// positive. The error names the setting as this documentation does.
    pub fn check(&self) -> crate::error::Result<()> {
        let bad = |what: &str, v: f64| {
            crate::error::Error::InvalidRequest(format!(
                "the solver's {what} is {v}; give a finite number ≥ 0"
            ))
        };
        for (what, v) in [
            ("ftol", self.ftol),
            ("xtol", self.xtol),
            ("gtol", self.gtol),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(what, v));
            }
        }
        if self.max_evaluations == 0 {
            return Err(crate::error::Error::InvalidRequest(
                "the solver's evaluation budget is 0; allow at least 1 evaluation".into(),
            ));
        }
        if !(self.factor.is_finite() && self.factor > 0.0) {
            return Err(bad("factor", self.factor));
        }
        Ok(())
    }
}

impl Default for Options {
    fn default() -> Self {
        Self {
            free: None,
            weights: None,
            lower: None,
            upper: None,
            ftol: 1e-15,
            xtol: 1e-15,
            gtol: 0.0,
            max_evaluations: 2000,
            factor: 100.0,
            cancel: None,
        }
    }
}

/// Why the solver stopped.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind", content = "detail")]
pub enum Termination {
    /// The sum of squares cannot decrease by more than `ftol` (relative).
    SmallReduction,
    /// The step is below `xtol` relative to the parameters.
    SmallStep,
    /// Both of the above.
    SmallReductionAndStep,
    /// The residuals are orthogonal to the Jacobian columns (within `gtol`).
    SmallGradient,
    /// No further progress is possible at machine precision.
    MachinePrecision,
    /// The evaluation budget ran out.
    MaxEvaluations,
    /// Nothing to fit (no free parameter).
    NothingFree,
    /// The model could not be evaluated at the start.
    EvaluationFailed(String),
    /// Stopped through [`Options::cancel`].
    Cancelled,
}

impl Termination {
    /// True when the solver stopped at a (local) minimum.
    pub fn converged(&self) -> bool {
        matches!(
            self,
            Self::SmallReduction
                | Self::SmallStep
                | Self::SmallReductionAndStep
                | Self::SmallGradient
                | Self::MachinePrecision
                | Self::NothingFree
        )
    }
    /// A readable reason, with a hint where one helps.
    pub fn reason(&self) -> String {
        match self {
            Self::SmallReduction => "converged: the sum of squares no longer decreases".into(),
            Self::SmallStep => "converged: the parameter step is negligible".into(),
            Self::SmallReductionAndStep => {
                "converged: neither the sum of squares nor the parameters change".into()
            }
            Self::SmallGradient => "converged: the gradient vanishes".into(),
            Self::MachinePrecision => "converged to machine precision".into(),
            Self::MaxEvaluations => {
                "stopped: evaluation budget exhausted before convergence; check the data or start closer".into()
            }
            Self::NothingFree => "nothing to fit: no parameter is free".into(),
            Self::Cancelled => "stopped: cancelled by the caller".into(),
            Self::EvaluationFailed(r) => format!(
                "the model cannot be evaluated at the start ({r}); check the data and the starting parameters"
            ),
        }
    }
}

/// The outcome of [`minimize`].
#[derive(Debug, Clone)]
pub struct Report {
    /// Parameters at the end (full vector).
    pub x: Vec<f64>,
    /// Why the solver stopped.
    pub termination: Termination,
    /// Accepted iterations (Jacobian evaluations − 1).
    pub iterations: usize,
    /// Residual evaluations.
    pub evaluations: usize,
    /// Weighted residuals at `x`.
    pub residuals: DVector<f64>,
    /// Weighted sum of squares at `x`.
    pub sum_of_squares: f64,
    /// Weighted Jacobian of the free parameters at `x` (`m × n_free`).
    pub jacobian: DMatrix<f64>,
    /// Indices of the free parameters (columns of `jacobian`).
    pub free: Vec<usize>,
    /// The solver's QR factorisation of `jacobian` when its last one was of
    /// that Jacobian (the usual case: the last step was negligible), for
    /// [`Report::covariance`].
    #[doc(hidden)] // public for the integration tests only
    pub factored: Option<Box<Factored>>,
}

/// A matrix's QR factorisation with column pivoting as [`qrfac`] leaves it.
#[derive(Debug, Clone)]
#[doc(hidden)] // public for the integration tests only
pub struct Factored {
    /// Which matrix was factored ([`fingerprint`]): the report's Jacobian
    /// is not copied to be compared.
    of: Fingerprint,
    /// [`qrfac`]'s output in place of the matrix (`m × n`), or, for a large
    /// Jacobian, in place of its triangular factor (`n × n`,
    /// [`triangular_factor`]): the same `R` but for rounding, without `Q`'s
    /// reflections.
    qr: DMatrix<f64>,
    ipvt: Vec<usize>,
    rdiag: Vec<f64>,
}

/// A matrix's shape and a hash of its entries' bits.
type Fingerprint = (usize, usize, u64);

/// The entries' bits folded by rotate, xor and multiply by an odd constant
/// (FxHash's step: a bijection of the hash for each entry and of each
/// entry for the hash, so that a matrix differing from another in one
/// entry never has its fingerprint). It only tells the fit's own matrices
/// apart, nothing adversarial: SipHash was 1 % of a Monte Carlo run.
fn fingerprint(m: &DMatrix<f64>) -> Fingerprint {
    const K: u64 = 0x517c_c1b7_2722_0a95;
    let h = m.iter().fold(0u64, |h, v| {
        (h.rotate_left(5) ^ v.to_bits()).wrapping_mul(K)
    });
    (m.nrows(), m.ncols(), h)
}

impl Factored {
    /// Whether `qr` holds `R` alone ([`triangular_factor`]).
    #[doc(hidden)] // public for the integration tests only
    pub fn compact(&self) -> bool {
        self.qr.nrows() < self.of.0
    }
}

impl Report {
    /// [`covariance`] of `jacobian`: from the solver's last factorisation
    /// when that was of this Jacobian (the same numbers, one QR fewer),
    /// else by a new one.
    pub fn covariance(&self, tol: f64) -> (DMatrix<f64>, usize) {
        match &self.factored {
            Some(f) if f.of == fingerprint(&self.jacobian) => {
                covariance_of(&f.qr, &f.ipvt, &f.rdiag, tol)
            }
            _ => covariance(&self.jacobian, tol),
        }
    }
}

/// Rows folded at a time by [`triangular_factor`].
#[doc(hidden)] // public for the integration tests only
pub const FOLD_ROWS: usize = 128;

/// The triangular factor `R` (`n × n`, upper) of `a = Q R` (no pivoting)
/// and the first `n` entries of `Qᵀf`, by blocks of rows: each block is
/// folded into the factor of the rows before it by Householder reflections
/// that act on one row of the factor and the block's rows (a sequential
/// TSQR), so that `a` is read, not overwritten, and besides it only `n²`
/// numbers are kept. [`qrfac`] of the factor then pivots it: `a P = Q Q_R R'`.
#[doc(hidden)] // public for the integration tests only
pub fn triangular_factor(a: &DMatrix<f64>, f: &[f64]) -> (DMatrix<f64>, Vec<f64>) {
    let all: Vec<usize> = (0..a.ncols()).collect();
    triangular_factor_of(a, &all, None, f)
}

/// [`triangular_factor`] of `a`'s columns `cols` (in that order), row `i`
/// multiplied by `scale[i]` when given, without copying them out.
pub(crate) fn triangular_factor_of(
    a: &DMatrix<f64>,
    cols: &[usize],
    scale: Option<&[f64]>,
    f: &[f64],
) -> (DMatrix<f64>, Vec<f64>) {
    use rayon::prelude::*;
    let (m, n) = (a.nrows(), cols.len());
    // The rows in parts factorised side by side (each into its own factor,
    // with `Qᵀf` as its last column), then the parts' factors folded into
    // the first's.
    let parts = rayon::current_num_threads().min(m / (8 * FOLD_ROWS)).max(1);
    let per = m.div_ceil(parts);
    let mut factors: Vec<Vec<f64>> = (0..parts)
        .into_par_iter()
        .map(|p| {
            let mut r = vec![0.0; n * (n + 1)];
            let mut block = vec![0.0; FOLD_ROWS * (n + 1)];
            let (mut start, end) = (p * per, ((p + 1) * per).min(m));
            while start < end {
                let b = FOLD_ROWS.min(end - start);
                for k in 0..=n {
                    let dst = &mut block[k * b..(k + 1) * b];
                    if k < n {
                        dst.copy_from_slice(
                            &a.as_slice()[cols[k] * m + start..cols[k] * m + start + b],
                        );
                        if let Some(w) = scale {
                            for (v, wi) in dst.iter_mut().zip(&w[start..start + b]) {
                                *v *= wi;
                            }
                        }
                    } else {
                        dst.copy_from_slice(&f[start..start + b]);
                    }
                }
                fold(&mut r, n, &mut block[..b * (n + 1)], b);
                start += b;
            }
            r
        })
        .collect();
    let mut r = factors.remove(0);
    for mut other in factors {
        // Another part's factor is n rows like any block (its rows, by
        // column).
        let mut block = vec![0.0; n * (n + 1)];
        for k in 0..=n {
            for i in 0..n {
                block[k * n + i] = other[k * n + i];
            }
        }
        other.clear();
        fold(&mut r, n, &mut block, n);
    }
    let r = DMatrix::from_vec(n, n + 1, r);
    let qtf = r.column(n).iter().copied().collect();
    (r.columns(0, n).into_owned(), qtf)
}

/// Fold `b` rows (`block`, column-major `b × (n + 1)`, the last column the
/// right-hand side's) into the triangular factor `r` (`n × (n + 1)`,
/// column-major): for each column `j`, the Householder reflection that
/// zeroes the block's column `j` against `r`'s diagonal entry, applied to
/// `r`'s row `j` and the block's later columns.
fn fold(r: &mut [f64], n: usize, block: &mut [f64], b: usize) {
    for j in 0..n {
        let x0 = r[j * n + j];
        let (head, rest) = block.split_at_mut((j + 1) * b);
        let xs = &head[j * b..];
        let tail = dot(xs, xs);
        if tail == 0.0 {
            continue;
        }
        let norm = (x0 * x0 + tail).sqrt();
        let alpha = if x0 > 0.0 { -norm } else { norm };
        let v0 = x0 - alpha;
        let vtv = v0 * v0 + tail;
        for (t, col) in rest.chunks_exact_mut(b).enumerate() {
            let k = j + 1 + t;
            let c = 2.0 * (v0 * r[k * n + j] + dot(xs, col)) / vtv;
            r[k * n + j] -= c * v0;
            for (y, x) in col.iter_mut().zip(xs) {
                *y -= c * x;
            }
        }
        r[j * n + j] = alpha;
    }
}

/// `Σ a_i b_i` in four lanes.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut lanes = [0.0; 4];
    let (ca, ra) = a.as_chunks::<4>();
    let (cb, rb) = b[..a.len()].as_chunks::<4>();
    for (x, y) in ca.iter().zip(cb) {
        for l in 0..4 {
            lanes[l] += x[l] * y[l];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]) + tail
}

/// The Euclidean norm of each column.
fn column_norms(a: &DMatrix<f64>) -> Vec<f64> {
    (0..a.ncols()).map(|j| a.column(j).norm()).collect()
}

/// [`qrfac_large`]'s factor, `ipvt`, `rdiag`, column norms and `(Qᵀf)[..n]`.
type LargeQr = (DMatrix<f64>, Vec<usize>, Vec<f64>, Vec<f64>, Vec<f64>);

/// [`qrfac`] of a large Jacobian through its triangular factor
/// ([`triangular_factor`]): `R`'s factorisation in place of `a`'s (`n × n`),
/// `ipvt`, `rdiag`, `a`'s column norms, and `(Qᵀf)[..n]`.
fn qrfac_large(a: &DMatrix<f64>, f: &[f64]) -> LargeQr {
    let (mut r, mut qtf) = triangular_factor(a, f);
    let (ipvt, rdiag, _) = qrfac(&mut r);
    apply_qt(&r, &mut qtf);
    (r, ipvt, rdiag, column_norms(a), qtf)
}

/// `(Q₁ᵀ v)[..rank]` of a compact factorisation ([`Factored::compact`]) of
/// `a`, from `a P = Q₁ R`: `Rᵀ (Q₁ᵀ v) = Pᵀ aᵀ v` on the leading `rank`
/// pivots (forward substitution).
fn leading_qt(a: &DMatrix<f64>, f: &Factored, v: &[f64], rank: usize, out: &mut [f64]) {
    let g = a.tr_mul(&DVector::from_column_slice(v));
    for j in 0..rank {
        let mut sum = g[f.ipvt[j]];
        for (i, o) in out[..j].iter().enumerate() {
            sum -= f.qr[(i, j)] * o;
        }
        out[j] = sum / f.rdiag[j];
    }
}

/// Multiply each row `i` of `m` by `w[i]`, column by column (the products
/// of scaling each row, in storage order).
pub(crate) fn scale_rows(m: &mut DMatrix<f64>, w: &[f64]) {
    by_rows(m, w, |v, wi| *v *= wi);
}

/// Divide each row `i` of `m` by `w[i]`, column by column.
pub(crate) fn unscale_rows(m: &mut DMatrix<f64>, w: &[f64]) {
    by_rows(m, w, |v, wi| *v /= wi);
}

/// `op(entry, w[row])` on every entry of `m`, in storage order.
fn by_rows(m: &mut DMatrix<f64>, w: &[f64], op: impl Fn(&mut f64, f64)) {
    let n = m.nrows();
    if n == 0 {
        return;
    }
    for col in m.as_mut_slice().chunks_exact_mut(n) {
        for (v, wi) in col.iter_mut().zip(w) {
            op(v, *wi);
        }
    }
}

fn enorm(v: &[f64]) -> f64 {
    v.iter().map(|a| a * a).sum::<f64>().sqrt()
}

/// Columns whose Householder dot products [`qrfac`] computes side by side.
const BLOCK: usize = 8;

/// QR factorisation with column pivoting (MINPACK `qrfac`). On return `a`
/// holds R in its upper triangle (diagonal in `rdiag`) and the Householder
/// vectors below; `ipvt[j]` is the original column of column j; `acnorm` the
/// original column norms.
#[doc(hidden)] // public for the integration tests only
pub fn qrfac(a: &mut DMatrix<f64>) -> (Vec<usize>, Vec<f64>, Vec<f64>) {
    let (m, n) = a.shape();
    let eps = f64::EPSILON;
    let acnorm: Vec<f64> = (0..n).map(|j| a.column(j).norm()).collect();
    let mut rdiag = acnorm.clone();
    let mut wa = acnorm.clone();
    let mut ipvt: Vec<usize> = (0..n).collect();
    for j in 0..m.min(n) {
        let kmax = (j..n).fold(j, |k, i| if rdiag[i] > rdiag[k] { i } else { k });
        if kmax != j {
            a.swap_columns(j, kmax);
            rdiag[kmax] = rdiag[j];
            wa[kmax] = wa[j];
            ipvt.swap(j, kmax);
        }
        let mut ajnorm = a.view((j, j), (m - j, 1)).norm();
        if ajnorm != 0.0 {
            if a[(j, j)] < 0.0 {
                ajnorm = -ajnorm;
            }
            for i in j..m {
                a[(i, j)] /= ajnorm;
            }
            a[(j, j)] += 1.0;
            // The Householder reflection applied to the later columns, on
            // contiguous column slices (the same operations in the same
            // order as indexed access, without its bounds checks). The dot
            // products of up to eight columns run side by side, each summed
            // in its own order: the same bits, without one long chain of
            // dependent additions.
            let mut recompute = vec![];
            {
                let (left, right) = a.as_mut_slice().split_at_mut((j + 1) * m);
                let v = &left[j * m + j..(j + 1) * m];
                let len = v.len();
                let mut k = j + 1;
                while k < n {
                    let w = (n - k).min(BLOCK);
                    let first = (k - j - 1) * m + j;
                    let mut sums = [0.0f64; BLOCK];
                    {
                        let cols: [&[f64]; BLOCK] = std::array::from_fn(|t| {
                            let s = first + t.min(w - 1) * m;
                            &right[s..s + len]
                        });
                        for (i, x) in v.iter().enumerate() {
                            for t in 0..BLOCK {
                                sums[t] += x * cols[t][i];
                            }
                        }
                    }
                    for (t, sum) in sums.iter().take(w).enumerate() {
                        let col = &mut right[first + t * m..first + t * m + len];
                        let temp = sum / v[0];
                        for (y, x) in col.iter_mut().zip(v) {
                            *y -= temp * x;
                        }
                        let kk = k + t;
                        if rdiag[kk] != 0.0 {
                            let t = col[0] / rdiag[kk];
                            rdiag[kk] *= (1.0 - t * t).max(0.0).sqrt();
                            if 0.05 * (rdiag[kk] / wa[kk]).powi(2) <= eps {
                                recompute.push(kk);
                            }
                        }
                    }
                    k += w;
                }
            }
            for k in recompute {
                rdiag[k] = a.view((j + 1, k), (m - j - 1, 1)).norm();
                wa[k] = rdiag[k];
            }
        }
        rdiag[j] = -ajnorm;
    }
    (ipvt, rdiag, acnorm)
}

/// Solve `min ‖(R; D·Pᵀ... )‖` — MINPACK `qrsolv`: given the upper triangle R
/// of `AP = QR`, the diagonal `diag` and `qtb = Qᵀb`, find `x` minimising
/// `‖A x − b‖² + ‖D x‖²`. The strict lower triangle of `r` receives S's.
fn qrsolv(
    r: &mut DMatrix<f64>,
    ipvt: &[usize],
    diag: &[f64],
    qtb: &[f64],
    x: &mut [f64],
    sdiag: &mut [f64],
) {
    let n = r.ncols();
    let mut wa = qtb[..n].to_vec();
    for j in 0..n {
        for i in j..n {
            r[(i, j)] = r[(j, i)];
        }
        x[j] = r[(j, j)];
    }
    for j in 0..n {
        let l = ipvt[j];
        if diag[l] != 0.0 {
            for s in sdiag.iter_mut().skip(j) {
                *s = 0.0;
            }
            sdiag[j] = diag[l];
            let mut qtbpj = 0.0;
            for k in j..n {
                if sdiag[k] == 0.0 {
                    continue;
                }
                let (sin, cos) = if r[(k, k)].abs() < sdiag[k].abs() {
                    let cotan = r[(k, k)] / sdiag[k];
                    let sin = 0.5 / (0.25 + 0.25 * cotan * cotan).sqrt();
                    (sin, sin * cotan)
                } else {
                    let tan = sdiag[k] / r[(k, k)];
                    let cos = 0.5 / (0.25 + 0.25 * tan * tan).sqrt();
                    (cos * tan, cos)
                };
                r[(k, k)] = cos * r[(k, k)] + sin * sdiag[k];
                let temp = cos * wa[k] + sin * qtbpj;
                qtbpj = -sin * wa[k] + cos * qtbpj;
                wa[k] = temp;
                for i in k + 1..n {
                    let temp = cos * r[(i, k)] + sin * sdiag[i];
                    sdiag[i] = -sin * r[(i, k)] + cos * sdiag[i];
                    r[(i, k)] = temp;
                }
            }
        }
        sdiag[j] = r[(j, j)];
        r[(j, j)] = x[j];
    }
    let mut nsing = n;
    for j in 0..n {
        if sdiag[j] == 0.0 && nsing == n {
            nsing = j;
        }
        if nsing < n {
            wa[j] = 0.0;
        }
    }
    for j in (0..nsing).rev() {
        let mut sum = 0.0;
        for i in j + 1..nsing {
            sum += r[(i, j)] * wa[i];
        }
        wa[j] = (wa[j] - sum) / sdiag[j];
    }
    for j in 0..n {
        x[ipvt[j]] = wa[j];
    }
}

/// `v ← Qᵀ v` by the Householder vectors [`qrfac`] leaves below R in `qr`.
#[doc(hidden)] // public for the integration tests only
pub fn apply_qt(qr: &DMatrix<f64>, v: &mut [f64]) {
    let (m, n) = qr.shape();
    for j in 0..m.min(n) {
        let col = &qr.as_slice()[j * m..(j + 1) * m];
        if col[j] != 0.0 {
            let mut sum = 0.0;
            for (h, vi) in col[j..].iter().zip(&v[j..]) {
                sum += h * vi;
            }
            let temp = -sum / col[j];
            for (h, vi) in col[j..].iter().zip(&mut v[j..]) {
                *vi += h * temp;
            }
        }
    }
}

/// The Levenberg–Marquardt parameter (MINPACK `lmpar`): returns `par` and the
/// step `x` with `‖D x‖ ≈ delta` (or the Gauss–Newton step if shorter).
fn lmpar(
    r: &mut DMatrix<f64>,
    ipvt: &[usize],
    diag: &[f64],
    qtb: &[f64],
    delta: f64,
    mut par: f64,
    x: &mut [f64],
) -> f64 {
    let n = r.ncols();
    let dwarf = f64::MIN_POSITIVE;
    let mut sdiag = vec![0.0; n];
    let mut wa1 = qtb[..n].to_vec();
    let mut nsing = n;
    for j in 0..n {
        if r[(j, j)] == 0.0 && nsing == n {
            nsing = j;
        }
        if nsing < n {
            wa1[j] = 0.0;
        }
    }
    for j in (0..nsing).rev() {
        wa1[j] /= r[(j, j)];
        let temp = wa1[j];
        for i in 0..j {
            wa1[i] -= r[(i, j)] * temp;
        }
    }
    for j in 0..n {
        x[ipvt[j]] = wa1[j];
    }
    let mut wa2: Vec<f64> = (0..n).map(|j| diag[j] * x[j]).collect();
    let mut dxnorm = enorm(&wa2);
    let mut fp = dxnorm - delta;
    if fp <= 0.1 * delta {
        return 0.0;
    }
    let mut parl = 0.0;
    if nsing == n {
        for j in 0..n {
            let l = ipvt[j];
            wa1[j] = diag[l] * (wa2[l] / dxnorm);
        }
        for j in 0..n {
            let mut sum = 0.0;
            for i in 0..j {
                sum += r[(i, j)] * wa1[i];
            }
            wa1[j] = (wa1[j] - sum) / r[(j, j)];
        }
        let temp = enorm(&wa1);
        parl = ((fp / delta) / temp) / temp;
    }
    for j in 0..n {
        let mut sum = 0.0;
        for i in 0..=j {
            sum += r[(i, j)] * qtb[i];
        }
        wa1[j] = sum / diag[ipvt[j]];
    }
    let gnorm = enorm(&wa1);
    let mut paru = gnorm / delta;
    if paru == 0.0 {
        paru = dwarf / delta.min(0.1);
    }
    par = par.max(parl).min(paru);
    if par == 0.0 {
        par = gnorm / dxnorm;
    }
    let mut iter = 0;
    loop {
        iter += 1;
        if par == 0.0 {
            par = dwarf.max(0.001 * paru);
        }
        let temp = par.sqrt();
        for j in 0..n {
            wa1[j] = temp * diag[j];
        }
        qrsolv(r, ipvt, &wa1, qtb, x, &mut sdiag);
        for j in 0..n {
            wa2[j] = diag[j] * x[j];
        }
        dxnorm = enorm(&wa2);
        let temp = fp;
        fp = dxnorm - delta;
        if fp.abs() <= 0.1 * delta || (parl == 0.0 && fp <= temp && temp < 0.0) || iter == 10 {
            return par;
        }
        for j in 0..n {
            let l = ipvt[j];
            wa1[j] = diag[l] * (wa2[l] / dxnorm);
        }
        for j in 0..n {
            wa1[j] /= sdiag[j];
            let temp = wa1[j];
            for i in j + 1..n {
                wa1[i] -= r[(i, j)] * temp;
            }
        }
        let temp = enorm(&wa1);
        let parc = ((fp / delta) / temp) / temp;
        if fp > 0.0 {
            parl = parl.max(par);
        }
        if fp < 0.0 {
            paru = paru.min(par);
        }
        par = parl.max(par + parc);
    }
}

/// A free parameter at a bound that the data push outwards (the gradient
/// of the sum of squares points out of the box) is held there: its Jacobian
/// column is zeroed for the step, as MINPACK-based bounded fits do
/// (Markwardt's MPFIT), so that the step moves the other parameters only and
/// the convergence tests see the directions left free. Without bounds
/// nothing changes. Whether a column was held.
fn hold_pegged<P: Problem>(
    s: &Scaled<'_, P>,
    x: &[f64],
    fvec: &DVector<f64>,
    fjac: &mut DMatrix<f64>,
) -> bool {
    if s.lower.is_none() && s.upper.is_none() {
        return false;
    }
    let mut held = false;
    for (k, &i) in s.free.iter().enumerate() {
        let g = fjac.column(k).dot(fvec);
        let at_lower = s.lower.is_some_and(|l| x[k] <= l[i]);
        let at_upper = s.upper.is_some_and(|u| x[k] >= u[i]);
        if (at_lower && g > 0.0) || (at_upper && g < 0.0) {
            fjac.column_mut(k).fill(0.0);
            held = true;
        }
    }
    held
}

struct Scaled<'a, P: Problem> {
    problem: &'a P,
    x0: Vec<f64>,
    free: Vec<usize>,
    weights: Option<&'a [f64]>,
    lower: Option<&'a [f64]>,
    upper: Option<&'a [f64]>,
    evaluations: usize,
}

impl<P: Problem> Scaled<'_, P> {
    fn full(&self, xf: &[f64]) -> Vec<f64> {
        let mut x = self.x0.clone();
        for (k, &i) in self.free.iter().enumerate() {
            x[i] = xf[k];
        }
        x
    }
    fn project(&self, xf: &mut [f64]) {
        for (k, &i) in self.free.iter().enumerate() {
            if let Some(l) = self.lower {
                xf[k] = xf[k].max(l[i]);
            }
            if let Some(u) = self.upper {
                xf[k] = xf[k].min(u[i]);
            }
        }
    }
    fn eval(
        &mut self,
        xf: &[f64],
        jac: bool,
    ) -> Result<(DVector<f64>, Option<DMatrix<f64>>), String> {
        self.evaluations += 1;
        let x = self.full(xf);
        let (mut r, j) = if jac {
            let (r, j) = self
                .problem
                .jacobian_columns(&x, &self.free, self.weights)?;
            (r, Some(j))
        } else {
            self.problem.evaluate(&x, false)?
        };
        if r.iter().any(|v| !v.is_finite()) {
            return Err("non-finite residual".into());
        }
        if let Some(w) = self.weights {
            for (ri, wi) in r.iter_mut().zip(w) {
                *ri *= wi;
            }
        }
        if let Some(j) = &j
            && j.iter().any(|v| !v.is_finite())
        {
            return Err("non-finite Jacobian".into());
        }
        Ok((r, j))
    }
}

/// Whether an `m × n` Jacobian is factorised by blocks ([`LARGE_JACOBIAN`]):
/// not with bounds, whose held columns change the matrix factorised.
fn is_large<P: Problem>(s: &Scaled<'_, P>, m: usize, n: usize) -> bool {
    m.saturating_mul(n) >= LARGE_JACOBIAN && m >= n && s.lower.is_none() && s.upper.is_none()
}

/// Minimise `Σ (w_i r_i(x))²` over the free parameters, from `x0`.
pub fn minimize<P: Problem>(problem: &P, x0: &[f64], opts: &Options) -> Report {
    let n_all = problem.n_params();
    let free: Vec<usize> = match &opts.free {
        Some(mask) => (0..n_all).filter(|&i| mask[i]).collect(),
        None => (0..n_all).collect(),
    };
    let mut s = Scaled {
        problem,
        x0: x0.to_vec(),
        free: free.clone(),
        weights: opts.weights.as_deref(),
        lower: opts.lower.as_deref(),
        upper: opts.upper.as_deref(),
        evaluations: 0,
    };
    let n = free.len();
    let mut x: Vec<f64> = free.iter().map(|&i| x0[i]).collect();
    s.project(&mut x);
    let finish_factored = |s: &Scaled<P>,
                           x: &[f64],
                           t: Termination,
                           it,
                           r: DVector<f64>,
                           j,
                           factored: Option<Box<Factored>>| Report {
        x: s.full(x),
        termination: t,
        iterations: it,
        evaluations: s.evaluations,
        sum_of_squares: r.norm_squared(),
        residuals: r,
        jacobian: j,
        free: free.clone(),
        factored,
    };
    let finish = |s: &Scaled<P>, x: &[f64], t: Termination, it, r: DVector<f64>, j| {
        finish_factored(s, x, t, it, r, j, None)
    };
    let (mut fvec, _) = match s.eval(&x, false) {
        Ok(v) => v,
        Err(e) => {
            let m = problem.n_residuals();
            return finish(
                &s,
                &x,
                Termination::EvaluationFailed(e),
                0,
                DVector::zeros(m),
                DMatrix::zeros(m, n),
            );
        }
    };
    let m = fvec.len();
    if n == 0 {
        return finish(
            &s,
            &x,
            Termination::NothingFree,
            0,
            fvec,
            DMatrix::zeros(m, 0),
        );
    }
    let eps = f64::EPSILON;
    let mut fnorm = fvec.norm();
    let mut par = 0.0;
    let mut delta = 0.0;
    let mut xnorm = 0.0;
    let mut diag = vec![0.0; n];
    let mut iter = 1;
    let mut wa1 = vec![0.0; n];
    let cancelled = || {
        opts.cancel
            .as_ref()
            .is_some_and(|c| c.load(Ordering::Relaxed))
    };
    let stopped = |s: &Scaled<P>, x: &[f64], iter: usize, fvec| {
        finish(
            s,
            x,
            Termination::Cancelled,
            iter - 1,
            fvec,
            DMatrix::zeros(m, n),
        )
    };
    loop {
        if cancelled() {
            return stopped(&s, &x, iter, fvec);
        }
        // Jacobian at x (recomputed with the residuals: one shared solve).
        let (fv, fjac) = match s.eval(&x, true) {
            Ok((f, Some(j))) => (f, j),
            Ok((_, None)) | Err(_) => {
                return finish(
                    &s,
                    &x,
                    Termination::EvaluationFailed("the Jacobian cannot be evaluated".into()),
                    iter - 1,
                    fvec,
                    DMatrix::zeros(m, n),
                );
            }
        };
        fvec = fv;
        // Scaled length of the step accepted since this Jacobian (to decide
        // whether the final Jacobian must be re-evaluated).
        let mut last_step = 0.0;
        // A large Jacobian is kept as it is and factorised by blocks; a
        // smaller one is copied (for the report) and factorised in place.
        let large = is_large(&s, m, n);
        let (jac_at_x, fjac, held, ipvt, rdiag, acnorm, qtf) = if large {
            let (qr, ipvt, rdiag, acnorm, qtf) = qrfac_large(&fjac, fvec.as_slice());
            (fjac, qr, false, ipvt, rdiag, acnorm, qtf)
        } else {
            let jac_at_x = fjac.clone();
            let mut fjac = fjac;
            // The factorisation of a Jacobian with held columns is not that
            // of the Jacobian reported.
            let held = hold_pegged(&s, &x, &fvec, &mut fjac);
            let (ipvt, rdiag, acnorm) = qrfac(&mut fjac);
            let mut wa4: Vec<f64> = fvec.iter().copied().collect();
            apply_qt(&fjac, &mut wa4);
            let mut qtf = vec![0.0; n];
            qtf[..m.min(n)].copy_from_slice(&wa4[..m.min(n)]);
            (jac_at_x, fjac, held, ipvt, rdiag, acnorm, qtf)
        };
        if iter == 1 {
            for j in 0..n {
                diag[j] = if acnorm[j] == 0.0 { 1.0 } else { acnorm[j] };
            }
            xnorm = enorm(&(0..n).map(|j| diag[j] * x[j]).collect::<Vec<_>>());
            delta = opts.factor * xnorm;
            if delta == 0.0 {
                delta = opts.factor;
            }
        }
        let mut r = DMatrix::zeros(n, n);
        for j in 0..n {
            for i in 0..j.min(m) {
                r[(i, j)] = fjac[(i, j)];
            }
            if j < m {
                r[(j, j)] = rdiag[j];
            }
        }
        // Scaled gradient norm.
        let mut gnorm: f64 = 0.0;
        if fnorm != 0.0 {
            for j in 0..n {
                let l = ipvt[j];
                if acnorm[l] != 0.0 {
                    let mut sum = 0.0;
                    for i in 0..=j {
                        sum += r[(i, j)] * (qtf[i] / fnorm);
                    }
                    gnorm = gnorm.max((sum / acnorm[l]).abs());
                }
            }
        }
        if gnorm <= opts.gtol {
            return finish(&s, &x, Termination::SmallGradient, iter - 1, fvec, jac_at_x);
        }
        for j in 0..n {
            diag[j] = diag[j].max(acnorm[j]);
        }
        loop {
            par = lmpar(&mut r, &ipvt, &diag, &qtf, delta, par, &mut wa1);
            let mut wa2: Vec<f64> = (0..n).map(|j| x[j] - wa1[j]).collect();
            s.project(&mut wa2);
            let step: Vec<f64> = (0..n).map(|j| wa2[j] - x[j]).collect();
            let pnorm = enorm(&(0..n).map(|j| diag[j] * step[j]).collect::<Vec<_>>());
            if iter == 1 {
                delta = delta.min(pnorm);
            }
            if cancelled() {
                return stopped(&s, &x, iter, fvec);
            }
            let trial = s.eval(&wa2, false);
            let (fnorm1, fvec1) = match trial {
                Ok((f, _)) => (f.norm(), Some(f)),
                Err(_) => (f64::INFINITY, None),
            };
            let actred = if 0.1 * fnorm1 < fnorm {
                1.0 - (fnorm1 / fnorm).powi(2)
            } else {
                -1.0
            };
            // Predicted reduction and directional derivative.
            let mut wa3 = vec![0.0; n];
            for j in 0..n {
                let temp = step[ipvt[j]];
                for i in 0..=j {
                    wa3[i] += r[(i, j)] * temp;
                }
            }
            let temp1 = enorm(&wa3) / fnorm;
            let temp2 = par.sqrt() * pnorm / fnorm;
            let prered = temp1 * temp1 + temp2 * temp2 / 0.5;
            let dirder = -(temp1 * temp1 + temp2 * temp2);
            let ratio = if prered != 0.0 { actred / prered } else { 0.0 };
            if ratio <= 0.25 {
                let mut temp = if actred >= 0.0 {
                    0.5
                } else {
                    0.5 * dirder / (dirder + 0.5 * actred)
                };
                if 0.1 * fnorm1 >= fnorm || temp < 0.1 {
                    temp = 0.1;
                }
                delta = temp * delta.min(pnorm / 0.1);
                par /= temp;
            } else if par == 0.0 || ratio >= 0.75 {
                delta = pnorm / 0.5;
                par *= 0.5;
            }
            if ratio >= 1e-4 {
                last_step = pnorm;
                x = wa2;
                xnorm = enorm(&(0..n).map(|j| diag[j] * x[j]).collect::<Vec<_>>());
                fvec = fvec1.expect("accepted steps were evaluated");
                fnorm = fnorm1;
                iter += 1;
            }
            let small_red = actred.abs() <= opts.ftol && prered <= opts.ftol && 0.5 * ratio <= 1.0;
            let small_step = delta <= opts.xtol * xnorm;
            let done = match (small_red, small_step) {
                (true, true) => Some(Termination::SmallReductionAndStep),
                (true, false) => Some(Termination::SmallReduction),
                (false, true) => Some(Termination::SmallStep),
                _ if s.evaluations >= opts.max_evaluations => Some(Termination::MaxEvaluations),
                _ if (actred.abs() <= eps && prered <= eps && 0.5 * ratio <= 1.0)
                    || delta <= eps * xnorm
                    || gnorm <= eps =>
                {
                    Some(Termination::MachinePrecision)
                }
                _ => None,
            };
            if let Some(t) = done {
                // Report the Jacobian at the final point; the one of the
                // previous point serves when the last step was negligible.
                // The factorisation goes with the report (the fit ends here).
                let at_x = move |jac_at_x: DMatrix<f64>| {
                    let f = Factored {
                        of: fingerprint(&jac_at_x),
                        qr: fjac,
                        ipvt,
                        rdiag,
                    };
                    (jac_at_x, (!held).then(|| Box::new(f)))
                };
                let (j, factored) = if last_step <= FINAL_JACOBIAN_STEP * xnorm {
                    at_x(jac_at_x)
                } else {
                    match s.eval(&x, true) {
                        Ok((_, Some(j))) => {
                            s.evaluations -= 1;
                            let (qr, ipvt, rdiag) = if large {
                                let (qr, ipvt, rdiag, ..) = qrfac_large(&j, fvec.as_slice());
                                (qr, ipvt, rdiag)
                            } else {
                                let mut qr = j.clone();
                                let (ipvt, rdiag, _) = qrfac(&mut qr);
                                (qr, ipvt, rdiag)
                            };
                            let f = Factored {
                                of: fingerprint(&j),
                                qr,
                                ipvt,
                                rdiag,
                            };
                            (j, Some(Box::new(f)))
                        }
                        _ => at_x(jac_at_x),
                    }
                };
                if t.converged()
                    && let Some(f) = &factored
                {
                    polish(&mut s, f, &j, &diag, &mut x, &mut fvec, opts);
                }
                return finish_factored(&s, &x, t, iter - 1, fvec, j, factored);
            }
            if ratio >= 1e-4 {
                break;
            }
        }
    }
}

/// The final polish of a converged fit: up to [`POLISH_STEPS`] Gauss–Newton
/// steps `x ← x − J⁺ r(x)` on the last Jacobian's factorisation, each kept
/// when it is small ([`POLISH_MAX_STEP`]) and the sum of squares does not
/// grow beyond rounding ([`POLISH_SLACK`]).
///
/// The trust region stops when sums of squares no longer tell points apart,
/// which in a fit's weakest directions happens up to `√ε·cond(J)` (relative)
/// from the minimum: two builds whose arithmetic differs in the last bit
/// stop at different points there. The Gauss–Newton step is computed from
/// the gradient `Jᵀr`, which is accurate to `ε·cond(J)`, so the polished
/// point is the minimum to that precision, whichever way the fit came.
fn polish<P: Problem>(
    s: &mut Scaled<P>,
    f: &Factored,
    jacobian: &DMatrix<f64>,
    diag: &[f64],
    x: &mut Vec<f64>,
    fvec: &mut DVector<f64>,
    opts: &Options,
) {
    let (m, n) = jacobian.shape();
    let k = m.min(n);
    let r11 = f.rdiag.first().map_or(0.0, |v| v.abs());
    let rank = (0..k)
        .take_while(|&j| f.rdiag[j].abs() > POLISH_RANK_TOL * r11)
        .count();
    if rank == 0 {
        return;
    }
    let mut ss = fvec.norm_squared();
    let mut qtf = vec![0.0; m];
    let mut z = vec![0.0; n];
    for _ in 0..POLISH_STEPS {
        if opts
            .cancel
            .as_ref()
            .is_some_and(|c| c.load(Ordering::Relaxed))
        {
            return;
        }
        if f.compact() {
            leading_qt(jacobian, f, fvec.as_slice(), rank, &mut qtf);
        } else {
            qtf.copy_from_slice(fvec.as_slice());
            apply_qt(&f.qr, &mut qtf);
        }
        // R₁₁ z = (Qᵀr)₁ on the well-determined pivots, zero on the rest.
        z.fill(0.0);
        for j in (0..rank).rev() {
            let mut sum = qtf[j];
            for (l, zl) in z.iter().enumerate().take(rank).skip(j + 1) {
                sum -= f.qr[(j, l)] * zl;
            }
            z[j] = sum / f.rdiag[j];
        }
        let mut trial = x.clone();
        for j in 0..rank {
            trial[f.ipvt[j]] -= z[j];
        }
        s.project(&mut trial);
        let xnorm = enorm(&(0..n).map(|j| diag[j] * x[j]).collect::<Vec<_>>());
        let pnorm = enorm(
            &(0..n)
                .map(|j| diag[j] * (trial[j] - x[j]))
                .collect::<Vec<_>>(),
        );
        if pnorm == 0.0 || pnorm > POLISH_MAX_STEP * xnorm {
            return;
        }
        let Ok((r1, _)) = s.eval(&trial, false) else {
            return;
        };
        let ss1 = r1.norm_squared();
        if ss1.is_nan() || ss1 > ss * (1.0 + POLISH_SLACK) {
            return;
        }
        *x = trial;
        *fvec = r1;
        ss = ss1;
        if pnorm <= POLISH_SETTLED * xnorm {
            return;
        }
    }
}

/// The pivot test of every covariance ([`covariance`]): pivots below this
/// fraction of the largest count as zero. The identifiability decision
/// ([`crate::identify::RANK_TOL`], on the column-scaled Jacobian) chooses
/// which parameters are free; this test, on the unscaled Jacobian, lies far
/// below it and only guards against exact zeros, so that a parameter the
/// decision keeps is never dropped for its unit's size.
pub const COVARIANCE_RANK_TOL: f64 = 1e-14;

/// Covariance factor `(JᵀJ)⁻¹` of the free parameters from the weighted
/// Jacobian, by QR with column pivoting (MINPACK `covar`): columns whose
/// pivot falls below `tol·|R₁₁|` are rank-deficient and get zero rows and
/// columns. Returns the matrix and the numerical rank.
pub fn covariance(jacobian: &DMatrix<f64>, tol: f64) -> (DMatrix<f64>, usize) {
    let mut a = jacobian.clone();
    let (ipvt, rdiag, _) = qrfac(&mut a);
    covariance_of(&a, &ipvt, &rdiag, tol)
}

/// [`covariance`] from [`qrfac`]'s factorisation of the Jacobian.
pub(crate) fn covariance_of(
    a: &DMatrix<f64>,
    ipvt: &[usize],
    rdiag: &[f64],
    tol: f64,
) -> (DMatrix<f64>, usize) {
    let n = a.ncols();
    let mut r = DMatrix::zeros(n, n);
    for j in 0..n {
        for i in 0..j.min(a.nrows()) {
            r[(i, j)] = a[(i, j)];
        }
        if j < a.nrows() {
            r[(j, j)] = rdiag[j];
        }
    }
    let r11 = r.get((0, 0)).map_or(0.0, |v| v.abs());
    let rank = (0..n).take_while(|&j| r[(j, j)].abs() > tol * r11).count();
    let mut cov = DMatrix::zeros(n, n);
    if rank > 0 {
        let rr = r.view((0, 0), (rank, rank)).into_owned();
        if let Some(rinv) = rr.solve_upper_triangular(&DMatrix::identity(rank, rank)) {
            let c = &rinv * rinv.transpose();
            for a in 0..rank {
                for b in 0..rank {
                    cov[(ipvt[a], ipvt[b])] = c[(a, b)];
                }
            }
        }
    }
    (cov, rank)
}
