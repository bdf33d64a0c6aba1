//! Measurement planning: choose the poses that make the free parameters most
//! observable (greedy selection, then DETMAX-style exchange), on the
//! information matrix `M = Σ AᵀA` of column-scaled identification Jacobians.

use crate::apply::screening::{REFRESH_UPDATES, Screen, shortlist, taken};
use crate::apply::workspace::WorkspacePoint;
use crate::engine::models::{Model, prepare_pose};
use crate::engine::sensitivity::sensitivity;
use crate::error::{Error, Result};
use crate::identify::{Observability, observability};
use crate::mechanism::{Mechanism, Params};
use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::Serialize;

/// Most lattice points over the workspace box that `plan` evaluates as
/// candidates: a finer `--candidates` spacing is coarsened to respect it
/// ([`crate::engine::atlas::lattice_spacing`]), so planning time is bounded.
pub const MAX_CANDIDATE_LATTICE: usize = 20_000;

/// The observability index a plan maximises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum PlanCriterion {
    /// Product of the singular values (D-optimal).
    O1,
    /// Smallest singular value (E-optimal).
    O3,
    /// Inverse of the summed inverse singular values.
    O5,
}

impl std::str::FromStr for PlanCriterion {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_uppercase().as_str() {
            "O1" => Ok(Self::O1),
            "O3" => Ok(Self::O3),
            "O5" => Ok(Self::O5),
            _ => Err(Error::InvalidRequest(format!(
                "unknown criterion `{s}`; use O1, O3 or O5"
            ))),
        }
    }
}

/// Column-scaled identification Jacobians of candidate poses.
pub struct Candidates {
    /// The candidate poses.
    pub points: Vec<WorkspacePoint>,
    /// Per candidate, `nx × n_free` rows of the scaled Jacobian.
    pub rows: Vec<DMatrix<f64>>,
}

/// Identification Jacobians (free columns, scaled to unit norm over all
/// candidates) of every candidate pose, at `params` with `model`.
pub fn candidate_jacobians<M: Mechanism>(
    mech: &M,
    points: Vec<WorkspacePoint>,
    params: &Params,
    model: Model,
    free: &[usize],
) -> Result<Candidates> {
    Ok(scaled_candidates(mech, points, params, model, free)?.0)
}

/// [`candidate_jacobians`] and each column's norm over all candidates (the
/// scale taken out).
fn scaled_candidates<M: Mechanism>(
    mech: &M,
    points: Vec<WorkspacePoint>,
    params: &Params,
    model: Model,
    free: &[usize],
) -> Result<(Candidates, Vec<f64>)> {
    let spec = mech.spec();
    let raw: Vec<Result<DMatrix<f64>>> = points
        .par_iter()
        .map(|p| {
            let commands: Vec<f64> = spec.actuated.iter().map(|&j| p.q[j]).collect();
            let pose = prepare_pose(mech, &commands, Some(&p.q))?;
            Ok(sensitivity(mech, &pose, params, model, &[])?
                .jacobian
                .select_columns(free))
        })
        .collect();
    let raw: Vec<DMatrix<f64>> = raw.into_iter().collect::<Result<_>>()?;
    let mut norms = vec![0.0; free.len()];
    for a in &raw {
        for (k, n) in norms.iter_mut().enumerate() {
            *n += a.column(k).norm_squared();
        }
    }
    let rows = raw
        .into_iter()
        .map(|mut a| {
            for (k, n) in norms.iter().enumerate() {
                if *n > 0.0 {
                    a.column_mut(k).unscale_mut(n.sqrt());
                }
            }
            a
        })
        .collect();
    let scale = norms.iter().map(|n| n.sqrt()).collect();
    Ok((Candidates { points, rows }, scale))
}

