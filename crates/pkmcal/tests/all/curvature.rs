//! Tests of `pkmcal::engine::curvature`.

use nalgebra::DMatrix;
use pkmcal::engine::curvature::*;

/// The kept blocks rebuild the dense matrices, and their weighted sum is
/// the dense sum bit for bit (zero weights skipped, as it skips them).
#[test]
fn blocks_rebuild_the_dense_matrices_and_their_sum() {
    let nq = 7;
    let mut dense = vec![];
    for k in 0..5 {
        let mut h = DMatrix::zeros(nq, nq);
        for (i, j) in [(k, k), (k, (k + 2) % nq), ((k + 2) % nq, k), (6, 6)] {
            h[(i, j)] = 1.0 / (1.0 + (i * nq + j + k) as f64);
        }
        dense.push(h);
    }
    dense.push(DMatrix::zeros(nq, nq));
    let kept = JointHessians::from_dense(&dense);
    assert_eq!(kept.len(), 6);
    for (k, h) in dense.iter().enumerate() {
        assert_eq!(kept.dense(k), *h);
    }
    let weights = [0.3, -1.7, 0.0, 2.5e-3, 1e5, 4.0];
    let ld = nq + 3;
    let mut sum = vec![0.0; ld * ld];
    kept.add_weighted(&weights, &mut sum, ld);
    let mut expected = vec![0.0; ld * ld];
    for (h, &wt) in dense.iter().zip(&weights) {
        if wt != 0.0 {
            for c in 0..nq {
                for r in 0..nq {
                    expected[c * ld + r] += h[(r, c)] * wt;
                }
            }
        }
    }
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&sum), bits(&expected));
    // Outputs keep 3 (or 2) of 7 joints: 9 (or 4) of 49 entries.
    assert_eq!(kept.values.len(), 4 * 9 + 4);
}

/// Outputs pushed on their joints are kept as the dense matrices are.
#[test]
fn pushed_blocks_are_the_dense_ones() {
    let nq = 9;
    let joints = [1, 4, 5, 8];
    let blocks = [
        [
            [1.0, 0.0, 2.0, 0.0],
            [0.0, 0.0, 0.0, 0.0],
            [2.0, 0.0, -0.0, 0.0],
            [0.0, 0.0, 0.0, 3.0],
        ],
        [[0.0; 4]; 4],
        [[0.0, f64::NAN, 0.0, 0.0], [0.0; 4], [0.0; 4], [0.0; 4]],
    ];
    let mut dense = vec![];
    let mut pushed = JointHessians::empty();
    pushed.clear(nq);
    for b in &blocks {
        let mut h = DMatrix::zeros(nq, nq);
        for (a, &r) in joints.iter().enumerate() {
            for (c, &col) in joints.iter().enumerate() {
                h[(r, col)] = b[a][c];
            }
        }
        dense.push(h);
        let block: Vec<f64> = (0..4).flat_map(|c| (0..4).map(move |a| b[a][c])).collect();
        pushed.push(&joints, &block);
    }
    pushed.push(&[], &[]);
    dense.push(DMatrix::zeros(nq, nq));
    let kept = JointHessians::from_dense(&dense);
    let bits = |h: &JointHessians| {
        (
            h.nq,
            h.starts.clone(),
            h.support.clone(),
            h.values.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        )
    };
    assert_eq!(bits(&pushed), bits(&kept));
}
