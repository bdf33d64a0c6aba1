//! Tests of `pkmcal::lm`.

use nalgebra::{DMatrix, DVector};
use pkmcal::lm::*;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

/// Agreement of the blockwise factorisation with MINPACK's, relative.
const FACTOR_TOL: f64 = 1e-11;

fn random(seed: u64, m: usize, n: usize) -> (DMatrix<f64>, DVector<f64>) {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
    // Columns of different scales, as a calibration's are.
    let a = DMatrix::from_fn(m, n, |_, j| g() * 10f64.powi(j as i32 % 4 - 2));
    let f = DVector::from_fn(m, |_, _| g());
    (a, f)
}

/// The least-squares solution of `a x ≈ f` by MINPACK's QR ([`qrfac`]).
fn least_squares(a: &DMatrix<f64>, f: &DVector<f64>) -> DVector<f64> {
    let n = a.ncols();
    let mut qr = a.clone();
    let (ipvt, rdiag, _) = qrfac(&mut qr);
    let mut qtf = f.as_slice().to_vec();
    apply_qt(&qr, &mut qtf);
    let mut z = vec![0.0; n];
    for j in (0..n).rev() {
        let sum: f64 = (j + 1..n).map(|l| qr[(j, l)] * z[l]).sum();
        z[j] = (qtf[j] - sum) / rdiag[j];
    }
    let mut x = DVector::zeros(n);
    for j in 0..n {
        x[ipvt[j]] = z[j];
    }
    x
}

/// The factor by blocks is `a`'s: `RᵀR = aᵀa`, and `R x = (Qᵀf)[..n]`
/// solves the least-squares problem `a x ≈ f` as MINPACK's QR does.
#[test]
fn blockwise_factor_is_the_matrix_s() {
    for (m, n) in [
        (3 * FOLD_ROWS + 17, 9),
        (FOLD_ROWS, 5),
        (12, 12),
        (40 * FOLD_ROWS + 3, 9),
    ] {
        let (a, f) = random(m as u64, m, n);
        let (r, qtf) = triangular_factor(&a, f.as_slice());
        for j in 0..n {
            for i in j + 1..n {
                assert_eq!(r[(i, j)], 0.0);
            }
        }
        let ata = a.transpose() * &a;
        let rtr = r.transpose() * &r;
        assert!((&rtr - &ata).amax() <= FACTOR_TOL * ata.amax(), "{m} × {n}");
        let x = r
            .solve_upper_triangular(&DVector::from_vec(qtf))
            .expect("full rank");
        let expected = least_squares(&a, &f);
        assert!((&x - &expected).amax() <= FACTOR_TOL * expected.amax().max(1.0));
    }
}

/// A linear least-squares problem.
struct Linear(DMatrix<f64>, DVector<f64>);

impl Problem for Linear {
    fn n_params(&self) -> usize {
        self.0.ncols()
    }
    fn n_residuals(&self) -> usize {
        self.0.nrows()
    }
    fn evaluate(
        &self,
        x: &[f64],
        jacobian: bool,
    ) -> Result<(DVector<f64>, Option<DMatrix<f64>>), String> {
        let r = &self.0 * DVector::from_column_slice(x) - &self.1;
        Ok((r, jacobian.then(|| self.0.clone())))
    }
}

/// A fit with a Jacobian beyond [`LARGE_JACOBIAN`] is factorised by
/// blocks and ends where MINPACK's QR puts the least-squares solution,
/// with the same covariance, and keeps no copy of the Jacobian.
#[test]
fn a_large_fit_factorised_by_blocks_is_the_least_squares_one() {
    let n = 27;
    let m = LARGE_JACOBIAN / n + 1;
    let (a, f) = random(5, m, n);
    let expected = least_squares(&a, &f);
    let problem = Linear(a, f);
    let report = minimize(&problem, &vec![0.0; n], &Options::default());
    assert!(report.termination.converged(), "{:?}", report.termination);
    let x = DVector::from_vec(report.x.clone());
    assert!((&x - &expected).amax() <= FACTOR_TOL * expected.amax());
    let factored = report.factored.as_ref().expect("kept");
    assert!(factored.compact());
    let (c, rank) = report.covariance(COVARIANCE_RANK_TOL);
    let (c0, rank0) = covariance(&report.jacobian, COVARIANCE_RANK_TOL);
    assert_eq!(rank, rank0);
    assert!((&c - &c0).amax() <= FACTOR_TOL * c0.amax());
}