/// The [`SCREENED`] candidates (not in `chosen`) with the largest D-optimal
/// gain `log det(I + A (M + reg·I)⁻¹ Aᵀ)`, in parallel.
#[doc(hidden)] // public for the integration tests only
pub fn screen(c: &Candidates, m: &DMatrix<f64>, reg: f64, chosen: &[usize]) -> Vec<usize> {
    let n = m.nrows();
    let mut mr = m.clone();
    for i in 0..n {
        mr[(i, i)] += reg;
    }
    let taken = taken(c.rows.len(), chosen);
    let Some(chol) = mr.cholesky() else {
        return (0..c.rows.len()).filter(|&i| !taken[i]).collect();
    };
    let l = chol.l();
    let gains: Vec<(f64, usize)> = (0..c.rows.len())
        .into_par_iter()
        .filter(|&i| !taken[i])
        .map(|i| {
            let a = &c.rows[i];
            let b = l
                .solve_lower_triangular(&a.transpose())
                .unwrap_or_else(|| DMatrix::zeros(n, a.nrows()));
            let s = DMatrix::identity(a.nrows(), a.nrows()) + b.transpose() * b;
            let gain = s.cholesky().map_or(0.0, |c| {
                c.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum::<f64>()
            });
            (gain, i)
        })
        .collect();
    shortlist(gains, SCREENED)
}

fn singular_values(m: &DMatrix<f64>) -> Vec<f64> {
    let mut ev: Vec<f64> = m
        .clone()
        .symmetric_eigenvalues()
        .iter()
        .map(|e| e.max(0.0).sqrt())
        .collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    ev
}

#[doc(hidden)] // public for the integration tests only
pub fn score(m: &DMatrix<f64>, reg: f64, criterion: PlanCriterion) -> f64 {
    let mut mr = m.clone();
    for i in 0..mr.nrows() {
        mr[(i, i)] += reg;
    }
    criterion_of(&singular_values(&mr), criterion)
}

/// The first-order expansion at `M + reg·I` of one criterion, which bounds
/// every candidate's score from above ([`score_bound`]), and the relative
/// rounding margin of those bounds.
#[doc(hidden)] // public for the integration tests only
pub struct Tangent {
    criterion: PlanCriterion,
    /// The expanded function at `M + reg·I`.
    #[doc(hidden)] // public for the integration tests only
    pub base: f64,
    /// Its derivative along `v_j v_jᵀ` for each eigenvector `v_j`.
    slope: Vec<f64>,
    /// The eigenvectors, by column.
    vectors: DMatrix<f64>,
    #[doc(hidden)] // public for the integration tests only
    pub margin: f64,
}

/// Rounding margin per unit of `n × ε × condition`: the computed eigenvalues
/// of a symmetric matrix are within a small multiple of `n ε ‖M‖` of the
/// true ones.
const BOUND_ROUNDING: f64 = 100.0;

/// Each criterion is a monotone function of `f(M)`, with `f` concave
/// (`Σ ln λ` for O1, `λ_min` for O3) or convex (`Σ λ^{-1/2}` for O5) in the
/// information matrix; its tangent `f(M) + ⟨∇f(M), AᵀA⟩ = f(M) + Σ_j
/// slope_j ‖A v_j‖²` therefore bounds the score of `M + AᵀA` from above.
#[doc(hidden)] // public for the integration tests only
pub fn tangent(m: &DMatrix<f64>, reg: f64, criterion: PlanCriterion) -> Option<Tangent> {
    let n = m.nrows();
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let mut mr = m.clone();
    for i in 0..n {
        mr[(i, i)] += reg;
    }
    let eig = mr.symmetric_eigen();
    let l = &eig.eigenvalues;
    let (lo, hi) = l.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), &v| {
        (lo.min(v), hi.max(v))
    });
    if !(lo > 0.0 && hi.is_finite()) {
        return None;
    }
    let (base, slope) = match criterion {
        PlanCriterion::O1 => (
            l.iter().map(|v| v.ln()).sum(),
            l.iter().map(|v| 1.0 / v).collect(),
        ),
        PlanCriterion::O3 => (
            lo,
            l.iter().map(|&v| if v == lo { 1.0 } else { 0.0 }).collect(),
        ),
        PlanCriterion::O5 => (
            l.iter().map(|v| 1.0 / v.sqrt()).sum(),
            l.iter().map(|v| -0.5 / (v * v.sqrt())).collect(),
        ),
    };
    Some(Tangent {
        criterion,
        base,
        slope,
        vectors: eig.eigenvectors,
        margin: 1e-10 + BOUND_ROUNDING * n as f64 * f64::EPSILON * hi / lo,
    })
}

