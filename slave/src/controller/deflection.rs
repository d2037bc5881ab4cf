//! Compensation of the arm's tangential deflection. The arm's deflection under the
//! measured wrench, Λ(x)F, moves the tool sideways (Λ couples the axes): the command gets
//! the opposite of its tangential part (and of its rotation), so the tool stays on its path
//! and does not drag friction sideways. The normal part is left to the force loop
//! (compensating it would close a positive feedback loop through the contact).
//!
//! The force the compensation is for: the prefiltered set-point (smooth, no sensor lag),
//! corrected by the low-passed difference to the measured force. Fed the measured force
//! directly, its ripple (and its lag) would drive the arm's lightly damped tangential
//! modes, which off the centre line push back on the normal force through the coupling of
//! Λ; the set-point also leads the deflection at touch-down instead of trailing it, so the
//! tool does not slide sideways (and tilt the force by friction) while the force builds up.

use h4_shared::kinematics::Pose;
use nalgebra::{Matrix4, Vector3};

use super::arm_model::mat4_vec;

/// Per-cycle fade of the compensation outside force control.
const COMP_FADE: f64 = 0.98;

/// The compensation and its force filter.
#[derive(Clone, Copy, Debug)]
pub(super) struct DeflectionComp {
    /// The offset added to the commanded pose, mm and rad.
    pub(super) comp: Pose,
    /// Low-passed difference between the measured normal force and the set-point, N.
    err_n: f64,
}

impl DeflectionComp {
    /// No compensation.
    pub(super) fn new() -> Self {
        DeflectionComp {
            comp: Pose::zeros(),
            err_n: 0.0,
        }
    }

    /// Out of force control the compensation fades out (no jump).
    pub(super) fn fade(&mut self) {
        self.comp *= COMP_FADE;
    }

    /// At a touch: the force filter restarts.
    pub(super) fn touch(&mut self) {
        self.err_n = 0.0;
    }

    /// The compensation for the normal force along `n`: `f_n` measured, `setpoint_n` the
    /// prefiltered set-point, `full` the arm's compliance (none: no compensation).
    pub(super) fn update(
        &mut self,
        full: Option<&Matrix4<f64>>,
        n: &Vector3<f64>,
        f_n: f64,
        setpoint_n: f64,
        time_constant_s: f64,
        dt: f64,
    ) {
        let a_comp = (dt / time_constant_s.max(dt)).min(1.0);
        self.err_n += ((f_n - setpoint_n) - self.err_n) * a_comp;
        let f_comp = setpoint_n + self.err_n;
        self.comp = match full {
            Some(full) => {
                // The normal force's deflection only: friction's share is left alone, so
                // the compensation cannot drag the tool and feed friction back into itself.
                let d = mat4_vec(full, [n[0] * f_comp, n[1] * f_comp, n[2] * f_comp, 0.0]);
                let d3 = Vector3::new(d[0], d[1], d[2]);
                let dt3 = d3 - n * d3.dot(n);
                Pose::new(-dt3[0], -dt3[1], -dt3[2], -d[3])
            }
            None => Pose::zeros(),
        };
    }
}
