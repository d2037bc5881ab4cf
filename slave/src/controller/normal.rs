//! The contact-normal estimate. While the tool slides, friction acts along its motion, so
//! the normal is the measured force without its component along the measured direction of
//! motion (figure 2's construction, made friction-proof). Right after touching it is the
//! force's direction; at a standstill it is held (the friction force of a stuck tool says
//! nothing about the normal), or under a steady force slowly turned to the force.

use nalgebra::{Matrix3, Vector3};

use super::params::ControllerParams;
use super::window::{MotionWindow, WINDOW_MAX};

/// The motion direction is used only while the depth correction is below this share of
/// the displacement.
const DEPTH_TRUST: f64 = 0.3;
/// Largest normal-force change over the motion window that counts as steady, N.
const STEADY_FORCE_CHANGE_N: f64 = 0.5;
/// Cycles right after touching during which the normal follows the force's direction.
const ONSET_CYCLES: u32 = 20;
/// The sliding normal's time constant grows by this factor times the estimated
/// environment compliance (mm/N): ×3 on 5 N/mm, ×1.5 on 20 N/mm, ×1.01 on aluminium.
const SOFT_NORMAL_SLOWDOWN_N_PER_MM: f64 = 10.0;
/// Time constant of the normal estimate at a standstill under a steady force (force
/// direction), s.
const STANDSTILL_NORMAL_TIME_CONSTANT_S: f64 = 0.1;
/// Time constant of the normal estimate right after touching (force direction), s.
const ONSET_NORMAL_TIME_CONSTANT_S: f64 = 0.01;
/// Smallest displacement over the motion window that counts as sliding, mm.
const MOTION_MIN_MM: f64 = 0.01;
/// Displacement over the motion window from which the normal update has full weight, mm.
const MOTION_FULL_MM: f64 = 0.1;

/// What the normal update needs besides the window.
#[derive(Clone, Copy, Debug)]
pub(super) struct NormalInputs {
    /// This cycle's filtered position, mm.
    pub(super) xf: [f64; 3],
    /// This cycle's bias-corrected force, N.
    pub(super) f3: Vector3<f64>,
    /// Total compliance along the current normal (arm + environment), mm/N.
    pub(super) c_prev_mm_per_n: f64,
    /// The environment's estimated compliance, mm/N.
    pub(super) c_env_mm_per_n: f64,
    /// The arm's translational compliance at this pose (the model's Λ block), mm/N.
    pub(super) lambda: Option<Matrix3<f64>>,
    /// The commanded speed along the surface, mm/s.
    pub(super) speed_mm_per_s: f64,
    /// Cycles since the touch.
    pub(super) contact_cycles: u32,
}

/// The estimated outward contact normal (zero before the first contact).
#[derive(Clone, Copy, Debug)]
pub(super) struct NormalEstimate {
    /// Unit normal, or zero.
    pub(super) normal: Vector3<f64>,
}

impl NormalEstimate {
    /// No estimate.
    pub(super) fn new() -> Self {
        NormalEstimate {
            normal: Vector3::zeros(),
        }
    }

    /// One update from the motion over the window and this cycle's force.
    pub(super) fn update(
        &mut self,
        window: &MotionWindow,
        inp: &NormalInputs,
        p: &ControllerParams,
        dt: f64,
    ) {
        let (xf, f3) = (inp.xf, inp.f3);
        let oldest = window.oldest();
        let xo = window.x[oldest];
        // The tool sinks deeper or rises as the force changes: add back that part of the
        // displacement (compliance × force change along the normal), so what is left is
        // the motion of the contact point along the surface.
        let df = f3 - window.f[oldest];
        let d_fn_window = df.dot(&self.normal);
        let depth_change = inp.c_prev_mm_per_n * d_fn_window;
        let disp_fk = Vector3::new(xf[0] - xo[0], xf[1] - xo[1], xf[2] - xo[2]);
        // The arm gives way under the force (tip = carriages' pose + Λ f): add back the
        // change of its deflection in every direction, not only along the normal (friction
        // building up along the motion bends the arm sideways, and Λ couples part of that
        // into the normal), then the surface's own give along the normal.
        let disp = match inp.lambda {
            Some(l) => disp_fk + l * df + self.normal * (inp.c_env_mm_per_n * d_fn_window),
            None => disp_fk + self.normal * depth_change,
        };
        // Without a commanded motion along the surface the displacement is trusted only
        // while the force is steady (the depth correction is then small): what is left is
        // the tool creeping along the surface under a tilted push, and removing friction
        // along it turns the normal towards the true one.
        let steady = d_fn_window.abs() < STEADY_FORCE_CHANGE_N;
        let disp = if inp.speed_mm_per_s > 0.0 || steady {
            disp
        } else {
            Vector3::zeros()
        };
        let disp_n = disp.norm();
        // A large depth correction rests on the compliance estimate: then the direction of
        // motion is not trusted (soft surfaces while the force still changes).
        let moving = inp.contact_cycles as usize >= WINDOW_MAX
            && disp_n > MOTION_MIN_MM
            && depth_change.abs() < DEPTH_TRUST * disp_n;
        let n_raw = if moving {
            let tm = disp / disp_n;
            Some(f3 - tm * f3.dot(&tm))
        } else if inp.contact_cycles < ONSET_CYCLES {
            Some(f3)
        } else if inp.speed_mm_per_s == 0.0 && steady && inp.contact_cycles as usize >= WINDOW_MAX {
            // At a standstill under a steady force the normal is only known to lie in the
            // friction cone around the force; the force's direction is the best guess (the
            // cone's centre), and it turns to the true normal as a tilted touch-down's
            // friction relaxes. Slowly: the friction left over is not a measurement.
            Some(f3)
        } else {
            None
        };
        let standstill = !moving && inp.contact_cycles >= ONSET_CYCLES;
        if let Some(v) = n_raw {
            let vn = v.norm();
            if vn > p.contact_lost_n.max(0.1) {
                let tau = if moving {
                    // Deep in a soft surface the motion's direction carries the depth
                    // corrections (millimetres): trust it more slowly there.
                    p.normal_time_constant_s
                        * (1.0 + SOFT_NORMAL_SLOWDOWN_N_PER_MM * inp.c_env_mm_per_n)
                } else if standstill {
                    STANDSTILL_NORMAL_TIME_CONSTANT_S
                } else {
                    ONSET_NORMAL_TIME_CONSTANT_S
                };
                // Short displacements are noisy: weigh the update by the distance slid.
                let weight = if moving {
                    (disp_n / MOTION_FULL_MM).min(1.0)
                } else {
                    1.0
                };
                self.turn_towards(v / vn, (dt / tau.max(dt) * weight).min(1.0));
            }
        }
    }

    /// Moves the normal the share `a` of the way to the unit vector `towards`.
    fn turn_towards(&mut self, towards: Vector3<f64>, a: f64) {
        let n_new = self.normal + (towards - self.normal) * a;
        let nn = n_new.norm();
        if nn > 1e-9 {
            self.normal = n_new / nn;
        }
    }
}