/// The tangent's value `f(X) + ⟨∇f(X), AᵀA⟩` for a candidate's rows `A`:
/// one small product per candidate instead of an eigendecomposition.
#[doc(hidden)] // public for the integration tests only
pub fn tangent_value(t: &Tangent, a: &DMatrix<f64>) -> f64 {
    let (nx, n) = a.shape();
    let a = a.as_slice();
    let mut f = t.base;
    for (&s, v) in t.slope.iter().zip(t.vectors.as_slice().chunks_exact(n)) {
        if s == 0.0 {
            continue;
        }
        let mut w = 0.0;
        for r in 0..nx {
            let d: f64 = a[r..].iter().step_by(nx).zip(v).map(|(x, y)| x * y).sum();
            w += d * d;
        }
        f += s * w;
    }
    f
}

/// The upper bound of the score that the tangent gives a candidate.
#[doc(hidden)] // public for the integration tests only
pub fn score_bound(t: &Tangent, a: &DMatrix<f64>) -> f64 {
    let f = tangent_value(t, a);
    match t.criterion {
        PlanCriterion::O1 => 0.5 * f,
        PlanCriterion::O3 => f.sqrt(),
        PlanCriterion::O5 if f > 0.0 => 1.0 / f,
        PlanCriterion::O5 => f64::INFINITY,
    }
}

/// Candidate `i`'s information matrix `AᵀA`, formed where it is used from
/// its rows (the same product, so the same numbers, as a stored one).
fn information(c: &Candidates, i: usize) -> DMatrix<f64> {
    c.rows[i].transpose() * &c.rows[i]
}

/// Most candidates scored exactly in one parallel batch.
const MAX_BATCH: usize = 256;

/// Times the bounds are tightened by a tangent at the best candidate so far.
const BOUND_REFINEMENTS: usize = 3;

/// The candidate of `pool` whose addition to `m` scores best (ties: the
/// smallest index). Candidates are scored exactly in order of their upper
/// bound ([`score_bound`]) until the next bound is below the best exact
/// score (less a rounding margin): the same choice as scoring every
/// candidate, with a few eigendecompositions instead of thousands. Also
/// returns how many candidates were scored exactly.
///
/// With a `floor` (an exchange's question: does any candidate beat the
/// current plan?) candidates whose bound is below it are not scored: the
/// answer is the best when that scores at least `floor`, and may be `None`
/// or a candidate below `floor` otherwise.
#[doc(hidden)] // public for the integration tests only
pub fn best_of(
    c: &Candidates,
    m: &DMatrix<f64>,
    reg: f64,
    criterion: PlanCriterion,
    pool: Vec<usize>,
    floor: Option<f64>,
) -> (Option<(f64, usize)>, usize) {
    let order = |a: &(f64, usize), b: &(f64, usize)| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1));
    let exact = |i: usize| (score(&(m + &information(c, i)), reg, criterion), i);
    let Some(t) = tangent(m, reg, criterion) else {
        let count = pool.len();
        return (pool.into_par_iter().map(exact).max_by(order), count);
    };
    let mut ranked: Vec<(f64, usize)> = pool
        .into_par_iter()
        .map(|i| (score_bound(&t, &c.rows[i]), i))
        .collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut batch = 2 * rayon::current_num_threads();
    let mut margin = t.margin;
    let mut best: Option<(f64, usize)> = None;
    let (mut next, mut refined) = (0, 0);
    while next < ranked.len() {
        // Below the best so far, or below the floor, less the margin (`x −
        // margin·|x|` grows with `x`: the best is never cut by a floor below
        // it).
        let cut = match (best, floor) {
            (Some((s, _)), Some(f)) => Some(s.max(f)),
            (Some((s, _)), None) => Some(s),
            (None, f) => f,
        };
        if let Some(s) = cut
            && ranked[next].0 < s - margin * s.abs()
        {
            break;
        }
        let chunk = &ranked[next..(next + batch).min(ranked.len())];
        next += chunk.len();
        // Growing batches: a few exact scores when the bounds are tight, few
        // parallel dispatches when they are not.
        batch = (2 * batch).min(MAX_BATCH);
        let top = chunk.par_iter().map(|&(_, i)| exact(i)).max_by(order);
        let before = best;
        best = match (best, top) {
            (Some(b), Some(x)) => Some(if order(&x, &b).is_gt() { x } else { b }),
            (b, x) => b.or(x),
        };
        // A tangent at `M + A_bᵀA_b` (the best so far) bounds the rest too,
        // shifted by its value at the best; it is tight for the candidates
        // near the best, the ones the tangent at `M` cannot rule out.
        if let Some((_, b)) = best
            && before.map(|x| x.1) != Some(b)
            && refined < BOUND_REFINEMENTS
            && ranked.len() - next > batch
            && let Some(mut t2) = tangent(&(m + &information(c, b)), reg, criterion)
        {
            refined += 1;
            t2.base -= tangent_value(&t2, &c.rows[b]) - t2.base;
            margin = margin.max(t2.margin);
            let (s, _) = best.unwrap_or((f64::INFINITY, 0));
            let s = floor.map_or(s, |f| s.max(f));
            let live = ranked[next..].partition_point(|e| e.0 >= s - margin * s.abs());
            ranked[next..next + live]
                .par_iter_mut()
                .for_each(|e| e.0 = e.0.min(score_bound(&t2, &c.rows[e.1])));
            // Sorted again as a whole, so that the first bound below the
            // threshold ends the search whatever the margin becomes.
            ranked[next..].sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        }
    }
    (best, next)
}

