//! The master's local model of the slave's contact (model-mediated rendering,
//! `coupling.model_*`): a plane and its stiffness learnt from the feedback, rendered at the
//! handle as a spring whose updates are passive unless the port's energy pays for them.
//! Positions and forces are in the slave frame (mm, N); the coupling scales them to the
//! handle.

use h4_shared::vec3::{dot3, norm3};
use h4_shared::wire::Feedback;

/// Settings of the master's local contact model (`coupling.model_*`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelParams {
    /// Render the local model (position–force only; `false`: the delayed slave force).
    pub enabled: bool,
    /// Largest stiffness the master renders, N/mm at the handle.
    pub stiffness_max_n_per_mm: f64,
    /// Stiffness assumed before the first estimate, N/mm at the slave.
    pub stiffness_initial_n_per_mm: f64,
    /// Measured slave force above which a feedback sample counts as contact, N.
    pub contact_n: f64,
    /// Time constant of the stiffness estimator's forgetting, s.
    pub estimator_time_constant_s: f64,
    /// Largest speed at which the rendered plane moves towards the operator where that
    /// pushes the handle out, mm/s at the slave (a newly learnt or moved surface is not
    /// rendered as a force step).
    pub plane_rate_mm_per_s: f64,
    /// Feedback silence after which the model's force fades (instead of
    /// `CouplingParams::feedback_timeout_ms`), ms.
    pub hold_ms: f64,
}

impl Default for ModelParams {
    fn default() -> Self {
        ModelParams {
            enabled: true,
            stiffness_max_n_per_mm: 50.0,
            stiffness_initial_n_per_mm: 5.0,
            contact_n: 1.0,
            estimator_time_constant_s: 0.3,
            plane_rate_mm_per_s: 2.0,
            hold_ms: 500.0,
        }
    }
}

/// The master's local model of the slave's contact: a plane (normal, position) and its
/// stiffness, estimated from the feedback (measured slave pose and force, and the command
/// it echoes); no wire change. In contact the plane used for rendering is placed so that
/// the model reproduces the latest measured force at the commanded position that produced
/// it (with the rendered stiffness: the surface in series with the slave's servo, capped);
/// out of contact the last estimated plane is kept until the slave is seen beyond it
/// without a force. A plane that would push the handle out moves at most at the plane rate.
#[derive(Clone, Copy, Debug, Default)]
pub struct ContactModel {
    normal: [f64; 3],
    has_normal: bool,
    /// Estimated stiffness, N/mm (slave); 0 = none yet.
    pub k_hat: f64,
    origin: [f64; 3],
    /// Estimated servo compliance of the slave (measured minus commanded position per
    /// newton along the normal), mm/N.
    pub servo_mm_per_n: f64,
    contact: bool,
    s_meas: f64,
    f_meas: f64,
    plane: f64,
    plane_valid: bool,
    /// Where the surface is for the offset: the touch point, moved in where the slave was
    /// later measured beyond it without a force (no measured force in it: no loop closes
    /// through it, and it does not jump when the contact flag does).
    surface: f64,
    p_used: f64,
    used_valid: bool,
    /// Stiffness rendered last cycle, N/mm (slave).
    k_used: f64,
    last_fb_ns: Option<u64>,
    /// Model force along the normal rendered last cycle, N (slave).
    pub force_n: f64,
}

