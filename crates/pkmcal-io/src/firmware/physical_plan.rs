//! Which extra measurement would shrink the predicted cube error most
//! (`--physical`, issue 54): candidates a printer owner can take — one
//! more probe point, the probe pattern again on a gauge block (heights at a
//! second level), the nozzle touching the bed at seven points (a paper
//! test), the twelve distances of Klipper's calibration object
//! measured with calipers — each scored by how much it would reduce the
//! variance of the verdict's cube errors ([`physical::cube_errors`]: X and
//! Y size and top flatness, at the centre and the edge).
//!
//! The fit's posterior covariance `Σ` of the free parameters (and the
//! bed's) is updated by a candidate's readings as a Gauss-Markov update
//! would: with `A` the readings' Jacobian and `R` their noise,
//! `Σ' = Σ − Σ Aᵀ (A Σ Aᵀ + R)⁻¹ A Σ`; the cube errors' Jacobian `G` gives
//! their variances `diag(G Σ Gᵀ)` before and `diag(G Σ' Gᵀ)` after. The
//! candidate that reduces their sum most is the targeted (c-optimal)
//! choice: the one that buys the most certainty about the printed cube,
//! not about the parameters in general. Jacobians are forward differences
//! through the physical model.

use super::physical::{self, PhysicalFit};
use crate::description::Mech;
use crate::error::{Error, Result};
use nalgebra::DMatrix;
use pkmcal::{Mechanism, Params};

/// Klipper's calibration object (`delta_calibrate.py`,
/// `docs/prints/calibrate_size.stl`): its six directions (degrees), its
/// outer radius and its ridges' (mm).
const OBJECT_ANGLES_DEG: [f64; 6] = [210.0, 270.0, 330.0, 30.0, 90.0, 150.0];
const OBJECT_OUTER_MM: f64 = 65.0;
const OBJECT_RIDGE_MM: f64 = 4.5;
/// How many of the next measurements ([`suggest`]) a summary or report
/// lists, best first.
pub const SHOWN: usize = 3;

/// The gauge block's height for heights at a second level (mm).
pub const GAUGE_BLOCK_MM: f64 = 50.0;
/// Directions of the candidate probe points (every 30°) and their share of
/// the build volume's radius (less the probe's offset: the nozzle stays
/// within it).
const PROBE_RING_STEP_DEG: f64 = 30.0;
const PROBE_RING_SHARES: [f64; 2] = [0.5, 0.9];
/// The nozzle touches' ring, a share of the build volume's radius.
const TOUCH_RING_SHARE: f64 = 0.8;
/// Forward-difference step of the Jacobians (mm or rad).
const DIFF: f64 = 1e-6;

/// An extra measurement.
#[derive(Debug, Clone, PartialEq)]
pub enum Extra {
    /// One probe reading with the probe at `at` (x, y on the bed, mm).
    ProbePoint {
        /// Where the probe touches.
        at: [f64; 2],
    },
    /// The probe at `points` on a gauge block `height` mm high.
    SecondLevel {
        /// The block's height (mm).
        height: f64,
        /// Where the probe touches its top.
        points: Vec<[f64; 2]>,
    },
    /// The nozzle touching the bed at `points` (a paper test), each read
    /// as a `nozzle` row of the heights measured by hand
    /// ([`super::physical_heights`]).
    NozzleTouches {
        /// Where the nozzle touches (x, y on the bed, mm).
        points: Vec<[f64; 2]>,
    },
    /// The 12 distances of Klipper's calibration object printed with the
    /// written values and measured with calipers.
    ObjectDistances,
}

/// A candidate and what it would do to the cube's predicted uncertainty.
#[derive(Debug, Clone, PartialEq)]
pub struct Suggestion {
    /// The measurement.
    pub extra: Extra,
    /// Its readings.
    pub readings: usize,
    /// Each cube error's σ now and after it (mm), in the order X size,
    /// Y size, flatness at the centre, then at the edge (the linearised
    /// σ; [`physical::cube_errors`] gives them from draws).
    pub sd_before: Vec<f64>,
    /// The same after the measurement (mm).
    pub sd_after: Vec<f64>,
}

impl Suggestion {
    /// The largest cube σ now and after (mm).
    pub fn largest(&self) -> (f64, f64) {
        let m = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        (m(&self.sd_before), m(&self.sd_after))
    }

