//! The D-optimal screen of a plan's candidates, kept up to date by low-rank
//! updates as poses join and leave the plan (Fedorov's exchange algorithm,
//! as the optimal-design literature does it).
//!
//! For the regularised information `M` of the chosen poses and a candidate's
//! rows `A_j` (`nx × n`), the screen ranks candidates by their D-optimal
//! gain `log det(I + G_j)` with `G_j = A_j M⁻¹ A_jᵀ`. A fresh screen costs a
//! triangular solve per candidate (`n²·nx`); here `Y_j = A_j M⁻¹` and `G_j`
//! are kept for every candidate and follow each change `M ± A_kᵀA_k` by the
//! Sherman–Morrison–Woodbury formula, `nx²·n` per candidate: with
//! `K = (I ± G_k)⁻¹` and `C_j = A_j M⁻¹ A_kᵀ`,
//!
//! ```text
//! Y_j ← Y_j ∓ C_j K A_k M⁻¹,    G_j ← G_j ∓ C_j K C_jᵀ.
//! ```
//!
//! The gain of a candidate once pose `k` has left (an exchange's question) is
//! the same formula without keeping the result. Only the candidates that can
//! be among the shortlisted need it: with `μ` the largest eigenvalue of
//! `G_k`, `M − A_kᵀA_k ≽ (1 − μ) M`, so each gain without pose `k` lies
//! between `log det(I + G_j)` and `log det(I + G_j / (1 − μ))`, and a
//! candidate whose upper end is below the shortlist's lowest lower end is
//! left out unread ([`Screen::shortlist_without`]). Rounding accumulates over
//! updates, so the state is computed afresh every [`REFRESH_UPDATES`]
//! updates and at every exchange pass; the screen only shortlists (the
//! criterion itself is scored exactly on the shortlist), so its last digits
//! do not decide a plan.

use super::planning::Candidates;

use nalgebra::DMatrix;
use rayon::prelude::*;

/// Updates after which the kept state is computed afresh: each update adds
/// a rounding error of about `ε · cond(M)` relative to the gains.
pub(crate) const REFRESH_UPDATES: usize = 32;

/// Candidates per parallel chunk.
const CHUNK: usize = 64;

/// The kept screen: for every candidate `j`, `Y_j = A_j M⁻¹` (stored
/// transposed, `nx` columns of length `n` each) and `G_j = A_j M⁻¹ A_jᵀ`.
#[doc(hidden)] // public for the integration tests only
pub struct Screen {
    n: usize,
    nx: usize,
    /// `n × (candidates · nx)`, column-major: column `j·nx + s` is
    /// `M⁻¹ a_{j,s}` for row `s` of candidate `j`.
    yt: Vec<f64>,
    /// `G_j` per candidate.
    #[doc(hidden)] // public for the integration tests only
    pub g: Vec<Block>,
    /// Updates since the state was computed afresh.
    #[doc(hidden)] // public for the integration tests only
    pub updates: usize,
    /// `log det(I + G_j)` and `trace G_j` of every candidate, for the
    /// current state (computed when first asked for).
    gain_trace: std::sync::OnceLock<Vec<(f64, f64)>>,
}

/// Relative margin on the bounds of [`Screen::shortlist_without`]: the kept
/// `Y_j` and `G_j` agree to about 1e-12 of the gains (rounding of the
/// updates), so a candidate is left out only when its bound is below the
/// threshold by far more than that.
const BOUND_MARGIN: f64 = 1e-6;

/// Most rows a candidate may have for the kept screen (a spatial tool's
/// six coordinates; more use the fresh screen).
#[doc(hidden)] // public for the integration tests only
pub const MAX_ROWS: usize = 8;

/// Pose `k`'s rows by column, padded to [`MAX_ROWS`]: `ak[c·MAX_ROWS + r]`
/// is row `r`, column `c`.
fn columns_of(c: &Candidates, k: usize, nx: usize, n: usize) -> Vec<f64> {
    let a = c.rows[k].as_slice();
    let mut ak = vec![0.0; n * MAX_ROWS];
    for col in 0..n {
        ak[col * MAX_ROWS..col * MAX_ROWS + nx].copy_from_slice(&a[col * nx..(col + 1) * nx]);
    }
    ak
}

