//! Shared test helpers: a non-redundant variant of the reference mechanism and
//! reachable poses.
#![allow(dead_code)]

use pkmcal::kinds::reference::JeongKim2Dof;
use pkmcal::{Mechanism, Scalar, Spec, spread_targets};

#[path = "../../support/examples.rs"]
mod examples;
pub use examples::example_table as table;

/// The reference mechanism with only `q1, q2` actuated (non-redundant).
pub struct NonRedundant {
    inner: JeongKim2Dof,
    spec: Spec,
}

impl NonRedundant {
    pub fn new() -> Self {
        let inner = JeongKim2Dof::new();
        let mut spec = inner.spec().clone();
        spec.actuated = vec![0, 1];
        spec.offsets.truncate(2);
        spec.stiffness.truncate(2);
        let ng = spec.n_geometric();
        let nominal = spec.nominal.clone();
        spec.nominal = nominal[..ng].to_vec();
        spec.nominal
            .extend([0.0, 0.0, nominal[ng + 3], nominal[ng + 4]]);
        spec.default_free.retain(|n| n != "dq3");
        spec.validate().unwrap();
        Self { inner, spec }
    }
}

impl Mechanism for NonRedundant {
    fn spec(&self) -> &Spec {
        &self.spec
    }
    fn constraints<D: Scalar>(&self, q: &[D], rho: &[D], g: &mut [D]) {
        self.inner.constraints(q, rho, g)
    }
    fn tool<D: Scalar>(&self, q: &[D], rho: &[D], x: &mut [D]) {
        self.inner.tool(q, rho, x)
    }
    fn inverse_kinematics_closed(
        &self,
        t: &[f64],
        rho: &[f64],
    ) -> Option<pkmcal::Result<Vec<f64>>> {
        self.inner.inverse_kinematics_closed(t, rho)
    }
    fn on_branch(&self, q: &[f64], rho: &[f64]) -> bool {
        self.inner.on_branch(q, rho)
    }
}

/// `n` usable targets of the reference mechanism.
pub fn targets(n: usize) -> Vec<Vec<f64>> {
    spread_targets(&JeongKim2Dof::new(), n)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect()
}

pub fn planar(name: &str) -> pkmcal::PlanarLinkage {
    let d: pkmcal::PlanarDescription = table(name).try_into().unwrap();
    pkmcal::PlanarLinkage::new(&d).unwrap()
}

pub fn gough_stewart(name: &str) -> pkmcal::GoughStewart {
    let d: pkmcal::GoughStewartDescription = table(name).try_into().unwrap();
    pkmcal::GoughStewart::new(&d).unwrap()
}

/// Seeded random errors on every geometric parameter (± `mm`) and encoder
/// offset (± `rad`).
pub fn perturbed(spec: &pkmcal::Spec, seed: u64, mm: f64, rad: f64) -> pkmcal::Params {
    let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(seed);
    let mut p = pkmcal::Params::nominal(spec);
    let (ng, na) = (spec.n_geometric(), spec.n_actuated());
    for v in &mut p.values[..ng] {
        *v += rand::RngExt::random_range(&mut rng, -mm..mm);
    }
    for v in &mut p.values[ng..ng + na] {
        *v += rand::RngExt::random_range(&mut rng, -rad..rad);
    }
    p
}

/// `n` targets spread over a mechanism's usable workspace.
pub fn spread<M: pkmcal::Mechanism>(m: &M, n: usize) -> Vec<Vec<f64>> {
    spread_targets(m, n)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect()
}

pub fn spatial(name: &str) -> pkmcal::SpatialMechanism {
    let d: pkmcal::SpatialDescription = table(name).try_into().unwrap();
    pkmcal::SpatialMechanism::new(&d).unwrap()
}

/// Seeded random errors by unit: ± `mm` on lengths, ± `rad` on angles and
/// encoder offsets in rad (offsets in mm get ± `mm`).
pub fn perturbed_by_unit(spec: &pkmcal::Spec, seed: u64, mm: f64, rad: f64) -> pkmcal::Params {
    let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(seed);
    let mut p = pkmcal::Params::nominal(spec);
    let n = spec.n_geometric() + spec.n_actuated();
    for (i, v) in p.values[..n].iter_mut().enumerate() {
        let r = match spec.param_unit(i) {
            pkmcal::Unit::Radian => rad,
            _ => mm,
        };
        *v += rand::RngExt::random_range(&mut rng, -r..r);
    }
    p
}

/// The `[tolerances]` table of `examples/<name>/mechanism.toml`, each as
/// `(name, σ)` resolved against `spec` (a percentage of the nominal value
/// by the library's one rule).
pub fn example_tolerances(spec: &pkmcal::Spec, name: &str) -> Vec<(String, f64)> {
    let path = format!(
        "{}/../../examples/{name}/mechanism.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let t: toml::Table = std::fs::read_to_string(path).unwrap().parse().unwrap();
    let given: Vec<(String, pkmcal::identify::prior::Tolerance)> = t["tolerances"]
        .as_table()
        .unwrap()
        .iter()
        .map(|(k, v)| {
            let text = match v {
                toml::Value::String(s) => s.clone(),
                other => other.to_string(),
            };
            (
                k.clone(),
                pkmcal::identify::prior::Tolerance::parse(&text).unwrap(),
            )
        })
        .collect();
    pkmcal::identify::prior::resolve_tolerances(spec, &given)
        .unwrap()
        .into_iter()
        .map(|(i, s)| (spec.param_names()[i].to_string(), s))
        .collect()
}