    /// The share of the cube errors' summed variance it removes.
    pub fn variance_removed(&self) -> f64 {
        let s = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>();
        1.0 - s(&self.sd_after) / s(&self.sd_before).max(f64::MIN_POSITIVE)
    }
}

/// The ends of the calibration object's 12 distances (on the bed, mm), as
/// Klipper's `measurements_to_distances` places them: six from the inner
/// ridge to the outer, six between neighbouring outer pillars.
pub fn object_pairs() -> Vec<([f64; 2], [f64; 2])> {
    let dir: Vec<[f64; 2]> = OBJECT_ANGLES_DEG
        .iter()
        .map(|a| {
            let (s, c) = a.to_radians().sin_cos();
            [c, s]
        })
        .collect();
    let at = |d: [f64; 2], r: f64| [d[0] * r, d[1] * r];
    let outer = OBJECT_OUTER_MM + OBJECT_RIDGE_MM;
    let mut pairs: Vec<_> = dir
        .iter()
        .map(|d| (at(*d, OBJECT_RIDGE_MM), at(*d, outer)))
        .collect();
    for k in 0..6 {
        let start = at(dir[k], OBJECT_OUTER_MM);
        let s = dir[(k + 2) % 6];
        pairs.push((
            [
                start[0] + s[0] * OBJECT_RIDGE_MM,
                start[1] + s[1] * OBJECT_RIDGE_MM,
            ],
            [start[0] + s[0] * outer, start[1] + s[1] * outer],
        ));
    }
    pairs
}

/// The candidate probe points: every [`PROBE_RING_STEP_DEG`] at the shares
/// [`PROBE_RING_SHARES`] of `radius`.
fn probe_candidates(radius: f64) -> Vec<[f64; 2]> {
    let mut out = vec![];
    for share in PROBE_RING_SHARES {
        let mut a: f64 = 0.0;
        while a < 360.0 - 1e-9 {
            let (s, c) = a.to_radians().sin_cos();
            out.push([share * radius * c, share * radius * s]);
            a += PROBE_RING_STEP_DEG;
        }
    }
    out
}

/// The gauge block's points: the centre and towards each tower's
/// direction (90° + 120° k) at half the radius.
fn block_points(radius: f64) -> Vec<[f64; 2]> {
    let mut out = vec![[0.0, 0.0]];
    for k in 0..3 {
        let (s, c) = (90.0 + 120.0 * k as f64).to_radians().sin_cos();
        out.push([0.5 * radius * c, 0.5 * radius * s]);
    }
    out
}

/// The nozzle touches' points: the centre and six every 60° (from the
/// third tower's direction, 90°) at [`TOUCH_RING_SHARE`] of `radius`, as
/// `DELTA_CALIBRATE` spreads its probe points.
fn touch_points(radius: f64) -> Vec<[f64; 2]> {
    let mut out = vec![[0.0, 0.0]];
    for k in 0..6 {
        let (s, c) = (90.0 + 60.0 * k as f64).to_radians().sin_cos();
        out.push([TOUCH_RING_SHARE * radius * c, TOUCH_RING_SHARE * radius * s]);
    }
    out
}

/// Every quantity the candidates and the cube depend on, for the printer
/// `params` with bed `bed` under the firmware's written values (their
/// commands in [`Sents`]): the 6 cube errors, then each candidate probe
/// point's height, each block point's, each object distance.
struct Quantities<'a> {
    fit: &'a PhysicalFit,
    probes: Vec<[f64; 2]>,
    block: Vec<[f64; 2]>,
    touches: Vec<[f64; 2]>,
    pairs: Vec<([f64; 2], [f64; 2])>,
}

