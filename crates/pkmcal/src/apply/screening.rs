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
//! the same formula without keeping the result. Rounding accumulates over
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
pub(crate) struct Screen {
    n: usize,
    nx: usize,
    /// `n × (candidates · nx)`, column-major: column `j·nx + s` is
    /// `M⁻¹ a_{j,s}` for row `s` of candidate `j`.
    yt: Vec<f64>,
    /// `G_j` per candidate.
    g: Vec<Block>,
    /// Updates since the state was computed afresh.
    pub(crate) updates: usize,
}

/// Most rows a candidate may have for the kept screen (a spatial tool's
/// six coordinates; more use the fresh screen).
pub(crate) const MAX_ROWS: usize = 8;

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

/// `C_j = A_j M⁻¹ A_kᵀ` (`nx × MAX_ROWS`, row-major, into `cj`) for
/// candidate `j` from its kept `Y_j` and pose `k`'s columns `ak`
/// ([`columns_of`]): the eight products of a column side by side.
fn cross(y: &[f64], ak: &[f64], n: usize, nx: usize, cj: &mut [[f64; MAX_ROWS]; MAX_ROWS]) {
    let (ak, _) = ak.as_chunks::<MAX_ROWS>();
    for (s, out) in cj.iter_mut().enumerate().take(nx) {
        let mut acc = [0.0; MAX_ROWS];
        for (yv, a) in y[s * n..(s + 1) * n].iter().zip(ak) {
            for r in 0..MAX_ROWS {
                acc[r] += yv * a[r];
            }
        }
        *out = acc;
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
fn log_det_plus_identity(g: &Block, nx: usize) -> f64 {
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
    pub(crate) fn fresh(c: &Candidates, m: &DMatrix<f64>, reg: f64) -> Option<Self> {
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
        })
    }

    /// The gain `log det(I + G_j)` of every candidate not in `chosen`.
    pub(crate) fn gains(&self, chosen: &[usize]) -> Vec<(f64, usize)> {
        self.g
            .par_iter()
            .enumerate()
            .filter(|(j, _)| !chosen.contains(j))
            .map(|(j, g)| (log_det_plus_identity(g, self.nx), j))
            .collect()
    }

    /// `(I + σ G_k)⁻¹` for pose `k`, `sign` σ = ±1, padded with zeros;
    /// `None` when not positive definite (a pose whose removal leaves a
    /// direction to the ridge alone).
    fn kernel(&self, k: usize, sign: f64) -> Option<Block> {
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
    pub(crate) fn gains_without(
        &self,
        c: &Candidates,
        k: usize,
        chosen: &[usize],
    ) -> Option<Vec<(f64, usize)>> {
        let (n, nx) = (self.n, self.nx);
        let kernel = self.kernel(k, -1.0)?;
        let ak = columns_of(c, k, nx, n);
        let gains = self
            .yt
            .par_chunks(n * nx)
            .zip(self.g.par_iter())
            .enumerate()
            .filter(|(j, _)| !chosen.contains(j))
            .map(|(j, (y, g))| {
                let mut cj = [[0.0; MAX_ROWS]; MAX_ROWS];
                cross(y, &ak, n, nx, &mut cj);
                // G_j + C_j K C_jᵀ
                let mut e = [[0.0; MAX_ROWS]; MAX_ROWS];
                small_product(&cj, &kernel, nx, 1.0, &mut e);
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
            .collect();
        Some(gains)
    }

    /// Follow `M ← M + σ A_kᵀA_k` (`sign` σ = ±1) for every candidate;
    /// `false` (the state then unusable) when the update cannot be formed
    /// stably.
    pub(crate) fn update(&mut self, c: &Candidates, k: usize, sign: f64) -> bool {
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
        self.yt.iter().all(|v| v.is_finite())
    }
}

/// The `keep` candidates with the largest gains (ties: the smallest index).
pub(crate) fn shortlist(mut gains: Vec<(f64, usize)>, keep: usize) -> Vec<usize> {
    gains.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    gains.into_iter().take(keep).map(|(_, i)| i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    /// Agreement of kept gains with gains computed afresh (relative to the
    /// gain, plus an absolute part for gains near 0).
    const GAIN_TOL: f64 = 1e-9;

    fn candidates(seed: u64, count: usize, nx: usize, n: usize) -> Candidates {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let rows = (0..count)
            .map(|_| {
                DMatrix::from_fn(nx, n, |_, j| {
                    let g: f64 = StandardNormal.sample(&mut rng);
                    g * 10f64.powi(j as i32 % 3 - 1)
                })
            })
            .collect();
        Candidates {
            points: vec![],
            rows,
        }
    }

    /// `log det(I + A (m + reg·I)⁻¹ Aᵀ)` of every candidate, directly.
    fn direct(c: &Candidates, m: &DMatrix<f64>, reg: f64) -> Vec<f64> {
        let n = m.nrows();
        let inv = (m + DMatrix::identity(n, n) * reg)
            .try_inverse()
            .expect("positive definite");
        c.rows
            .iter()
            .map(|a| {
                let s = DMatrix::identity(a.nrows(), a.nrows()) + a * &inv * a.transpose();
                s.determinant().ln()
            })
            .collect()
    }

    fn info(c: &Candidates, set: &[usize], n: usize) -> DMatrix<f64> {
        let mut m = DMatrix::zeros(n, n);
        for &i in set {
            m += c.rows[i].transpose() * &c.rows[i];
        }
        m
    }

    fn assert_gains(kept: &[(f64, usize)], expected: &[f64], what: &str) {
        for &(g, j) in kept {
            let e = expected[j];
            assert!(
                (g - e).abs() <= GAIN_TOL * (1.0 + e.abs()),
                "{what}: candidate {j}: kept {g}, fresh {e}"
            );
        }
    }

    /// Gains kept through additions and removals (an exchange's swaps) are
    /// those computed afresh, and the gains without a chosen pose are those
    /// of the information without it.
    #[test]
    fn kept_gains_follow_additions_and_removals() {
        let (nx, n) = (6, 20);
        let c = candidates(3, 150, nx, n);
        let reg = 1e-9;
        let mut set: Vec<usize> = (0..8).map(|k| 3 * k).collect();
        let mut kept = Screen::fresh(&c, &info(&c, &set, n), reg).expect("positive definite");
        assert_gains(
            &kept.gains(&set),
            &direct(&c, &info(&c, &set, n), reg),
            "fresh",
        );
        for step in 0..12 {
            if step % 3 == 2 {
                let out = set.remove(step % set.len());
                assert!(kept.update(&c, out, -1.0));
            } else {
                let add = 100 + 4 * step;
                assert!(kept.update(&c, add, 1.0));
                set.push(add);
            }
            let m = info(&c, &set, n);
            assert_gains(&kept.gains(&set), &direct(&c, &m, reg), "kept");
            let k = set[1];
            let without = &m - c.rows[k].transpose() * &c.rows[k];
            let g = kept.gains_without(&c, k, &set).expect("stable");
            assert_gains(&g, &direct(&c, &without, reg), "without");
            assert_eq!(g.len(), c.rows.len() - set.len());
        }
        assert_eq!(kept.updates, 12);
    }

    /// The shortlist from kept gains is the fresh screen's (the planning's
    /// own, one triangular solve per candidate).
    #[test]
    fn kept_shortlist_is_the_fresh_screens() {
        let (nx, n) = (6, 24);
        let c = candidates(9, 300, nx, n);
        let reg = 1e-9;
        let mut set: Vec<usize> = (0..6).collect();
        let mut kept = Screen::fresh(&c, &info(&c, &set, n), reg).expect("positive definite");
        for add in [40, 41, 77, 150] {
            assert!(kept.update(&c, add, 1.0));
            set.push(add);
        }
        let m = info(&c, &set, n);
        let keep = super::super::planning::SCREENED;
        assert_eq!(
            shortlist(kept.gains(&set), keep),
            super::super::planning::screen(&c, &m, reg, &set)
        );
        let without = &m - c.rows[40].transpose() * &c.rows[40];
        assert_eq!(
            shortlist(kept.gains_without(&c, 40, &set).expect("stable"), keep),
            super::super::planning::screen(&c, &without, reg, &set)
        );
    }

    /// Candidates of another shape, or more rows than a block holds, are
    /// left to the fresh screen.
    #[test]
    fn shapes_it_cannot_keep_are_refused() {
        let n = 5;
        let m = DMatrix::identity(n, n);
        assert!(Screen::fresh(&candidates(1, 10, MAX_ROWS + 1, n), &m, 1e-9).is_none());
        let mut c = candidates(1, 10, 3, n);
        c.rows[4] = DMatrix::zeros(2, n);
        assert!(Screen::fresh(&c, &m, 1e-9).is_none());
        assert!(Screen::fresh(&candidates(1, 10, 3, n), &(-m), 1e-9).is_none());
    }
}