impl ContactModel {
    /// Learns from one accepted feedback message (slave frame): the measured pose and
    /// force it carries, and `commanded_mm`, the slave position the master sent in the
    /// command the feedback echoes. The surface (plane and stiffness) is estimated from the
    /// measured pose, which is right even when the slave could not go where it was sent
    /// (passivity drift, force guard); the slave's position-servo compliance (measured
    /// minus commanded per newton) from the two when they agree, so that the model
    /// relates force to the *commanded* position the master controls.
    pub fn observe(&mut self, mp: &ModelParams, fb: &Feedback, commanded_mm: [f64; 3]) {
        let fv = [
            fb.wrench_measured[0],
            fb.wrench_measured[1],
            fb.wrench_measured[2],
        ];
        let pos = [fb.pose[0], fb.pose[1], fb.pose[2]];
        if !fv
            .iter()
            .chain(pos.iter())
            .chain(commanded_mm.iter())
            .all(|x| x.is_finite())
        {
            return;
        }
        let dt_s = self
            .last_fb_ns
            .map_or(1e-3, |t| fb.send_time_ns.saturating_sub(t) as f64 * 1e-9)
            .clamp(1e-4, 1.0);
        self.last_fb_ns = Some(fb.send_time_ns);
        let fmag = norm3(&fv);
        if fmag > mp.contact_n {
            let u = [fv[0] / fmag, fv[1] / fmag, fv[2] / fmag];
            if !self.has_normal {
                self.normal = u;
                self.has_normal = true;
            } else {
                let a = (dt_s / NORMAL_TIME_CONSTANT_S).min(1.0) * (fmag / (fmag + 5.0));
                let mut n = [0.0; 3];
                for i in 0..3 {
                    n[i] = self.normal[i] + a * (u[i] - self.normal[i]);
                }
                let l = norm3(&n);
                if l > 1e-9 {
                    self.normal = [n[0] / l, n[1] / l, n[2] / l];
                }
            }
            if !self.contact {
                // A new touch: the force crossed the contact threshold here; positions
                // along the normal are measured from this point (a projection of the
                // absolute position would move with every small turn of the normal). The
                // remembered plane and the rendered one stay where they are in space.
                let shift = self.along_normal(&pos);
                self.origin = pos;
                self.plane -= shift;
                self.p_used -= shift;
                self.s_meas -= shift;
                self.surface = 0.0;
            }
            let s = self.along_normal(&pos);
            let s_ref = self.along_normal(&commanded_mm);
            let f = dot3(&self.normal, &fv);
            // Secant stiffness from the touch point (quasi-static, robust to the contact's
            // dynamics), low-passed; kept across touches until new data replaces it.
            let a = (dt_s / mp.estimator_time_constant_s.max(1e-3)).min(1.0);
            let depth = -s;
            // A sample says something about the stiffness when the force is well above the
            // touch threshold, or, on a soft surface, the depth is: the slave held out of a
            // soft surface (offset) sees small forces, and must still correct a stiffness
            // learnt too high.
            let above = f - mp.contact_n;
            if depth > 0.02 && (above > mp.contact_n || (depth > 0.1 && above > 0.3)) {
                let k = ((f - mp.contact_n) / depth).clamp(0.05, 1e4);
                if self.k_hat > 0.0 {
                    self.k_hat += a * (k - self.k_hat);
                } else {
                    self.k_hat = k;
                }
            }
            // Servo compliance, while the slave is where it was sent (no drift).
            let lag = s - s_ref;
            if f > 2.0 * mp.contact_n && lag.abs() < SERVO_AGREEMENT_MM {
                let c = (lag / f).clamp(0.0, SERVO_COMPLIANCE_MAX_MM_PER_N);
                self.servo_mm_per_n += a * (c - self.servo_mm_per_n);
            }
            self.contact = true;
            self.s_meas = s;
            self.f_meas = f.max(0.0);
            let k = self.k_est(mp);
            self.plane = s + self.f_meas / k;
            self.plane_valid = true;
        } else {
            self.contact = false;
            let s = self.along_normal(&pos);
            if self.plane_valid && s < self.plane - PLANE_GONE_MM {
                // Far beyond the remembered surface with no force: it is not there (any
                // more).
                self.plane_valid = false;
            } else if self.plane_valid {
                // No force here: the surface is at least this far in. Without this a
                // surface remembered a little too far out holds the slave off it (the
                // offset) and no contact ever corrects it.
                self.plane = self.plane.min(s);
                self.surface = self.surface.min(s);
            }
        }
    }

    fn along_normal(&self, p: &[f64; 3]) -> f64 {
        let rel = [
            p[0] - self.origin[0],
            p[1] - self.origin[1],
            p[2] - self.origin[2],
        ];
        dot3(&self.normal, &rel)
    }

    /// A surface is known (in contact now, or remembered).
    pub fn valid(&self) -> bool {
        self.plane_valid && self.has_normal
    }

