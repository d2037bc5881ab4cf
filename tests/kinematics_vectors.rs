//! The kinematics reproduce every reference value of `h4_vectors.json` (IK, FK, J, J⁻¹, Λ, K)
//! at the stated tolerances, reject every invalid input with the right reason, and satisfy
//! FK(IK(P)) = P, J·J⁻¹ = I and J = finite differences of IK over the workspace.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::{ActuatorStiffness, H4Params, Pose};
use h4_tests::Vectors;
use nalgebra::{Matrix4, Vector4};
use proptest::prelude::*;

fn rows(m: &[[f64; 4]; 4]) -> Matrix4<f64> {
    Matrix4::from_fn(|i, j| m[i][j])
}

fn assert_rel(name: &str, got: &Matrix4<f64>, want: &Matrix4<f64>, case: usize) {
    let scale = want.amax().max(1e-300);
    let err = (got - want).amax() / scale;
    assert!(
        err <= 1e-9,
        "case {case} {name}: relative error {err:e}\n got {got}\nwant {want}"
    );
}

#[test]
fn every_valid_vector_matches() {
    let v = Vectors::load();
    let mut c_positive = 0;
    let mut sets = std::collections::BTreeSet::new();
    for (i, case) in v.valid.iter().enumerate() {
        let p = v.params(&case.params);
        sets.insert(case.params.clone());
        let pose = Vector4::from(case.pose);
        let want_l = Vector4::from(case.l);
        let l = p
            .ik_checked(&pose)
            .unwrap_or_else(|e| panic!("case {i}: {e}"));
        assert!((l - want_l).amax() <= 1e-9, "case {i} IK: {l} vs {want_l}");
        let fk = p.fk(&want_l).unwrap_or_else(|e| panic!("case {i}: {e}"));
        assert!((fk - pose).amax() <= 1e-9, "case {i} FK: {fk} vs {pose}");
        assert_rel("J", &p.jacobian(&pose).unwrap(), &rows(&case.j), i);
        assert_rel(
            "J_inv",
            &p.jacobian_inverse(&pose).unwrap(),
            &rows(&case.j_inv),
            i,
        );
        let k1 = ActuatorStiffness::uniform(1.0).unwrap();
        assert_rel(
            "Lambda",
            &p.compliance(&pose, &k1).unwrap(),
            &rows(&case.lambda_k1),
            i,
        );
        assert_rel("K", &p.stiffness(&pose, &k1).unwrap(), &rows(&case.k_k1), i);
        // Equal stiffness k scales both by 1/k and k.
        let k7 = ActuatorStiffness::uniform(7.0).unwrap();
        assert_rel(
            "Lambda k=7",
            &(p.compliance(&pose, &k7).unwrap() * 7.0),
            &rows(&case.lambda_k1),
            i,
        );
        assert_rel(
            "K k=7",
            &(p.stiffness(&pose, &k7).unwrap() / 7.0),
            &rows(&case.k_k1),
            i,
        );
        if case.c_positive_both_roots_negative {
            c_positive += 1;
        }
    }
    assert_eq!(sets.len(), 2, "both parameter sets are covered");
    assert!(c_positive >= 1, "the C > 0 cases are covered");
    assert!(v.valid.len() >= 60);
}

#[test]
fn per_actuator_stiffness_is_consistent() {
    // With unequal k, Λ must still be the inverse of K, and δ = ΛF must give the actuator
    // deflections f_i / k_i with f = J⁻ᵀ F.
    let v = Vectors::load();
    let k = ActuatorStiffness::per_actuator([50.0, 80.0, 120.0, 65.0]).unwrap();
    for (i, case) in v.valid.iter().enumerate() {
        let p = v.params(&case.params);
        let pose = Vector4::from(case.pose);
        let lam = p.compliance(&pose, &k).unwrap();
        let stiff = p.stiffness(&pose, &k).unwrap();
        let prod = lam * stiff;
        let err = (prod - Matrix4::identity()).amax();
        assert!(err < 1e-6, "case {i}: Λ·K − I = {err:e}");
        let wrench = Vector4::new(3.0, -5.0, 20.0, 150.0);
        let delta = lam * wrench;
        let jinv = p.jacobian_inverse(&pose).unwrap();
        let actuator_force = jinv.transpose() * wrench;
        let actuator_defl = actuator_force.component_div(&k.n_per_mm);
        let delta2 = jinv * actuator_defl;
        assert!(
            (delta - delta2).amax() < 1e-9 * delta.amax().max(1.0),
            "case {i}"
        );
    }
}