/// `C_j = A_j M⁻¹ A_kᵀ` (`nx × nx` of a `MAX_ROWS` block, row-major, into
/// `cj`) for candidate `j` from its kept `Y_j` and pose `k`'s columns `ak`
/// ([`columns_of`]). Each entry is summed over the `n` parameters in their
/// order; rows are taken three at a time, so that the sums of a row do not
/// wait on one another (the same sums, in the same order, as one row at a
/// time).
fn cross(y: &[f64], ak: &[f64], n: usize, nx: usize, cj: &mut Block) {
    match nx {
        1 => cross_rows::<1>(y, ak, n, cj),
        2 => cross_rows::<2>(y, ak, n, cj),
        3 => cross_rows::<3>(y, ak, n, cj),
        4 => cross_rows::<4>(y, ak, n, cj),
        5 => cross_rows::<5>(y, ak, n, cj),
        6 => cross_rows::<6>(y, ak, n, cj),
        7 => cross_rows::<7>(y, ak, n, cj),
        _ => cross_rows::<MAX_ROWS>(y, ak, n, cj),
    }
}

/// [`cross`] for `NX` rows (each row's loop on its own, which the compiler
/// turns into vector operations).
fn cross_rows<const NX: usize>(y: &[f64], ak: &[f64], n: usize, cj: &mut Block) {
    let (ak, _) = ak.as_chunks::<MAX_ROWS>();
    let ak = &ak[..n];
    let row = |a: &[f64; MAX_ROWS]| -> [f64; NX] {
        let mut out = [0.0; NX];
        out.copy_from_slice(&a[..NX]);
        out
    };
    let mut s = 0;
    while s + 3 <= NX {
        let (y0, y1, y2) = (
            &y[s * n..(s + 1) * n],
            &y[(s + 1) * n..(s + 2) * n],
            &y[(s + 2) * n..(s + 3) * n],
        );
        let (mut c0, mut c1, mut c2) = ([0.0; NX], [0.0; NX], [0.0; NX]);
        for (((a, v0), v1), v2) in ak.iter().zip(y0).zip(y1).zip(y2) {
            let a = row(a);
            for r in 0..NX {
                c0[r] += v0 * a[r];
            }
            for r in 0..NX {
                c1[r] += v1 * a[r];
            }
            for r in 0..NX {
                c2[r] += v2 * a[r];
            }
        }
        cj[s][..NX].copy_from_slice(&c0);
        cj[s + 1][..NX].copy_from_slice(&c1);
        cj[s + 2][..NX].copy_from_slice(&c2);
        s += 3;
    }
    while s < NX {
        let mut c0 = [0.0; NX];
        for (a, v0) in ak.iter().zip(&y[s * n..(s + 1) * n]) {
            let a = row(a);
            for r in 0..NX {
                c0[r] += v0 * a[r];
            }
        }
        cj[s][..NX].copy_from_slice(&c0);
        s += 1;
    }
}

/// `E = σ C K` and `G ∓= E Cᵀ`-style products of the small blocks:
/// `out[s][q] = f · Σ_r a[s][r] b[r][q]` for `s, q, r < nx`.
fn small_product(
    a: &[[f64; MAX_ROWS]; MAX_ROWS],
    b: &[[f64; MAX_ROWS]; MAX_ROWS],
    nx: usize,
    f: f64,
    out: &mut [[f64; MAX_ROWS]; MAX_ROWS],
) {
    for s in 0..nx {
        let mut acc = [0.0; MAX_ROWS];
        for r in 0..nx {
            let v = a[s][r];
            for q in 0..MAX_ROWS {
                acc[q] += v * b[r][q];
            }
        }
        for q in 0..MAX_ROWS {
            out[s][q] = f * acc[q];
        }
    }
}

/// A candidate's `nx × nx` block, padded to [`MAX_ROWS`].
type Block = [[f64; MAX_ROWS]; MAX_ROWS];

