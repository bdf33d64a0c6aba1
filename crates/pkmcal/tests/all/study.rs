//! Tests of `pkmcal::identify::study`.

use pkmcal::Mechanism;
use pkmcal::identify::study::*;
use pkmcal::kinds::reference::JeongKim2Dof;
use pkmcal::measurement::MeasurementModel;

fn names(s: &[&str]) -> Vec<String> {
    s.iter().map(|s| s.to_string()).collect()
}

/// The free set from names: the default set, `all`, `default` plus
/// names, `--fix` removing; unknown names, frame parameters and an
/// empty set are typed errors naming the list.
#[test]
fn free_sets_resolve_names_and_refuse_by_type() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let tool = MeasurementModel::tool(spec);
    let default = resolve_free_set(spec, &tool, &spec.default_free, None, &[]).unwrap();
    assert_eq!(default.len(), spec.default_free.len());
    let all =
        resolve_free_set(spec, &tool, &spec.default_free, Some(&names(&["all"])), &[]).unwrap();
    assert_eq!(all.len(), spec.n_params());
    let more = resolve_free_set(
        spec,
        &tool,
        &spec.default_free,
        Some(&names(&["default", "k1"])),
        &names(&["l11"]),
    )
    .unwrap();
    assert_eq!(more.len(), default.len());
    assert!(more.contains(&spec.param_index("k1").unwrap()));
    assert!(!more.contains(&spec.param_index("l11").unwrap()));
    assert!(matches!(
        resolve_free_set(
            spec,
            &tool,
            &spec.default_free,
            Some(&names(&["l111"])),
            &[]
        ),
        Err(FreeSetError::Unknown {
            list: NameList::Free,
            ..
        })
    ));
    assert!(matches!(
        resolve_free_set(spec, &tool, &spec.default_free, None, &names(&["nope"])),
        Err(FreeSetError::Unknown {
            list: NameList::Fix,
            ..
        })
    ));
    let free_frame = tool
        .clone()
        .in_frame(pkmcal::measurement::Frame::Free)
        .unwrap();
    assert!(matches!(
        resolve_free_set(
            spec,
            &free_frame,
            &spec.default_free,
            Some(&names(&["frame.x"])),
            &[]
        ),
        Err(FreeSetError::FrameParameter {
            list: NameList::Free,
            ..
        })
    ));
    assert_eq!(
        resolve_free_set(
            spec,
            &tool,
            &spec.default_free,
            Some(&names(&["l11"])),
            &names(&["l11"])
        ),
        Err(FreeSetError::Empty)
    );
    // No message names a command-line option.
    for e in [
        resolve_free_set(
            spec,
            &tool,
            &spec.default_free,
            Some(&names(&["l111"])),
            &[],
        )
        .unwrap_err(),
        resolve_free_set(
            spec,
            &free_frame,
            &spec.default_free,
            Some(&names(&["frame.x"])),
            &[],
        )
        .unwrap_err(),
        FreeSetError::Empty,
    ] {
        assert!(!e.to_string().contains("--"), "{e}");
    }
}

/// No warning's message or hint names a command-line option: each front
/// end words its options itself.
#[test]
fn warnings_name_no_option() {
    use pkmcal::engine::models::Model;
    use pkmcal::identify::result::{Warning, WarningKind as K};
    let o = pkmcal::error::Origin {
        pose: 3,
        line: Some(7),
        distance: false,
    };
    let kinds = vec![
        K::StiffnessRatios { fixed: "k1".into() },
        K::Unidentifiable {
            model: Model::Rigid,
            combination: "dq3".into(),
            fixed: Some("dq3".into()),
        },
        K::FrameGauge {
            model: Model::Exact,
            fixed: vec!["B1x".into()],
            unfixed: 1,
        },
        K::NotConverged {
            reason: "evaluations".into(),
        },
        K::RankDeficient { rank: 3, free: 4 },
        K::Outliers {
            poses: vec![o],
            threshold: 4.0,
            robust_loss: true,
            dropping: false,
        },
        K::Outliers {
            poses: vec![o],
            threshold: 4.0,
            robust_loss: false,
            dropping: true,
        },
        K::Dropped { poses: vec![o] },
    ];
    for k in kinds {
        let w = Warning::new(k);
        assert!(!w.message.contains("--") && !w.hint.contains("--"), "{w:?}");
    }
}
