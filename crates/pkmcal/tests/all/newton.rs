//! Tests of `pkmcal::engine::newton`.

use pkmcal::engine::newton::*;

/// The loop stops on the policy's judgement: a step below the
/// tolerance, a small step that stopped shrinking, the equilibrium's
/// rate; it damps long steps, and reports running out or an unusable
/// step.
#[test]
fn the_driver_judges_steps_by_the_policy() {
    let steps = |sizes: Vec<f64>, policy: Policy| {
        let mut taken = vec![];
        let end = run(
            &policy,
            &mut taken,
            |_, it| Ok::<_, ()>(sizes.get(it).map(|&size| Step { size, turn: size })),
            |t, scale| t.push(scale),
        )
        .unwrap();
        (end, taken)
    };
    let (end, taken) = steps(vec![1.0, 1e-3, 1e-14], CLOSURE);
    assert_eq!(end, End::Converged(3));
    assert_eq!(taken, [0.5, 1.0, 1.0]);
    // Below the stall tolerance and no shorter than before.
    assert_eq!(steps(vec![1e-10, 2e-10], CLOSURE).0, End::Converged(2));
    assert_eq!(steps(vec![1e-10, 1e-11, 1e-12], CLOSURE).0, End::Unusable);
    // The equilibrium's rate: 1e-8 then 1e-15 predicts 1e-22.
    assert_eq!(steps(vec![1e-8, 1e-15], EQUILIBRIUM).0, End::Converged(2));
    assert_eq!(steps(vec![1e-11], EQUILIBRIUM).0, End::Converged(1));
    assert_eq!(steps(vec![1e-11], CLOSURE).0, End::Unusable);
    let few = Policy {
        max_iterations: 2,
        ..LEG
    };
    assert_eq!(steps(vec![1.0; 5], few).0, End::Exhausted);
    assert_eq!(CLOSURE.residual_limit(10.0), CLOSURE_RESIDUAL_TOL * 10.0);
    assert_eq!(parameter_scale(&[0.5, -300.0, 2.0]), 300.0);
    assert_eq!(parameter_scale(&[]), 1.0);
}