/// `log det(I + g)` of a symmetric `nx × nx` block by Cholesky; 0 when
/// `I + g` is not positive definite (rounding), as the fresh screen does.
#[doc(hidden)] // public for the integration tests only
pub fn log_det_plus_identity(g: &Block, nx: usize) -> f64 {
    let mut l = *g;
    for (i, row) in l.iter_mut().enumerate().take(nx) {
        row[i] += 1.0;
    }
    let mut sum = 0.0;
    for j in 0..nx {
        let (above, below) = l.split_at_mut(j + 1);
        let lj = &mut above[j];
        let d = lj[j] - lj[..j].iter().map(|v| v * v).sum::<f64>();
        if !(d > 0.0 && d.is_finite()) {
            return 0.0;
        }
        sum += d.ln();
        let d = d.sqrt();
        lj[j] = d;
        for li in below.iter_mut().take(nx - j - 1) {
            let v = li[j]
                - li[..j]
                    .iter()
                    .zip(&lj[..j])
                    .map(|(a, b)| a * b)
                    .sum::<f64>();
            li[j] = v / d;
        }
    }
    sum
}

impl Screen {
    /// The screen of every candidate against `m + reg·I`, computed afresh;
    /// `None` when that matrix is not positive definite, or the candidates'
    /// shapes differ or have more than [`MAX_ROWS`] rows.
    #[doc(hidden)] // public for the integration tests only
    pub fn fresh(c: &Candidates, m: &DMatrix<f64>, reg: f64) -> Option<Self> {
        let n = m.nrows();
        let nx = c.rows.first()?.nrows();
        if nx == 0 || nx > MAX_ROWS || c.rows.iter().any(|a| a.nrows() != nx || a.ncols() != n) {
            return None;
        }
        let mut mr = m.clone();
        for i in 0..n {
            mr[(i, i)] += reg;
        }
        let chol = mr.cholesky()?;
        let nc = c.rows.len();
        let mut yt = vec![0.0; n * nx * nc];
        let mut g = vec![[[0.0; MAX_ROWS]; MAX_ROWS]; nc];
        yt.par_chunks_mut(n * nx * CHUNK)
            .zip(g.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(chunk, (yt, g))| {
                let first = chunk * CHUNK;
                let mut b = DMatrix::zeros(n, nx * g.len());
                for t in 0..g.len() {
                    let a = &c.rows[first + t];
                    for s in 0..nx {
                        b.column_mut(t * nx + s).copy_from(&a.row(s).transpose());
                    }
                }
                chol.solve_mut(&mut b);
                yt.copy_from_slice(b.as_slice());
                for (t, gt) in g.iter_mut().enumerate() {
                    let ak = columns_of(c, first + t, nx, n);
                    let mut cj = [[0.0; MAX_ROWS]; MAX_ROWS];
                    cross(&yt[t * nx * n..(t + 1) * nx * n], &ak, n, nx, &mut cj);
                    // Symmetric by construction; symmetrised against rounding.
                    for s in 0..nx {
                        for u in 0..nx {
                            gt[s][u] = 0.5 * (cj[s][u] + cj[u][s]);
                        }
                    }
                }
            });
        if yt.iter().any(|v| !v.is_finite()) {
            return None;
        }
        Some(Self {
            n,
            nx,
            yt,
            g,
            updates: 0,
            gain_trace: std::sync::OnceLock::new(),
        })
    }

    /// `log det(I + G_j)` and `trace G_j` of every candidate.
    fn gain_trace(&self) -> &[(f64, f64)] {
        self.gain_trace.get_or_init(|| {
            let nx = self.nx;
            self.g
                .par_iter()
                .map(|g| (log_det_plus_identity(g, nx), (0..nx).map(|s| g[s][s]).sum()))
                .collect()
        })
    }

    /// The gain `log det(I + G_j)` of every candidate not in `chosen`.
    #[doc(hidden)] // public for the integration tests only
    pub fn gains(&self, chosen: &[usize]) -> Vec<(f64, usize)> {
        let taken = taken(self.g.len(), chosen);
        self.gain_trace()
            .iter()
            .enumerate()
            .filter(|(j, _)| !taken[*j])
            .map(|(j, &(gain, _))| (gain, j))
            .collect()
    }

