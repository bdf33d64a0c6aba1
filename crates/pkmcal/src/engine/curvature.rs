//! Per-output joint Hessians kept on the joints each output involves: a
//! Gough–Stewart leg's constraint involves its own length and the
//! platform's six coordinates, not the other legs', and a tool coordinate
//! that is a joint has none. A pose keeps these for every equilibrium it
//! starts (tens of thousands of poses in a large calibration), so the zeros
//! are left out: the same numbers as the dense matrices, a seventh of the
//! memory on an 8-leg platform.

use nalgebra::DMatrix;

/// Second derivatives `∇²_q y_k` of each output `y_k` (the constraints,
/// then the tool coordinates) with respect to the `nq` joints, each stored
/// as a dense block over its support: the joints whose row or column of the
/// dense matrix holds a non-zero entry (every entry outside that block is
/// exactly zero).
#[derive(Debug, Clone, PartialEq)]
pub struct JointHessians {
    #[doc(hidden)] // public for the integration tests only
    pub nq: usize,
    /// Output `k`'s support is `support[starts[k]..starts[k + 1]]`.
    #[doc(hidden)] // public for the integration tests only
    pub starts: Vec<u32>,
    #[doc(hidden)] // public for the integration tests only
    pub support: Vec<u32>,
    /// The blocks, column-major, one after another.
    #[doc(hidden)] // public for the integration tests only
    pub values: Vec<f64>,
}

impl JointHessians {
    /// The dense matrices' entries on their supports (each `nq × nq`).
    ///
    /// # Panics
    /// When the matrices are not all square of one size.
    pub fn from_dense(dense: &[DMatrix<f64>]) -> Self {
        let nq = dense.first().map_or(0, DMatrix::nrows);
        let mut starts = Vec::with_capacity(dense.len() + 1);
        starts.push(0);
        let mut support = vec![];
        let mut values = vec![];
        for h in dense {
            assert_eq!(h.shape(), (nq, nq), "joint Hessians are nq × nq");
            // (NaN counts as non-zero, as it does in a weighted sum.)
            let first = support.len();
            support.extend((0..nq).filter_map(|i| {
                let involved = (0..nq).any(|j| h[(i, j)] != 0.0 || h[(j, i)] != 0.0);
                involved.then_some(i as u32)
            }));
            let sup = &support[first..];
            for &c in sup {
                values.extend(sup.iter().map(|&r| h[(r as usize, c as usize)]));
            }
            starts.push(support.len() as u32);
        }
        // Kept with every prepared pose: no spare capacity.
        support.shrink_to_fit();
        values.shrink_to_fit();
        Self {
            nq,
            starts,
            support,
            values,
        }
    }

    /// No output, for no joint (to be refilled by [`JointHessians::clear`]
    /// and [`JointHessians::push`]).
    pub fn empty() -> Self {
        Self {
            nq: 0,
            starts: vec![0],
            support: vec![],
            values: vec![],
        }
    }

    /// Drop every output (keeping the storage), for `nq` joints.
    pub fn clear(&mut self, nq: usize) {
        self.nq = nq;
        self.starts.clear();
        self.starts.push(0);
        self.support.clear();
        self.values.clear();
    }

    /// Add the next output's Hessian, given on the joints `joints`
    /// (ascending) as `block` (`k × k` column-major, `k = joints.len()`;
    /// every other entry zero): kept as [`JointHessians::from_dense`] keeps
    /// the dense matrix, the same support and values, without building it.
    pub fn push(&mut self, joints: &[usize], block: &[f64]) {
        let k = joints.len();
        assert_eq!(block.len(), k * k, "a k × k block on k joints");
        let entry = |a: usize, b: usize| block[b * k + a];
        // (NaN counts as non-zero, as in `from_dense`.)
        let involved = |a: usize| (0..k).any(|b| entry(a, b) != 0.0 || entry(b, a) != 0.0);
        // The involved joints' positions as bits (up to 64 joints; beyond,
        // asked again).
        let mut mask = 0u64;
        let first = self.support.len();
        for (a, &joint) in joints.iter().enumerate() {
            if involved(a) {
                self.support.push(joint as u32);
                if a < 64 {
                    mask |= 1 << a;
                }
            }
        }
        debug_assert!(self.support[first..].is_sorted());
        let on = |a: usize| {
            if k <= 64 {
                mask >> a & 1 == 1
            } else {
                involved(a)
            }
        };
        for b in (0..k).filter(|&b| on(b)) {
            self.values
                .extend((0..k).filter(|&a| on(a)).map(|a| entry(a, b)));
        }
        self.starts.push(self.support.len() as u32);
    }

    /// Release the spare capacity (for Hessians kept with a pose).
    pub fn shrink_to_fit(&mut self) {
        self.starts.shrink_to_fit();
        self.support.shrink_to_fit();
        self.values.shrink_to_fit();
    }

    /// Number of outputs.
    pub fn len(&self) -> usize {
        self.starts.len() - 1
    }

    /// Whether there is no output.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of joints.
    pub fn joints(&self) -> usize {
        self.nq
    }

    /// Output `k`'s Hessian as a dense `nq × nq` matrix.
    pub fn dense(&self, k: usize) -> DMatrix<f64> {
        let mut m = DMatrix::zeros(self.nq, self.nq);
        self.each(|o, sup, block| {
            if o == k {
                for (b, &c) in sup.iter().enumerate() {
                    for (a, &r) in sup.iter().enumerate() {
                        m[(r as usize, c as usize)] = block[b * sup.len() + a];
                    }
                }
            }
        });
        m
    }

    /// `out[r, c] += Σ_k weights[k] · ∇²y_k[r, c]` on the leading `nq × nq`
    /// block of the column-major `out` (`ld` rows), output after output,
    /// skipping zero weights: each entry receives the same products in the
    /// same order as the dense sum, without the zeros.
    #[doc(hidden)] // public for the integration tests only
    pub fn add_weighted(&self, weights: &[f64], out: &mut [f64], ld: usize) {
        self.each(|k, sup, block| {
            let wt = weights.get(k).copied().unwrap_or(0.0);
            if wt == 0.0 {
                return;
            }
            let s = sup.len();
            for (b, &c) in sup.iter().enumerate() {
                let col = &mut out[c as usize * ld..c as usize * ld + self.nq];
                for (v, &r) in block[b * s..(b + 1) * s].iter().zip(sup) {
                    col[r as usize] += v * wt;
                }
            }
        });
    }

    /// `f(k, support, block)` for each output in order.
    fn each(&self, mut f: impl FnMut(usize, &[u32], &[f64])) {
        let mut at = 0;
        for k in 0..self.len() {
            let sup = &self.support[self.starts[k] as usize..self.starts[k + 1] as usize];
            let len = sup.len() * sup.len();
            f(k, sup, &self.values[at..at + len]);
            at += len;
        }
    }
}
