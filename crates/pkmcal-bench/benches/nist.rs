//! The least-squares solver on the 27 NIST StRD problems, from both starts
//! (compare with `benchmarks/nist_scipy.py`, MINPACK through scipy).

#[path = "../../pkmcal/tests/nist/mod.rs"]
mod nist;

use criterion::{Criterion, criterion_group, criterion_main};
use pkmcal::lm::{Options, minimize};
use std::hint::black_box;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("nist");
    g.sample_size(20)
        .warm_up_time(Duration::from_millis(200))
        .measurement_time(Duration::from_millis(600));
    for name in nist::NAMES {
        let p = nist::load(name);
        for start in [0, 1] {
            g.bench_function(format!("{name}/start{}", start + 1), |b| {
                b.iter(|| black_box(minimize(&p, &p.starts[start], &Options::default())))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