    /// `(I + σ G_k)⁻¹` for pose `k`, `sign` σ = ±1, padded with zeros;
    /// `None` when not positive definite (a pose whose removal leaves a
    /// direction to the ridge alone).
    #[doc(hidden)] // public for the integration tests only
    pub fn kernel(&self, k: usize, sign: f64) -> Option<Block> {
        let nx = self.nx;
        let a = DMatrix::from_fn(nx, nx, |s, t| {
            sign * self.g[k][s][t] + if s == t { 1.0 } else { 0.0 }
        });
        let inv = a.cholesky()?.inverse();
        let mut out = [[0.0; MAX_ROWS]; MAX_ROWS];
        for s in 0..nx {
            for t in 0..nx {
                out[s][t] = inv[(s, t)];
            }
        }
        out.iter().flatten().all(|v| v.is_finite()).then_some(out)
    }

    /// The gain of every candidate not in `chosen` against the information
    /// without pose `k` (`M − A_kᵀA_k`), the state unchanged; `None` when
    /// that cannot be formed stably.
    #[doc(hidden)] // public for the integration tests only
    pub fn gains_without(
        &self,
        c: &Candidates,
        k: usize,
        chosen: &[usize],
    ) -> Option<Vec<(f64, usize)>> {
        let taken = taken(self.g.len(), chosen);
        let pool: Vec<usize> = (0..self.g.len()).filter(|&j| !taken[j]).collect();
        let kernel = self.kernel(k, -1.0)?;
        Some(self.gains_without_of(c, k, &kernel, &pool))
    }

    /// The `keep` candidates not in `chosen` with the largest gains against
    /// the information without pose `k` (ties: the smallest index): the
    /// shortlist of [`Screen::gains_without`], reading `Y_j` only for the
    /// candidates whose bounds (module doc) let them be among it. `None`
    /// when the information without pose `k` cannot be formed stably.
    #[doc(hidden)] // public for the integration tests only
    pub fn shortlist_without(
        &self,
        c: &Candidates,
        k: usize,
        chosen: &[usize],
        keep: usize,
    ) -> Option<Vec<usize>> {
        let nx = self.nx;
        let kernel = self.kernel(k, -1.0)?;
        let taken = taken(self.g.len(), chosen);
        let bounds = self.gain_trace();
        let mut lower: Vec<(f64, usize)> = bounds
            .iter()
            .enumerate()
            .filter(|(j, _)| !taken[*j])
            .map(|(j, &(gain, _))| (gain, j))
            .collect();
        // `1 / (1 − μ)` is the largest eigenvalue of the kernel `(I − G_k)⁻¹`.
        let k_block = DMatrix::from_fn(nx, nx, |s, t| kernel[s][t]);
        let f = k_block
            .symmetric_eigenvalues()
            .iter()
            .copied()
            .fold(1.0_f64, f64::max);
        let usable = lower.iter().all(|e| e.0.is_finite()) && f.is_finite();
        let pool: Vec<usize> = if keep > 0 && keep < lower.len() && usable {
            // The shortlist's gains are at least its lower bounds' `keep`-th
            // largest: a candidate whose upper bound is below that is not in
            // it. Upper bounds: `log(1 + fλ) − log(1 + λ) ≤ (f − 1)λ` summed
            // over `G_j`'s eigenvalues, then `log det(I + f G_j)` itself.
            let order = |a: &(f64, usize), b: &(f64, usize)| b.0.total_cmp(&a.0);
            let (_, tau, _) = lower.select_nth_unstable_by(keep - 1, order);
            let tau = tau.0;
            let cut = tau - BOUND_MARGIN * (1.0 + tau.abs());
            lower
                .par_iter()
                .filter(|&&(gain, j)| {
                    gain >= cut
                        || (gain + (f - 1.0) * bounds[j].1 >= cut && {
                            let mut gf = self.g[j];
                            for row in gf.iter_mut().take(nx) {
                                for v in row.iter_mut().take(nx) {
                                    *v *= f;
                                }
                            }
                            log_det_plus_identity(&gf, nx) >= cut
                        })
                })
                .map(|&(_, j)| j)
                .collect()
        } else {
            lower.iter().map(|&(_, j)| j).collect()
        };
        Some(shortlist(self.gains_without_of(c, k, &kernel, &pool), keep))
    }