/// A singular value of the column-scaled identification Jacobian below this
/// fraction of the largest counts as an undetermined direction: the
/// information matrix `Σ AᵀA` squares the condition, so its eigenvalues
/// below 1e-14 of the largest are rounding.
pub const PLAN_RANK_TOL: f64 = 1e-7;

/// Number of parameter directions a set of candidates determines
/// ([`PLAN_RANK_TOL`]).
pub fn plan_rank(c: &Candidates, set: &[usize]) -> usize {
    rank_of(&set_singular_values(c, set))
}

/// Observability of a set of candidates (indices into `c`).
pub fn plan_observability(c: &Candidates, set: &[usize]) -> (Observability, f64) {
    observability_of(&set_singular_values(c, set), set.len())
}

/// The singular values (largest first) of a set's column-scaled
/// identification Jacobian, from its information matrix.
fn set_singular_values(c: &Candidates, set: &[usize]) -> Vec<f64> {
    let n = c.rows[0].ncols();
    prior_singular_values(c, set, &DMatrix::zeros(n, n))
}

/// [`set_singular_values`] with the information `prior` added.
fn prior_singular_values(c: &Candidates, set: &[usize], prior: &DMatrix<f64>) -> Vec<f64> {
    let mut m = prior.clone();
    for &i in set {
        m += c.rows[i].transpose() * &c.rows[i];
    }
    singular_values(&m)
}

/// The planning criterion of an information matrix's singular values (as
/// [`score`] without its ridge).
fn criterion_of(sv: &[f64], criterion: PlanCriterion) -> f64 {
    match criterion {
        PlanCriterion::O1 => sv.iter().map(|s| s.ln()).sum(),
        PlanCriterion::O3 => sv.last().copied().unwrap_or(0.0),
        PlanCriterion::O5 => 1.0 / sv.iter().map(|s| 1.0 / s).sum::<f64>(),
    }
}

/// Directions above [`PLAN_RANK_TOL`] of the largest singular value.
fn rank_of(sv: &[f64]) -> usize {
    let top = sv.first().copied().unwrap_or(0.0);
    sv.iter().filter(|&&s| s > PLAN_RANK_TOL * top).count()
}

/// Observability indices and condition number of `poses` poses' singular
/// values.
fn observability_of(sv: &[f64], poses: usize) -> (Observability, f64) {
    let cond = match (sv.first(), sv.last()) {
        (Some(a), Some(b)) if *b > 0.0 => a / b,
        _ => f64::INFINITY,
    };
    (observability(sv, poses), cond)
}

/// Work (about `candidates × parameters³ × poses`) up to which every
/// candidate is scored exactly at every step; beyond it each step scores
/// exactly only the [`SCREENED`] candidates with the largest information
/// gain `log det(I + A M⁻¹ Aᵀ)` (kept up to date by low-rank updates,
/// `crate::apply::screening`), so that planning a 6-DOF platform with 56
/// parameters takes a second or two, not hours.
pub const EXHAUSTIVE_WORK: f64 = 2e9;
/// Candidates scored exactly per step when screening.
pub const SCREENED: usize = 24;

