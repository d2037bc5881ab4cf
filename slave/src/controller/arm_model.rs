//! The arm as the controller models it: the workspace and the compliance `Λ(x)` of the
//! actuators' *assumed* stiffness, evaluated once per cycle at the measured pose.

use h4_shared::kinematics::{ActuatorStiffness, Pose, Workspace};
use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};

/// The workspace and the assumed actuator compliance.
#[derive(Clone, Debug)]
pub(super) struct ArmModel {
    /// Geometry and limits (forward and checked inverse kinematics).
    pub(super) ws: Workspace,
    /// 1/k of each actuator (the assumed stiffness), mm/N.
    actuator_compliance: [f64; 4],
}

/// The arm's compliance at this cycle's measured pose.
#[derive(Clone, Copy, Debug)]
pub(super) struct CycleCompliance {
    /// The full 4×4 `Λ(x)` when the compliance model is on (and the pose has a Jacobian).
    pub(super) full: Option<Matrix4<f64>>,
    /// Its translational 3×3 block (what the force loop uses).
    pub(super) lambda: Option<Matrix3<f64>>,
    /// The translational block for the force guards: evaluated even without the model.
    pub(super) guard: Option<Matrix3<f64>>,
}

impl ArmModel {
    /// The arm `ws` with actuators of stiffness `assumed`.
    pub(super) fn new(ws: Workspace, assumed: ActuatorStiffness) -> Self {
        ArmModel {
            ws,
            actuator_compliance: assumed.n_per_mm.map(|k| 1.0 / k).into(),
        }
    }

    /// The compliance at `pose_fk`; `use_model` is `controller.compliance_model`.
    pub(super) fn at(&self, pose_fk: &Pose, use_model: bool) -> CycleCompliance {
        let full = if use_model {
            self.compliance(pose_fk)
        } else {
            None
        };
        let lambda: Option<Matrix3<f64>> = full.map(|m| m.fixed_view::<3, 3>(0, 0).into_owned());
        let guard: Option<Matrix3<f64>> = match lambda {
            Some(l) => Some(l),
            None => self
                .compliance(pose_fk)
                .map(|m| m.fixed_view::<3, 3>(0, 0).into_owned()),
        };
        CycleCompliance {
            full,
            lambda,
            guard,
        }
    }

    /// The arm's compliance `Λ = J⁻¹ diag(1/k) J⁻ᵀ` at `pose` for the assumed actuator
    /// stiffness (as [`h4_shared::kinematics::H4Params::compliance`], written out: the
    /// symmetric product of a 4×4 matrix, ten entries).
    fn compliance(&self, pose: &Pose) -> Option<Matrix4<f64>> {
        let inv = self.ws.params.jacobian_inverse(pose).ok()?;
        let c = &self.actuator_compliance;
        let mut lam = Matrix4::zeros();
        for i in 0..4 {
            for j in i..4 {
                let v = inv[(i, 0)] * c[0] * inv[(j, 0)]
                    + inv[(i, 1)] * c[1] * inv[(j, 1)]
                    + inv[(i, 2)] * c[2] * inv[(j, 2)]
                    + inv[(i, 3)] * c[3] * inv[(j, 3)];
                lam[(i, j)] = v;
                lam[(j, i)] = v;
            }
        }
        Some(lam)
    }
}

impl CycleCompliance {
    /// The measured pose: `pose_fk` plus the deflection `Λ(x) F` under `wrench` when the
    /// model is on.
    pub(super) fn deflected(&self, pose_fk: Pose, wrench: &Vector4<f64>) -> Pose {
        match &self.full {
            Some(full) => pose_fk + mat4_vec(full, [wrench[0], wrench[1], wrench[2], wrench[3]]),
            None => pose_fk,
        }
    }
}

/// The arm's compliance along the contact normal `n` (0 without a model or a normal), mm/N.
pub(super) fn along_normal(lambda: Option<&Matrix3<f64>>, n: &Vector3<f64>) -> f64 {
    match lambda {
        Some(l) if n.norm_squared() > 0.25 => quad_form(l, n).max(0.0),
        _ => 0.0,
    }
}

/// `M v` (written out: nalgebra's generic product is not inlined here).
#[inline]
pub(super) fn mat4_vec(m: &Matrix4<f64>, v: [f64; 4]) -> Vector4<f64> {
    let row = |i: usize| m[(i, 0)] * v[0] + m[(i, 1)] * v[1] + m[(i, 2)] * v[2] + m[(i, 3)] * v[3];
    Vector4::new(row(0), row(1), row(2), row(3))
}

/// `nᵀ L n`.
#[inline]
pub(super) fn quad_form(l: &Matrix3<f64>, n: &Vector3<f64>) -> f64 {
    let mut s = 0.0;
    for i in 0..3 {
        s += n[i] * (l[(i, 0)] * n[0] + l[(i, 1)] * n[1] + l[(i, 2)] * n[2]);
    }
    s
}