    /// The gain against the information without pose `k` (its `kernel`
    /// `(I − G_k)⁻¹`) of each candidate of `pool`, in parallel.
    fn gains_without_of(
        &self,
        c: &Candidates,
        k: usize,
        kernel: &Block,
        pool: &[usize],
    ) -> Vec<(f64, usize)> {
        let (n, nx) = (self.n, self.nx);
        let ak = columns_of(c, k, nx, n);
        pool.par_iter()
            .map(|&j| {
                let (y, g) = (&self.yt[j * n * nx..(j + 1) * n * nx], &self.g[j]);
                let mut cj = [[0.0; MAX_ROWS]; MAX_ROWS];
                cross(y, &ak, n, nx, &mut cj);
                // G_j + C_j K C_jᵀ
                let mut e = [[0.0; MAX_ROWS]; MAX_ROWS];
                small_product(&cj, kernel, nx, 1.0, &mut e);
                let mut gm = *g;
                for s in 0..nx {
                    for t in 0..nx {
                        let mut v = 0.0;
                        for q in 0..nx {
                            v += e[s][q] * cj[t][q];
                        }
                        gm[s][t] += v;
                    }
                }
                (log_det_plus_identity(&gm, nx), j)
            })
            .collect()
    }

    /// Follow `M ← M + σ A_kᵀA_k` (`sign` σ = ±1) for every candidate;
    /// `false` (the state then unusable) when the update cannot be formed
    /// stably.
    #[doc(hidden)] // public for the integration tests only
    pub fn update(&mut self, c: &Candidates, k: usize, sign: f64) -> bool {
        let (n, nx) = (self.n, self.nx);
        let Some(kernel) = self.kernel(k, sign) else {
            return false;
        };
        let ak = columns_of(c, k, nx, n);
        // W = M⁻¹ A_kᵀ (`nx` columns of length `n`), taken before the
        // update changes pose k's own state.
        let w = self.yt[k * nx * n..(k + 1) * nx * n].to_vec();
        self.yt
            .par_chunks_mut(n * nx)
            .zip(self.g.par_iter_mut())
            .for_each(|(y, g)| {
                let mut cj = [[0.0; MAX_ROWS]; MAX_ROWS];
                cross(y, &ak, n, nx, &mut cj);
                let mut e = [[0.0; MAX_ROWS]; MAX_ROWS];
                small_product(&cj, &kernel, nx, sign, &mut e);
                // Y_j ← Y_j − E Wᵀ: row s less Σ_q E[s][q] w_q.
                for s in 0..nx {
                    let ys = &mut y[s * n..(s + 1) * n];
                    for q in 0..nx {
                        let f = e[s][q];
                        for (v, wq) in ys.iter_mut().zip(&w[q * n..(q + 1) * n]) {
                            *v -= f * wq;
                        }
                    }
                }
                // G_j ← G_j − E C_jᵀ
                for s in 0..nx {
                    for t in 0..nx {
                        let mut v = 0.0;
                        for q in 0..nx {
                            v += e[s][q] * cj[t][q];
                        }
                        g[s][t] -= v;
                    }
                }
            });
        self.updates += 1;
        self.gain_trace = std::sync::OnceLock::new();
        self.yt.iter().all(|v| v.is_finite())
    }
}

/// The `keep` candidates with the largest gains (ties: the smallest index),
/// largest first.
#[doc(hidden)] // public for the integration tests only
pub fn shortlist(mut gains: Vec<(f64, usize)>, keep: usize) -> Vec<usize> {
    let order = |a: &(f64, usize), b: &(f64, usize)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
    // A total order (the indices differ): the first `keep` are the same
    // whichever way they are found.
    if keep < gains.len() {
        gains.select_nth_unstable_by(keep, order);
        gains.truncate(keep);
    }
    gains.sort_unstable_by(order);
    gains.into_iter().map(|(_, i)| i).collect()
}

/// Whether each of `count` candidates is in `chosen` (a lookup for the
/// loops over every candidate).
pub(crate) fn taken(count: usize, chosen: &[usize]) -> Vec<bool> {
    let mut taken = vec![false; count];
    for &i in chosen {
        if let Some(t) = taken.get_mut(i) {
            *t = true;
        }
    }
    taken
}
