//! Motion along the surface: the tracking direction is the commanded direction of motion
//! projected onto the tangent plane (figure 2), and the speed along it ramps with the
//! tracking acceleration limit, so the contact normal (estimated from the motion) settles
//! before the speed is high.

use nalgebra::Vector3;

use super::params::ControllerParams;

/// The tracking direction and the speed along it.
#[derive(Clone, Copy, Debug)]
pub(super) struct Tracking {
    /// Unit tracking direction on the surface (zero when not tracking).
    pub(super) tangent: Vector3<f64>,
    /// The ramped speed along it, mm/s.
    speed_mm_per_s: f64,
}

impl Tracking {
    /// Not tracking.
    pub(super) fn new() -> Self {
        Tracking {
            tangent: Vector3::zeros(),
            speed_mm_per_s: 0.0,
        }
    }

    /// Starts the speed along the surface from zero (at a touch).
    pub(super) fn reset_speed(&mut self) {
        self.speed_mm_per_s = 0.0;
    }

    /// The tracking direction from the commanded `velocity` (of magnitude `speed`) and the
    /// normal `n`. Returns the commanded speed along the surface, mm/s.
    pub(super) fn direct(&mut self, n: &Vector3<f64>, velocity: &[f64; 4], speed: f64) -> f64 {
        let v3 = Vector3::new(velocity[0], velocity[1], velocity[2]);
        let vt = v3 - n * v3.dot(n);
        let vt_n = vt.norm();
        self.tangent = if speed > 1e-9 && vt_n > 1e-9 {
            vt / vt_n
        } else {
            Vector3::zeros()
        };
        vt_n
    }

    /// This cycle's motion along the surface towards the speed `target_mm_per_s`, mm.
    pub(super) fn advance(
        &mut self,
        target_mm_per_s: f64,
        p: &ControllerParams,
        dt: f64,
    ) -> Vector3<f64> {
        let dv = p.track_accel_mm_per_s2 * dt;
        self.speed_mm_per_s =
            (target_mm_per_s).clamp(self.speed_mm_per_s - 4.0 * dv, self.speed_mm_per_s + dv);
        self.tangent * self.speed_mm_per_s * dt
    }
}