    /// How far the rendered plane lies inside the surface, as a vector along the normal
    /// (slave frame, mm). The rendered plane falls behind the surface when the handle went
    /// in before the surface was known (a blind touch: the plane is placed at the handle),
    /// and when a stiffer estimate moves it in (same stored energy); it moves out only as
    /// energy allows. Meanwhile the slave is commanded this much out of the surface, so that
    /// it presses with the force the operator feels. The surface is the touch point (not
    /// the stiffness-dependent plane estimate: no loop through the measured force), moved
    /// in where the slave later went beyond it without a force.
    pub fn offset_mm(&self) -> [f64; 3] {
        if !self.valid() || !self.used_valid {
            return [0.0; 3];
        }
        let d = (self.surface - self.p_used).max(0.0);
        [d * self.normal[0], d * self.normal[1], d * self.normal[2]]
    }

    /// Forgets where the rendered plane was (it is placed again at the handle).
    pub fn reset_used(&mut self) {
        self.used_valid = false;
    }

    fn k_est(&self, mp: &ModelParams) -> f64 {
        if self.k_hat > 0.0 {
            self.k_hat
        } else {
            mp.stiffness_initial_n_per_mm
        }
    }

    /// The model's force on the slave at the slave position `desired_mm` (slave frame),
    /// as a vector along the normal, N; `k_max_slave` the largest stiffness rendered
    /// (N/mm at the slave); `budget_n_mm` the energy (slave units) the model's update may
    /// put into the handle this cycle (`f64::INFINITY`: no limit).
    ///
    /// The rendered model is a spring `k (p − s)` between the plane `p` and the handle's
    /// position `s` along the normal, storing `½ k (p − s)²`. Its updates are passive
    /// unless paid for: a stiffness change keeps the stored energy (the plane moves in
    /// when the stiffness rises, out when it falls), the plane moves in at once (energy is
    /// lost, not made), moves out freely up to the handle (nothing is stored), and beyond
    /// the handle — compressing the spring further, which pushes the handle out — only at
    /// the plane rate and only as far as `budget_n_mm` pays for.
    pub fn force_at(
        &mut self,
        mp: &ModelParams,
        desired_mm: &[f64; 3],
        k_max_slave: f64,
        dt_s: f64,
        budget_n_mm: f64,
    ) -> [f64; 3] {
        if !self.plane_valid || !self.has_normal {
            self.force_n = 0.0;
            self.used_valid = false;
            return [0.0; 3];
        }
        // Stiffness from the commanded position to the force: the surface in series with
        // the slave's servo compliance.
        let k_series = 1.0 / (1.0 / self.k_est(mp) + self.servo_mm_per_n);
        let k_r = k_series.min(k_max_slave).max(1e-3);
        let p_r = if self.contact {
            // The model gives the measured force where the slave would be commanded to
            // measure it.
            self.s_meas - self.servo_mm_per_n * self.f_meas + self.f_meas / k_r
        } else {
            self.plane
        };
        let s_d = self.along_normal(desired_mm);
        if self.used_valid && self.p_used > s_d && self.k_used > 0.0 {
            // Same stored energy with the new stiffness.
            self.p_used = s_d + (self.p_used - s_d) * (self.k_used / k_r).sqrt();
        }
        self.k_used = k_r;
        if !self.used_valid {
            self.p_used = p_r.min(s_d);
            self.used_valid = true;
        } else if p_r <= self.p_used {
            self.p_used = p_r;
        } else {
            let free = self.p_used.max(s_d);
            let mut p = p_r.min((self.p_used + mp.plane_rate_mm_per_s * dt_s).max(s_d));
            if p > free {
                let d0 = free - s_d;
                let d_max = (d0 * d0 + 2.0 * budget_n_mm.max(0.0) / k_r).sqrt();
                p = p.min(s_d + d_max);
            }
            self.p_used = p.max(self.p_used);
        }
        let f = (k_r * (self.p_used - s_d)).max(0.0);
        self.force_n = f;
        [f * self.normal[0], f * self.normal[1], f * self.normal[2]]
    }
}

/// The commanded and measured slave positions agree within this when the servo
/// compliance is learnt (more: drift or a force guard), mm.
const SERVO_AGREEMENT_MM: f64 = 0.3;

/// Largest servo compliance the model accepts, mm/N.
const SERVO_COMPLIANCE_MAX_MM_PER_N: f64 = 0.02;

