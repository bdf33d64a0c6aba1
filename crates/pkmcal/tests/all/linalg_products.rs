//! Tests of `pkmcal::linalg`'s written-out products.

/// [`pkmcal::linalg::product_into`] and [`pkmcal::linalg::gram_into`] are nalgebra's
/// `mul_to` to the bit, for shapes on both sides of its loop (seeded
/// random entries, signed zeros among them).
#[test]
fn products_are_nalgebra_s() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(52);
    for (m, k, n) in [
        (3, 5, 3),
        (3, 5, 1),
        (2, 2, 21),
        (1, 1, 1),
        (6, 7, 8),
        (30, 36, 30),
        (7, 6, 5),
        (4, 0, 3),
        (0, 3, 2),
    ] {
        let mut entry = |_, _| match rng.random_range(0..10) {
            0 => -0.0,
            _ => rng.random_range(-1e3..1e3),
        };
        let a = nalgebra::DMatrix::from_fn(m, k, &mut entry);
        let b = nalgebra::DMatrix::from_fn(k, n, &mut entry);
        let mut want = nalgebra::DMatrix::zeros(m, n);
        a.mul_to(&b, &mut want);
        let mut got = vec![f64::NAN; m * n];
        pkmcal::linalg::product_into(a.as_slice(), b.as_slice(), &mut got, m, k, n);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&got), bits(want.as_slice()), "{m}x{k} by {k}x{n}");
        // And `a aᵀ` by [`pkmcal::linalg::gram_into`].
        let mut want = nalgebra::DMatrix::zeros(m, m);
        a.mul_to(&a.transpose(), &mut want);
        let mut got = vec![f64::NAN; m * m];
        pkmcal::linalg::gram_into(&a, &mut nalgebra::DMatrix::zeros(0, 0), &mut got);
        assert_eq!(
            bits(&got),
            bits(want.as_slice()),
            "{m}x{k} by its transpose"
        );
    }
}