#[test]
fn every_invalid_pose_is_rejected_with_its_reason() {
    let v = Vectors::load();
    assert!(!v.invalid_poses.is_empty());
    for case in &v.invalid_poses {
        let p = v.params(&case.params);
        let err = p
            .ik_checked(&Vector4::from(case.pose))
            .expect_err(&case.reason);
        assert_eq!(err.reason_code(), case.reason, "{:?}: {err}", case.pose);
    }
}

#[test]
fn every_invalid_fk_input_is_rejected_with_its_reason() {
    let v = Vectors::load();
    assert!(!v.invalid_fk_inputs.is_empty());
    for case in &v.invalid_fk_inputs {
        let p = v.params(&case.params);
        let err = p.fk(&Vector4::from(case.l)).expect_err(&case.reason);
        assert_eq!(err.reason_code(), case.reason, "{:?}: {err}", case.l);
    }
}

/// Poses of the nominal workspace of KINEMATICS.md: |x| ≤ 200, |θ| ≤ 60°, rail clearance
/// ≥ 0.05 R, ≥ 10 mm from the singular line.
fn nominal_pose(p: H4Params) -> impl Strategy<Value = Pose> {
    (
        -200.0..200.0f64,
        -260.0..260.0f64,
        -380.0..20.0f64,
        -1.047..1.047f64,
    )
        .prop_map(|(x, y, z, t)| Vector4::new(x, y, z, t))
        .prop_filter("inside the nominal workspace", move |pose| {
            let ws = h4_shared::Workspace {
                params: p,
                limits: h4_shared::WorkspaceLimits {
                    min_rail_clearance_mm: 0.05 * p.leg_length_mm,
                    ..Default::default()
                },
            };
            ws.ik(pose).is_ok()
        })
}

fn both_sets() -> impl Strategy<Value = H4Params> {
    prop_oneof![Just(H4Params::PROTOTYPE), Just(H4Params::ALT)]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, max_global_rejects: 100_000, ..ProptestConfig::default() })]

    #[test]
    fn fk_inverts_ik((p, pose) in both_sets().prop_flat_map(|p| (Just(p), nominal_pose(p)))) {
        let l = p.ik_checked(&pose).unwrap();
        let back = p.fk(&l).unwrap();
        prop_assert!((back - pose).amax() < 1e-8, "{pose} -> {back}");
    }

    #[test]
    fn jacobian_times_inverse_is_identity((p, pose) in both_sets().prop_flat_map(|p| (Just(p), nominal_pose(p)))) {
        let j = p.jacobian(&pose).unwrap();
        let inv = p.jacobian_inverse(&pose).unwrap();
        let err = (j * inv - Matrix4::identity()).amax();
        prop_assert!(err < 1e-8, "{err:e} at {pose}");
    }

    #[test]
    fn jacobian_matches_finite_differences((p, pose) in both_sets().prop_flat_map(|p| (Just(p), nominal_pose(p)))) {
        let j = p.jacobian(&pose).unwrap();
        for col in 0..4 {
            let h = if col == 3 { 1e-6 } else { 1e-4 };
            let mut plus = pose;
            let mut minus = pose;
            plus[col] += h;
            minus[col] -= h;
            let fd = (p.ik_raw(&plus).unwrap() - p.ik_raw(&minus).unwrap()) / (2.0 * h);
            let scale = j.column(col).amax().max(1.0);
            let err = (fd - j.column(col)).amax() / scale;
            prop_assert!(err < 1e-5, "column {col}: {err:e} at {pose}");
        }
    }

    #[test]
    fn random_actuator_inputs_never_panic(l in proptest::array::uniform4(-1e4..1e4f64)) {
        // Any answer is fine; a panic or a non-finite pose is not.
        if let Ok(pose) = H4Params::PROTOTYPE.fk(&Vector4::from(l)) {
            prop_assert!(pose.iter().all(|v| v.is_finite()));
        }
    }
}
