//! Position mode: the commanded pose is followed with velocity and acceleration limits per
//! axis; the position-mode force guard and the back-off keep a push into a wall under the
//! force limit.

use h4_shared::kinematics::Pose;

use super::Cycle;
use super::guards;
use super::interface::Status;
use super::params::ControllerParams;

/// The reference velocity of the trajectory.
#[derive(Clone, Copy, Debug)]
pub(super) struct PositionTrajectory {
    /// `[vx, vy, vz, ω]`, mm/s and rad/s.
    pub(super) v_ref: Pose,
}

impl PositionTrajectory {
    /// At rest.
    pub(super) fn new() -> Self {
        PositionTrajectory {
            v_ref: Pose::zeros(),
        }
    }

    /// Stops the trajectory (the next motion starts from rest).
    pub(super) fn stop(&mut self) {
        self.v_ref = Pose::zeros();
    }

    /// One step from the commanded pose `x_cmd` towards `target`; `c_env` is the
    /// environment's compliance for the back-off. Returns the next commanded pose and the
    /// state.
    pub(super) fn step(
        &mut self,
        x_cmd: &Pose,
        target: &[f64; 4],
        cx: &Cycle,
        c_env: f64,
        p: &ControllerParams,
    ) -> (Pose, Status) {
        let dt = cx.dt_s;
        let mut next = *x_cmd;
        let target = Pose::from(*target);
        for j in 0..4 {
            let (vmax, amax) = if j < 3 {
                (
                    p.max_speed_mm_per_s / 3f64.sqrt(),
                    p.max_accel_mm_per_s2 / 3f64.sqrt(),
                )
            } else {
                (
                    p.max_theta_rate_rad_per_s,
                    p.max_theta_rate_rad_per_s * 10.0,
                )
            };
            let err = target[j] - next[j];
            let v_des = err.signum()
                * vmax
                    .min((2.0 * amax * err.abs()).sqrt())
                    .min(err.abs() / dt);
            let dv = (v_des - self.v_ref[j]).clamp(-amax * dt, amax * dt);
            self.v_ref[j] += dv;
            next[j] += self.v_ref[j] * dt;
        }
        let mut status = Status::Free;
        if cx.f_mag > p.contact_threshold_n
            && let Some(n) = guards::position_force_guard(&mut next, cx, p)
        {
            // The trajectory's speed into the surface is dropped.
            let v_into = (0..3).map(|i| n[i] * self.v_ref[i]).sum::<f64>().min(0.0);
            for i in 0..3 {
                self.v_ref[i] -= n[i] * v_into;
            }
            status = Status::ForceLimited;
        }
        if cx.f_mag > p.force_limit_n {
            self.stop();
            next = *x_cmd;
            guards::back_off(&mut next, cx, c_env, p);
            status = Status::ForceLimited;
        }
        (next, status)
    }
}