/// Choose `count` candidates maximising `criterion`: greedy selection, then
/// exchanges (swap a chosen pose for a candidate while that improves the
/// criterion), as DETMAX does. Returns candidate indices.
pub fn plan_poses(c: &Candidates, count: usize, criterion: PlanCriterion) -> Result<Vec<usize>> {
    plan_poses_with_progress(c, count, criterion, &|| {})
}

/// [`plan_poses`], calling `tick` after each greedy step and each exchange
/// position (`count × (1 + passes)` ticks).
pub fn plan_poses_with_progress(
    c: &Candidates,
    count: usize,
    criterion: PlanCriterion,
    tick: &(dyn Fn() + Sync),
) -> Result<Vec<usize>> {
    let n = c.rows[0].ncols();
    let steps = |_: usize, _: usize| tick();
    crate::on_pool(|| {
        choose(
            c,
            count,
            criterion,
            &steps,
            None,
            &DMatrix::zeros(n, n),
            None,
        )
    })
}

/// [`plan_poses_with_progress`] on the calling thread, stopping with
/// [`Error::Cancelled`] at the next step once `cancel` is set; with `start`,
/// the exchanges start from those candidates instead of a greedy selection.
/// `tick(done, foreseen)` after each greedy step and exchange position: the
/// steps done and those foreseen (the greedy steps and one exchange pass,
/// then, each time a pass improved the plan, the positions not yet tried
/// against the improved plan).
#[doc(hidden)] // public for the integration tests only
pub fn choose(
    c: &Candidates,
    count: usize,
    criterion: PlanCriterion,
    tick: &(dyn Fn(usize, usize) + Sync),
    cancel: Option<&std::sync::atomic::AtomicBool>,
    prior: &DMatrix<f64>,
    start: Option<&[usize]>,
) -> Result<Vec<usize>> {
    let nc = c.rows.len();
    if count == 0 || count > nc {
        return Err(Error::InvalidRequest(format!(
            "cannot choose {count} poses from {nc} candidates; use a finer candidate spacing or fewer poses"
        )));
    }
    let n = c.rows[0].ncols();
    // A tiny ridge keeps the criterion defined while the set is rank deficient
    // (`trace AᵀA` is the squared Frobenius norm of `A`). Each candidate's
    // information `AᵀA` is formed where it is used, not kept: kept, it would
    // take candidates × parameters² numbers (3.6 GB for a 48-leg platform).
    let reg = 1e-9 * (0..nc).map(|i| information(c, i).trace()).sum::<f64>() / (nc * n) as f64;
    let mut chosen: Vec<usize> = start.map_or_else(Vec::new, <[usize]>::to_vec);
    // What is known before any pose (the priors' information, or nothing),
    // and what the starting poses add.
    let mut m = prior.clone();
    for &i in &chosen {
        m += &information(c, i);
    }
    let screening = (nc as f64) * (n as f64).powi(3) * count as f64 > EXHAUSTIVE_WORK;
    // When screening, the candidates' D-optimal gains are kept up to date by
    // low-rank updates ([`Screen`]) once the chosen poses have as many rows
    // as parameters; before that the ridge alone bounds `M⁻¹` in some
    // directions, where updates would lose digits, and each step screens
    // afresh.
    let rows = c.rows[0].nrows();
    let mut kept: Option<Screen> = None;
    let fresh_if_due = |kept: &mut Option<Screen>, m: &DMatrix<f64>| {
        if kept.as_ref().is_none_or(|s| s.updates >= REFRESH_UPDATES) {
            *kept = Screen::fresh(c, m, reg);
        }
    };
    let unchosen = |chosen: &[usize]| {
        let taken = taken(nc, chosen);
        (0..nc).filter(|&i| !taken[i]).collect()
    };
    let (mut done, mut foreseen) = (0, count - chosen.len().min(count) + count);
    while chosen.len() < count {
        crate::error::check_cancel(cancel)?;
        let pool: Vec<usize> = if !screening {
            unchosen(&chosen)
        } else if chosen.len() * rows >= n {
            fresh_if_due(&mut kept, &m);
            match &kept {
                Some(s) => shortlist(s.gains(&chosen), SCREENED),
                None => screen(c, &m, reg, &chosen),
            }
        } else {
            screen(c, &m, reg, &chosen)
        };
        let (_, i) = best_of(c, &m, reg, criterion, pool, None)
            .0
            .expect("enough candidates");
        m += &information(c, i);
        chosen.push(i);
        if let Some(s) = kept.as_mut()
            && !s.update(c, i, 1.0)
        {
            kept = None;
        }
        done += 1;
        tick(done, foreseen);
    }
    let mut current = score(&m, reg, criterion);
    // Positions tried in a row without an exchange.
    let mut unchanged = 0;
    for pass in 0..EXCHANGE_PASSES {
        let mut improved = false;
        // The positions tried since the last exchange were tried against
        // this same plan: the exchanges end once every position has been
        // (Fedorov's rule), a pass earlier than a pass of no exchange. They
        // are foreseen again only if an exchange comes first.
        let mut spare = 0;
        if pass > 0 {
            spare = unchanged.min(count);
            foreseen += count - spare;
        }
        // Each pass starts from a fresh screen (the updates' rounding reset).
        kept = None;
        for k in 0..chosen.len() {
            if unchanged >= chosen.len() {
                break;
            }
            crate::error::check_cancel(cancel)?;
            let without = &m - &information(c, chosen[k]);
            let pool: Vec<usize> = if screening {
                fresh_if_due(&mut kept, &m);
                kept.as_ref()
                    .and_then(|s| s.shortlist_without(c, chosen[k], &chosen, SCREENED))
                    .unwrap_or_else(|| screen(c, &without, reg, &chosen))
            } else {
                unchosen(&chosen)
            };
            // Only a candidate above the current plan's score can be taken.
            let floor = current * (1.0 + 1e-12) + 1e-300;
            if let Some((s, i)) = best_of(c, &without, reg, criterion, pool, Some(floor)).0
                && s > floor
            {
                if let Some(st) = kept.as_mut()
                    && !(st.update(c, chosen[k], -1.0) && st.update(c, i, 1.0))
                {
                    kept = None;
                }
                m = without + &information(c, i);
                chosen[k] = i;
                current = s;
                improved = true;
                unchanged = 0;
                foreseen += std::mem::take(&mut spare);
            } else {
                unchanged += 1;
            }
            done += 1;
            tick(done, foreseen);
        }
        if !improved {
            break;
        }
    }
    Ok(chosen)
}