impl Quantities<'_> {
    /// The probe's targets: the nozzle sent to put the probe (the effector
    /// frame's origin) over each candidate point, then over each block
    /// point at the block's height.
    fn probe_targets(&self) -> Vec<[f64; 3]> {
        let o = self.fit.delta.probe_offset;
        self.probes
            .iter()
            .map(|p| [p[0] - o[0], p[1] - o[1], 0.0])
            .chain(
                self.block
                    .iter()
                    .map(|p| [p[0] - o[0], p[1] - o[1], GAUGE_BLOCK_MM]),
            )
            .collect()
    }

    /// The nozzle's targets: each touch at z = 0, then both ends of each
    /// object distance.
    fn nozzle_targets(&self) -> Vec<[f64; 3]> {
        self.touches
            .iter()
            .map(|p| [p[0], p[1], 0.0])
            .chain(
                self.pairs
                    .iter()
                    .flat_map(|(a, b)| [[a[0], a[1], 0.0], [b[0], b[1], 0.0]]),
            )
            .collect()
    }

    /// The quantities on the printer `params` with bed `bed`, and the
    /// printer's joints at every point read; each prediction from
    /// `starts`' joints at the same point where given.
    fn eval(
        &self,
        sent: &Sents,
        params: &Params,
        bed: &[f64],
        starts: Option<&Kept>,
    ) -> Result<(Vec<f64>, Kept)> {
        let fit = self.fit;
        let at = |tool: [f64; 3]| physical::Printer {
            mech: &fit.mech,
            params,
            bed,
            nozzle: tool,
        };
        let mut out = vec![];
        let mut kept = Kept {
            cubes: vec![],
            probes: vec![],
            nozzle: vec![],
        };
        for (k, cube) in sent.cubes.iter().enumerate() {
            let start = starts.and_then(|s| s.cubes.get(k)).map(Vec::as_slice);
            let (e, joints) = cube.nozzle_errors(&at(fit.delta.nozzle()), start)?;
            let (size, flat) = physical::cube_of(&e);
            out.extend([size[0], size[1], flat]);
            kept.cubes.push(joints);
        }
        // A probe reading: the probe's height over the bed (the probe is
        // the effector frame's origin).
        let start = starts.map(|s| s.probes.as_slice());
        let (e, joints) = sent.probes.nozzle_errors(&at([0.0; 3]), start)?;
        out.extend(e.iter().map(|e| e[2]));
        kept.probes = joints;
        // A nozzle touch: the nozzle's height over the bed where the
        // firmware puts it at z = 0; then the object's distances' ends.
        let start = starts.map(|s| s.nozzle.as_slice());
        let (nozzle, joints) = sent.nozzle.nozzle_errors(&at(fit.delta.nozzle()), start)?;
        kept.nozzle = joints;
        let (touch, e) = nozzle.split_at(self.touches.len());
        out.extend(touch.iter().map(|e| e[2]));
        for (k, pair) in e.chunks(2).enumerate() {
            let (a, b) = self.pairs[k];
            let pa = [a[0] + pair[0][0], a[1] + pair[0][1]];
            let pb = [b[0] + pair[1][0], b[1] + pair[1][1]];
            out.push((pa[0] - pb[0]).hypot(pa[1] - pb[1]));
        }
        Ok((out, kept))
    }
}

/// The firmware's commands for every point the quantities read, made once:
/// its values are fixed and only the printer varies.
struct Sents<'t> {
    cubes: Vec<physical::Sent<'t>>,
    probes: physical::Sent<'t>,
    nozzle: physical::Sent<'t>,
}

/// The printer's joints at every point the quantities read, in [`Sents`]'
/// order: the next evaluation's predictions start there.
struct Kept {
    cubes: Vec<physical::Joints>,
    probes: physical::Joints,
    nozzle: physical::Joints,
}

