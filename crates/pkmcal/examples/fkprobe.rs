use pkmcal::Mechanism;
use std::time::Instant;
fn load<T: serde::de::DeserializeOwned>(p: &str) -> T {
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
    t.remove("type");
    t.remove("target");
    t.try_into().unwrap()
}
fn main() {
    let sp: pkmcal::SpatialDescription = load("examples/spatial-gough-stewart-6/mechanism.toml");
    let sp = pkmcal::SpatialMechanism::new(&sp).unwrap();
    let gs: pkmcal::GoughStewartDescription = load("examples/gough-stewart-6/mechanism.toml");
    let gs = pkmcal::GoughStewart::new(&gs).unwrap();
    fn run<M: Mechanism>(name: &str, m: &M) {
        let spec = m.spec();
        let rho = &spec.nominal[..spec.n_geometric()];
        let targets = pkmcal::workspace::grid_targets(m, 500).unwrap();
        let cmds: Vec<Vec<f64>> = targets
            .iter()
            .map(|t| spec.actuated.iter().map(|&j| t.q[j]).collect())
            .collect();
        for mode in 0..3 {
            let t0 = Instant::now();
            let mut prev: Option<Vec<f64>> = None;
            for c in &cmds {
                let p = match mode {
                    0 => pkmcal::prepare_pose(m, c, None).unwrap(),
                    1 => pkmcal::prepare_pose(m, c, prev.as_deref()).unwrap(),
                    _ => {
                        let g = m.configuration_guess(c, rho).unwrap();
                        let st = spec
                            .independent
                            .iter()
                            .zip(c)
                            .map(|(&i, v)| ((g[i] - v) / 10.0).abs())
                            .fold(0.0f64, f64::max)
                            .ceil();
                        let t1 = Instant::now();
                        let _ = pkmcal::forward_kinematics(m, rho, &c[..spec.dof()], &g).unwrap();
                        let mut q = g.clone();
                        for (k, &i) in spec.independent.iter().enumerate() {
                            q[i] = g[i] + 0.5 * (c[k] - g[i]);
                        }
                        let it1 =
                            pkmcal::kinematics::solve_closure(m, rho, &mut q, &spec.independent)
                                .unwrap();
                        for (k, &i) in spec.independent.iter().enumerate() {
                            q[i] = c[k];
                        }
                        let it2 =
                            pkmcal::kinematics::solve_closure(m, rho, &mut q, &spec.independent)
                                .unwrap();
                        if std::ptr::eq(c, &cmds[100]) {
                            println!("iterations {it1} {it2}");
                        }
                        let el = t1.elapsed().as_secs_f64() * 1e6;
                        if std::ptr::eq(c, &cmds[0])
                            || std::ptr::eq(c, &cmds[100])
                            || std::ptr::eq(c, &cmds[200])
                        {
                            println!("stages {st} fk {el:.1} us");
                        }
                        continue;
                    }
                };
                prev = Some(p.nominal_q.clone());
            }
            println!(
                "{name} mode {mode}: {:.1} us/pose",
                t0.elapsed().as_secs_f64() * 1e6 / cmds.len() as f64
            );
        }
        let q = &spec.reference_q;
        let t0 = Instant::now();
        for _ in 0..10000 {
            std::hint::black_box(pkmcal::autodiff::jacobians(m, q, rho, 0..q.len()));
        }
        println!(
            "{name} jacobians q: {:.2} us",
            t0.elapsed().as_secs_f64() * 1e6 / 10000.0
        );
    }
    run("spatial", &sp);
    run("builtin", &gs);
}
