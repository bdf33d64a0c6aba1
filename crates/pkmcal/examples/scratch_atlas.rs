use std::time::Instant;
fn main() {
    let text = std::fs::read_to_string("../../examples/4-rrr/mechanism.toml").unwrap();
    let mut t: toml::Table = toml::from_str(&text).unwrap();
    t.remove("type");
    t.remove("target");
    let d: pkmcal::PlanarDescription = t.try_into().unwrap();
    let mut v = vec![];
    for _ in 0..7 {
        let t0 = Instant::now();
        let l = pkmcal::PlanarLinkage::new(&d).unwrap();
        v.push(t0.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(l);
    }
    v.sort_by(f64::total_cmp);
    println!("new: median {:.2} ms ({:?})", v[3], v);
}