/// The extra measurements for the fitted printer `fit` with the written
/// values `fw_params` (bed `fw_bed` where the firmware tilts Z), best
/// first: each probe point of a ring, the block, and the calibration
/// object's distances where `distances` (the firmware reads them).
pub fn suggest(
    fit: &PhysicalFit,
    fw_mech: &Mech,
    fw_params: &Params,
    fw_bed: Option<&[f64]>,
    distances: bool,
) -> Result<Vec<Suggestion>> {
    let radius = fit.delta.print_radius();
    let q = Quantities {
        fit,
        probes: probe_candidates(
            radius - fit.delta.probe_offset[0].hypot(fit.delta.probe_offset[1]),
        ),
        block: block_points(radius),
        touches: touch_points(radius),
        pairs: if distances { object_pairs() } else { vec![] },
    };
    let cal = &fit.study.calibration;
    let spec = fit.mech.spec();
    let names = fit.readings.measurement.all_names(spec);
    let n_params = spec.n_params();
    let cube_points: Vec<[[f64; 3]; 8]> = physical::cube_centres(&fit.delta)
        .into_iter()
        .map(physical::cube_points)
        .collect();
    let (probe_targets, nozzle_targets) = (q.probe_targets(), q.nozzle_targets());
    let sent = |targets| physical::Sent::new(fw_mech, fw_params, fw_bed, targets);
    let sents = Sents {
        cubes: cube_points.iter().map(|p| sent(p)).collect::<Result<_>>()?,
        probes: sent(&probe_targets)?,
        nozzle: sent(&nozzle_targets)?,
    };
    let (base, kept) = q.eval(&sents, &cal.params, &cal.measurement, None)?;
    let columns: Vec<Vec<f64>> = {
        use rayon::prelude::*;
        cal.free
            .par_iter()
            .map(|&i| -> Result<Vec<f64>> {
                let (mut p, mut bed) = (cal.params.clone(), cal.measurement.clone());
                if i < n_params {
                    let v = p.get(spec, &names[i])?;
                    p.set(spec, &names[i], v + DIFF)?;
                } else {
                    bed[i - n_params] += DIFF;
                }
                Ok(q.eval(&sents, &p, &bed, Some(&kept))?
                    .0
                    .iter()
                    .zip(&base)
                    .map(|(a, b)| (a - b) / DIFF)
                    .collect())
            })
            .collect::<Result<_>>()?
    };
    let n_free = cal.free.len();
    let jac = DMatrix::from_fn(base.len(), n_free, |r, c| columns[c][r]);
    let sigma = &cal.covariance;
    if sigma.nrows() != n_free {
        return Err(Error::Content(
            "the fit's covariance does not match its free parameters".into(),
        ));
    }
    let g = jac.rows(0, 6).into_owned();
    let gs = &g * sigma;
    let sd_before: Vec<f64> = (0..6)
        .map(|k| gs.row(k).dot(&g.row(k)).max(0.0).sqrt())
        .collect();
    let score = |rows: &[usize], noise: f64, extra: Extra| -> Option<Suggestion> {
        let a = DMatrix::from_fn(rows.len(), n_free, |r, c| jac[(rows[r], c)]);
        let s =
            &a * sigma * a.transpose() + DMatrix::identity(rows.len(), rows.len()) * noise * noise;
        let inv = s.try_inverse()?;
        let gsa = &gs * a.transpose();
        let drop = &gsa * inv * gsa.transpose();
        let sd_after = (0..6)
            .map(|k| (sd_before[k].powi(2) - drop[(k, k)]).max(0.0).sqrt())
            .collect();
        Some(Suggestion {
            extra,
            readings: rows.len(),
            sd_before: sd_before.clone(),
            sd_after,
        })
    };
    let mut out = vec![];
    let first_probe = 6;
    for (k, at) in q.probes.iter().enumerate() {
        out.extend(score(
            &[first_probe + k],
            fit.probe_noise.mm(),
            Extra::ProbePoint { at: *at },
        ));
    }
    let first_block = first_probe + q.probes.len();
    let rows: Vec<usize> = (first_block..first_block + q.block.len()).collect();
    out.extend(score(
        &rows,
        fit.probe_noise.mm(),
        Extra::SecondLevel {
            height: GAUGE_BLOCK_MM,
            points: q.block.clone(),
        },
    ));
    let first_touch = first_block + q.block.len();
    let rows: Vec<usize> = (first_touch..first_touch + q.touches.len()).collect();
    out.extend(score(
        &rows,
        super::physical_heights::TOUCH_NOISE_MM,
        Extra::NozzleTouches {
            points: q.touches.clone(),
        },
    ));
    if distances {
        let first = first_touch + q.touches.len();
        let rows: Vec<usize> = (first..first + q.pairs.len()).collect();
        out.extend(score(
            &rows,
            physical::DISTANCE_NOISE_MM,
            Extra::ObjectDistances,
        ));
    }
    // Best probe point only, then the groups: by variance removed.
    out.sort_by(|a, b| b.variance_removed().total_cmp(&a.variance_removed()));
    let mut seen_probe = false;
    out.retain(|s| {
        let probe = matches!(s.extra, Extra::ProbePoint { .. });
        let keep = !(probe && seen_probe);
        seen_probe |= probe;
        keep
    });
    Ok(out)
}