/// The slave this far beyond the remembered surface with no force: the surface is gone, mm.
const PLANE_GONE_MM: f64 = 0.5;

/// Time constant of the contact model's normal estimate, s.
const NORMAL_TIME_CONSTANT_S: f64 = 2.0;

#[cfg(test)]
mod tests {
    use super::*;

    /// Feedback with the slave measured at `z_mm` (a servo compliance of 0.002 mm/N
    /// behind the commanded position) under a force `z_force_n`.
    fn feedback(seq: u64, z_force_n: f64, z_mm: f64) -> Feedback {
        Feedback {
            seq,
            send_time_ns: seq * 1_000_000,
            echo_seq: seq,
            pose: [0.0, 0.0, z_mm, 0.0],
            wrench_measured: [0.0, 0.0, z_force_n, 0.0],
            ..Feedback::default()
        }
    }

    /// The model learns a 100 N/mm plane from commanded positions and measured forces,
    /// renders it locally, keeps it out of contact, forgets it when the slave is seen
    /// beyond it without a force, and never pushes the handle out faster than the plane
    /// rate.
    #[test]
    fn contact_model_learns_renders_and_forgets_a_plane() {
        let mp = ModelParams {
            enabled: true,
            ..ModelParams::default()
        };
        let wall = |z: f64| (100.0 * (-250.0 - z)).max(0.0);
        let mut m = ContactModel::default();
        let mut seq = 0;
        // Pressing in slowly: the commanded position 0.001 mm per message down to about
        // 0.2 mm deep; the measured one lags it by the servo compliance (the force makes
        // the position it is measured at: solved by a few fixed-point steps).
        let servo = 0.002;
        let mut z_cmd = -249.9;
        let mut z_meas = z_cmd;
        while z_cmd > -250.25 {
            for _ in 0..20 {
                z_meas = z_cmd + servo * wall(z_meas);
            }
            seq += 1;
            m.observe(&mp, &feedback(seq, wall(z_meas), z_meas), [0.0, 0.0, z_cmd]);
            z_cmd -= 0.001;
        }
        // Held there for a second (the estimator's time constant is 0.3 s).
        for _ in 0..1000 {
            seq += 1;
            m.observe(&mp, &feedback(seq, wall(z_meas), z_meas), [0.0, 0.0, z_cmd]);
        }
        assert!((m.k_hat - 100.0).abs() < 10.0, "{}", m.k_hat);
        assert!(
            (m.servo_mm_per_n - servo).abs() < 5e-4,
            "{}",
            m.servo_mm_per_n
        );
        assert!(m.valid());
        // Rendered where the handle is above the plane: nothing; commanded 0.12 mm deep:
        // the series stiffness (100 N/mm with 0.002 mm/N: 83 N/mm), ~10 N.
        let dt = 1e-3;
        let f = m.force_at(&mp, &[0.0, 0.0, -249.0], 1e3, dt, f64::INFINITY);
        assert_eq!(f, [0.0; 3]);
        let f = m.force_at(&mp, &[0.0, 0.0, -250.12], 1e3, dt, f64::INFINITY);
        assert!((f[2] - 10.0).abs() < 1.5, "{f:?}");
        // Lifted off: the plane is remembered.
        seq += 1;
        m.observe(&mp, &feedback(seq, 0.0, -249.0), [0.0, 0.0, -249.0]);
        let f = m.force_at(&mp, &[0.0, 0.0, -250.12], 1e3, dt, f64::INFINITY);
        assert!((f[2] - 10.0).abs() < 1.5, "{f:?}");
        // Placed again at the handle (e.g. after a feedback gap): the force grows only at
        // the plane rate while the handle holds still.
        m.reset_used();
        let f0 = m.force_at(&mp, &[0.0, 0.0, -250.12], 1e3, dt, f64::INFINITY)[2];
        let f1 = m.force_at(&mp, &[0.0, 0.0, -250.12], 1e3, dt, f64::INFINITY)[2];
        assert!(f0.abs() < 1e-9, "{f0}");
        assert!(f1 <= 100.0 * mp.plane_rate_mm_per_s * dt + 1e-9, "{f1}");
        // With no energy to pay for it, a plane that would push the handle out does not
        // move out (the force does not grow), and a stiffer estimate keeps the stored
        // energy (the force grows only with the square root of the stiffness ratio).
        m.reset_used();
        let _ = m.force_at(&mp, &[0.0, 0.0, -250.12], 1e3, dt, 0.0);
        for _ in 0..100 {
            let f = m.force_at(&mp, &[0.0, 0.0, -250.12], 1e3, dt, 0.0)[2];
            assert!(f.abs() < 1e-9, "{f}");
        }
        // The rendered plane lags the surface by the handle's depth: the slave is told to
        // stay that much out of it.
        let o = m.offset_mm();
        assert!(o[2] > 0.0 && o[0] == 0.0, "{o:?}");
        let f_budget = m.force_at(&mp, &[0.0, 0.0, -250.12], 1e3, dt, 1.0)[2];
        let k = m.k_hat;
        assert!(f_budget > 0.0, "{f_budget}");
        // The energy stored, f² / 2k_r, is at most the 1 N·mm budget (k_r ≤ k_hat).
        assert!(f_budget <= (2.0 * k).sqrt() + 1e-9, "{f_budget} {k}");
        // The slave is seen 1 mm beyond the plane with no force: the surface is gone.
        seq += 1;
        m.observe(&mp, &feedback(seq, 0.0, -251.0), [0.0, 0.0, -251.0]);
        assert!(!m.valid());
        assert_eq!(
            m.force_at(&mp, &[0.0, 0.0, -250.12], 1e3, dt, f64::INFINITY),
            [0.0; 3]
        );
    }

