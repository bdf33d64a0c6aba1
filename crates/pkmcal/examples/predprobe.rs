use pkmcal::Mechanism;
use std::time::Instant;
fn load<T: serde::de::DeserializeOwned>(p: &str) -> T {
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
    t.remove("type");
    t.remove("target");
    t.try_into().unwrap()
}
fn main() {
    let gs: pkmcal::GoughStewartDescription = load("examples/gough-stewart-8/mechanism.toml");
    let m = pkmcal::GoughStewart::new(&gs).unwrap();
    let spec = m.spec();
    let targets = pkmcal::workspace::grid_targets(&m, 500).unwrap();
    let cmds: Vec<Vec<f64>> = targets
        .iter()
        .map(|t| spec.actuated.iter().map(|&j| t.q[j]).collect())
        .collect();
    let mut params = pkmcal::Params::nominal(spec);
    for v in params.values.iter_mut().take(spec.n_geometric()) {
        *v += 0.1;
    }
    let mut out = vec![];
    for _rep in 0..3 {
        let (mut tp, mut tx) = (0.0, 0.0);
        out.clear();
        for c in &cmds {
            let t0 = Instant::now();
            let pose = pkmcal::prepare_pose(&m, c, None).unwrap();
            let t1 = Instant::now();
            let p = pkmcal::predict_pose(&m, &pose, &params, pkmcal::Model::Exact, &[]).unwrap();
            let t2 = Instant::now();
            tp += (t1 - t0).as_secs_f64();
            tx += (t2 - t1).as_secs_f64();
            if out.is_empty() {
                println!("iterations {}", p.iterations);
            }
            out.push(p.x);
        }
        let n = cmds.len() as f64;
        println!(
            "prepare {:.1} us, predict {:.1} us",
            tp / n * 1e6,
            tx / n * 1e6
        );
    }
    std::fs::write("/tmp/predprobe.txt", format!("{out:?}")).unwrap();
}