/// Most exchange passes (each tries every chosen position once).
pub const EXCHANGE_PASSES: usize = 20;

/// Settings of [`plan`].
#[derive(Debug, Clone)]
pub struct PlanOptions {
    /// Poses to choose.
    pub count: usize,
    /// The observability index maximised.
    pub criterion: PlanCriterion,
    /// Forward model of the identification Jacobians.
    pub model: Model,
    /// Indices of the parameters to identify.
    pub free: Vec<usize>,
    /// Wanted candidate lattice spacing (mm; angle axes scaled by the
    /// mechanism's work scale); coarsened to stay within four lattice points
    /// per allowed candidate and [`MAX_CANDIDATE_LATTICE`].
    pub spacing: f64,
    /// Most candidates scored: a larger lattice is thinned evenly.
    pub max_candidates: usize,
    /// Priors (tolerances) of the mechanism's parameters: the plan is then
    /// optimal given what they already tell, its poses measured with
    /// `noise` (docs/model.md eq. 13). Empty: the plain information of the
    /// poses.
    pub priors: Vec<crate::identify::Prior>,
    /// The instrument's noise the poses are weighed with against the priors
    /// (unused without priors).
    pub noise: crate::measurement::data::Noise,
    /// Set from another thread to stop the planning at its next step
    /// ([`Error::Cancelled`]); `None` for none.
    pub cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
}