    /// A surface remembered a little too far out does not hold the slave off it for ever:
    /// the slave measured beyond it with no force moves it in, and the offset with it. A new
    /// touch elsewhere along the normal leaves the rendered plane where it is in space (no
    /// force step at the handle).
    #[test]
    fn contact_model_corrects_the_surface_and_keeps_the_plane_across_touches() {
        let mp = ModelParams {
            enabled: true,
            ..ModelParams::default()
        };
        let dt = 1e-3;
        let mut m = ContactModel::default();
        // A blind touch: first felt at -250.02, then pressed to 20 N at -250.2, while the
        // handle is already at -252: the rendered plane is placed at the handle and the
        // slave is to stay out of the surface by the lag.
        m.observe(&mp, &feedback(1, 2.0, -250.02), [0.0, 0.0, -250.02]);
        m.observe(&mp, &feedback(2, 20.0, -250.2), [0.0, 0.0, -250.2]);
        assert!(m.valid());
        let f = m.force_at(&mp, &[0.0, 0.0, -252.0], 1e3, dt, 0.0);
        assert!(f[2].abs() < 1e-9, "{f:?}");
        let o0 = m.offset_mm()[2];
        assert!((o0 - 1.98).abs() < 1e-9, "{o0}");
        // Held out, the slave feels nothing at -250.0; then it is seen at -250.1 with no
        // force: the surface is at least that far in.
        m.observe(&mp, &feedback(3, 0.0, -250.0), [0.0, 0.0, -250.0]);
        assert!((m.offset_mm()[2] - o0).abs() < 1e-9);
        m.observe(&mp, &feedback(4, 0.0, -250.1), [0.0, 0.0, -250.1]);
        let o1 = m.offset_mm()[2];
        assert!((o1 - 1.9).abs() < 1e-9, "{o1}");
        // The handle presses 0.05 mm into the rendered plane; a new touch at -250.15
        // (the origin of the along-normal coordinates moves there) changes nothing at the
        // handle, and the offset is measured from the new touch point.
        let f0 = m.force_at(&mp, &[0.0, 0.0, -252.05], 1e3, dt, 0.0)[2];
        assert!(f0 > 1.0, "{f0}");
        m.observe(&mp, &feedback(5, 2.0, -250.15), [0.0, 0.0, -250.15]);
        let f1 = m.force_at(&mp, &[0.0, 0.0, -252.05], 1e3, dt, 0.0)[2];
        assert!((f1 - f0).abs() < 1e-9, "{f0} {f1}");
        let o2 = m.offset_mm()[2];
        assert!((o2 - 1.85).abs() < 1e-9, "{o2}");
    }
}
