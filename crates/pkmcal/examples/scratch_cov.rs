use nalgebra::DMatrix;
use std::time::Instant;
fn main() {
    let mut s = 1u64;
    let j = DMatrix::from_fn(360, 56, |_, _| {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    });
    let mut t = vec![];
    for _ in 0..50 {
        let t0 = Instant::now();
        std::hint::black_box(pkmcal::lm::covariance(&j, 1e-12));
        t.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    println!("covariance 360x56: {:.3} ms", t[25]);
    let mut t = vec![];
    for _ in 0..50 {
        let t0 = Instant::now();
        std::hint::black_box(j.clone().svd(false, true));
        t.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    println!("svd 360x56: {:.3} ms", t[25]);
}