/// A measurement plan and how it compares with a plain grid of the same size.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The chosen poses, in the candidates' (lattice) order: the same set
    /// gives the same file, whichever path the selection took.
    pub poses: Vec<WorkspacePoint>,
    /// Observability of the chosen poses and the condition number of their
    /// column-scaled identification Jacobian.
    pub observability: Observability,
    /// Condition number of the chosen poses.
    pub condition: f64,
    /// A plain grid of `count` poses ([`crate::apply::workspace::grid_targets`]).
    pub grid: Vec<WorkspacePoint>,
    /// Observability of the grid, with the same column scaling.
    pub grid_observability: Observability,
    /// Condition number of the grid.
    pub grid_condition: f64,
    /// Number of free-parameter directions the chosen poses determine
    /// (singular values of the column-scaled identification Jacobian above
    /// [`PLAN_RANK_TOL`] of the largest); below the number of free
    /// parameters, the plan leaves some unidentified.
    pub rank: usize,
    /// Number of free parameters.
    pub free: usize,
    /// What the user should know: a plan that leaves directions
    /// undetermined ([`crate::identify::WarningKind::PlanRankDeficient`]).
    pub warnings: Vec<crate::identify::Warning>,
    /// Lattice spacing used (mm).
    pub spacing: f64,
    /// Usable lattice points before thinning.
    pub lattice_points: usize,
    /// Candidates scored.
    pub candidates: usize,
}

/// Whether `count` poses of `axes` tool coordinates each can determine
/// `free` parameters (more coordinates than parameters); the error says how
/// many to plan.
pub fn check_count(count: usize, axes: usize, free: usize) -> Result<()> {
    if count.saturating_mul(axes) <= free {
        return Err(Error::InvalidRequest(format!(
            "{count} poses give too few coordinates for {free} free parameters; plan at least {}",
            free / axes.max(1) + 1
        )));
    }
    Ok(())
}

/// Plan `opts.count` poses over the mechanism's usable workspace at
/// `params`: candidates on a lattice ([`crate::apply::workspace::sample_workspace`]),
/// thinned evenly to `opts.max_candidates`, chosen by [`plan_poses`];
/// `tick(done, foreseen)` is called after each greedy step and exchange
/// position with the steps done and those foreseen so far (the greedy steps
/// and one exchange pass; each time a pass improves the plan, the positions
/// not yet tried against the improved plan; and the exchanges again from
/// the plain grid where the plan ends below it).
pub fn plan<M: Mechanism>(
    mech: &M,
    params: &Params,
    opts: &PlanOptions,
    tick: &(dyn Fn(usize, usize) + Sync),
) -> Result<Plan> {
    let spec = mech.spec();
    check_count(opts.count, spec.tool_axes.len(), opts.free.len())?;
    if !(opts.spacing.is_finite() && opts.spacing > 0.0) {
        return Err(Error::InvalidRequest(format!(
            "the candidate spacing must be a positive length in mm, got {}",
            opts.spacing
        )));
    }
    if opts.max_candidates == 0 {
        return Err(Error::InvalidRequest(
            "the number of candidates must be at least 1".into(),
        ));
    }
    let spacing = crate::engine::atlas::lattice_spacing(
        spec,
        opts.spacing,
        MAX_CANDIDATE_LATTICE.min(opts.max_candidates.saturating_mul(4)),
    );
    let mut points = crate::apply::workspace::sample_workspace(mech, spacing);
    let lattice_points = points.len();
    if points.len() > opts.max_candidates {
        points = crate::engine::atlas::thin_evenly(points.len(), opts.max_candidates)
            .into_iter()
            .map(|k| points[k].clone())
            .collect();
    }
    let candidates = points.len();
    // The plain grid of the same size, judged with the same column scaling.
    points.extend(crate::apply::workspace::grid_targets(mech, opts.count)?);
    crate::error::check_cancel(opts.cancel.as_deref())?;
    let (mut cands, scale) = scaled_candidates(mech, points, params, opts.model, &opts.free)?;
    crate::error::check_cancel(opts.cancel.as_deref())?;
    let n = opts.free.len();
    let mut prior = DMatrix::zeros(n, n);
    let mut unseen = 0;
    opts.noise.check("noise")?;
    if !opts.priors.is_empty() {
        for p in &opts.priors {
            if p.index < spec.n_params() {
                crate::identify::prior::check_sigma(
                    spec.param_names()[p.index],
                    p.sigma,
                    spec.param_unit(p.index),
                )?;
            }
        }
        // Rows weighted by the instrument's noise per axis, the priors'
        // precision in the column-scaled parameters (`p_s = D p`).
        let w: Vec<f64> = spec
            .tool_units
            .iter()
            .map(|u| 1.0 / opts.noise.for_unit(*u))
            .collect();
        for a in &mut cands.rows {
            for (r, wr) in w.iter().enumerate() {
                a.row_mut(r).scale_mut(*wr);
            }
        }
        // A parameter no pose sees (its effect below the identifiability
        // analysis's zero, as a stiffness where the actuators do not fight)
        // is known by its prior alone: no choice of poses changes that, so
        // it is left out of the criterion (its prior, in units of a column
        // that is rounding, would swamp every other direction).
        let effect: Vec<f64> = (0..n)
            .map(|k| {
                scale[k]
                    * spec
                        .nominal
                        .get(opts.free[k])
                        .map_or(1.0, |v| v.abs().max(1.0))
            })
            .collect();
        let top = effect.iter().copied().fold(0.0, f64::max);
        // A parameter held by a constraint ([`crate::identify::is_constraint`])
        // is known whatever the poses: left out too.
        let held = |k: usize| {
            opts.priors.iter().any(|p| {
                p.index == opts.free[k]
                    && crate::identify::is_constraint(
                        p.sigma,
                        spec.nominal.get(p.index).copied().unwrap_or(0.0),
                    )
            })
        };
        let seen: Vec<usize> = (0..n)
            .filter(|&k| effect[k] > crate::identify::ZERO_COLUMN * top && !held(k))
            .collect();
        for p in &opts.priors {
            if let Some(k) = opts.free.iter().position(|&f| f == p.index)
                && !held(k)
            {
                prior[(k, k)] = 1.0 / (scale[k].max(f64::MIN_POSITIVE) * p.sigma).powi(2);
            }
        }
        if seen.len() < n && !seen.is_empty() {
            for a in &mut cands.rows {
                *a = a.select_columns(&seen);
            }
            prior = prior.select_rows(&seen).select_columns(&seen);
            unseen = n - seen.len();
        }
    }
    let pool = Candidates {
        points: cands.points[..candidates].to_vec(),
        rows: cands.rows[..candidates].to_vec(),
    };
    // Steps of the first selection, for the second's progress.
    let first = std::sync::atomic::AtomicUsize::new(0);
    let counted = |done: usize, foreseen: usize| {
        first.store(done, std::sync::atomic::Ordering::Relaxed);
        tick(done, foreseen);
    };
    let mut chosen = crate::on_pool(|| {
        choose(
            &pool,
            opts.count,
            opts.criterion,
            &counted,
            opts.cancel.as_deref(),
            &prior,
            None,
        )
    })?;
    let grid_idx: Vec<usize> = (candidates..cands.points.len()).collect();
    let grid_sv = prior_singular_values(&cands, &grid_idx, &prior);
    let (grid_observability, grid_condition) = observability_of(&grid_sv, grid_idx.len());
    let mut sv = prior_singular_values(&cands, &chosen, &prior);
    // A plan never worse than the plain grid: where the selection (greedy,
    // exchanges among a lattice, screened) ends below the grid, the
    // exchanges start again from the grid, the grid's poses candidates too.
    if criterion_of(&grid_sv, opts.criterion) > criterion_of(&sv, opts.criterion)
        && grid_idx.len() == opts.count
    {
        let before = first.load(std::sync::atomic::Ordering::Relaxed);
        let again = |done: usize, foreseen: usize| tick(before + done, before + foreseen);
        chosen = crate::on_pool(|| {
            choose(
                &cands,
                opts.count,
                opts.criterion,
                &again,
                opts.cancel.as_deref(),
                &prior,
                Some(&grid_idx),
            )
        })?;
        sv = prior_singular_values(&cands, &chosen, &prior);
    }
    chosen.sort_unstable();
    let (observability, condition) = observability_of(&sv, chosen.len());
    let rank = rank_of(&sv) + unseen;
    Ok(Plan {
        poses: chosen.iter().map(|&i| cands.points[i].clone()).collect(),
        observability,
        condition,
        grid: grid_idx.iter().map(|&i| cands.points[i].clone()).collect(),
        grid_observability,
        grid_condition,
        rank,
        free: opts.free.len(),
        warnings: if rank < opts.free.len() {
            vec![crate::identify::Warning::new(
                crate::identify::WarningKind::PlanRankDeficient {
                    poses: opts.count,
                    rank,
                    free: opts.free.len(),
                },
            )]
        } else {
            vec![]
        },
        spacing,
        lattice_points,
        candidates,
    })
}
