//! The master's coupling: a pure 1 kHz step from the device's state and the latest slave
//! feedback to the command sent and the wrench rendered. No clock reads, no I/O, no
//! allocation.
//!
//! * **Position–force**: the slave follows `slave_anchor + scale.motion · (x_master −
//!   master_anchor)`; the master renders `scale.force · F_slave` through the master port's
//!   passivity controller ([`h4_shared::passivity::ImpedancePort`]).
//! * **Force-guided** (cutting): the master's motion along the surface moves the slave along
//!   it; the operator sets the contact-force set-point by pushing the handle into a local
//!   virtual spring along the contact normal (`guide_stiffness_n_per_mm`): the set-point is
//!   the spring's force divided by `scale.force`, and the spring's force is what the hand
//!   feels. Nothing measured at the slave is rendered through the link, so the link closes
//!   no loop in this mode.
//! * **Clutch / indexing**: while the clutch is held the slave holds and nothing is
//!   rendered; on release the anchors are reset so the slave target does not jump.
//! * **Workspace mapping**: a target outside the slave's workspace is pulled back (by
//!   bisection) to the last point inside it on the way there.
//! * **Saturation**: the rendered force is limited to `force_limit_n` keeping its direction
//!   (passive), and faded to zero when feedback stops arriving.

use h4_shared::kinematics::{Pose, Workspace};
use h4_shared::vec3::{dot3, norm3};
use h4_shared::wire::{CMD_FLAG_CLUTCH, Command, Feedback, Mode, PROTOCOL_VERSION};
use serde::{Deserialize, Serialize};

use crate::device::DeviceState;
use h4_shared::passivity::ImpedancePort;

/// Coupling mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CouplingMode {
    /// The slave follows the master's pose; the master renders the slave's force.
    PositionForce,
    /// The master guides motion along the surface and sets the contact force by pushing.
    ForceGuided,
}

/// Parameters of the coupling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CouplingParams {
    /// Mode.
    pub mode: CouplingMode,
    /// Slave motion per master motion (translation).
    pub motion_scale: f64,
    /// Master force per slave force.
    pub force_scale: f64,
    /// The slave's workspace (targets are mapped into it).
    pub slave_workspace: Workspace,
    /// Slave pose that corresponds to the master's start pose.
    pub slave_anchor: [f64; 4],
    /// Largest force rendered, N.
    pub force_limit_n: f64,
    /// Largest slave speed commanded, mm/s (below the slave's speed limit).
    pub slave_speed_limit_mm_per_s: f64,
    /// Feedback silence after which the rendered force fades, ms.
    pub feedback_timeout_ms: f64,
    /// Time the fade takes, ms.
    pub fade_ms: f64,
    /// Passivity controller on (the observer always runs).
    pub passivity: bool,
    /// The master port's passivity controller settings (damping cap, release, reserve).
    pub passivity_params: h4_shared::passivity::PassivityParams,
    /// Force-guided: stiffness of the virtual spring the operator pushes, N/mm.
    pub guide_stiffness_n_per_mm: f64,
    /// Force-guided: largest set-point, N.
    pub guide_setpoint_max_n: f64,
    /// Force-guided: how far beyond the surface the slave's approach target lies, mm.
    pub guide_approach_depth_mm: f64,
    /// Local damping the master renders against the handle's velocity, N·s/mm (position–
    /// force mode; passive, not part of the link's two-port).
    pub master_damping_n_s_per_mm: f64,
    /// Cut-off of the low-pass on the rendered slave force, Hz (0: unfiltered).
    pub force_filter_hz: f64,
    /// Model-mediated rendering (position–force): the master renders a local model of the
    /// slave's contact instead of the delayed measured force.
    pub model: ModelParams,
    /// Arm id in the commands.
    pub arm_id: u16,
}

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

/// One cycle of the master.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MasterStep {
    /// Wrench to write to the device, `[Fx, Fy, Fz, My]`.
    pub wrench: [f64; 4],
    /// Force the link asked to render before the passivity controller and saturation, N.
    pub link_force_n: [f64; 3],
    /// Damping the passivity controller added, N·s/mm.
    pub damping_n_s_per_mm: f64,
    /// The master port's observer, J.
    pub observed_j: f64,
    /// Feedback fade factor (1: feedback fresh, 0: faded out).
    pub fade: f64,
    /// Slave target this cycle.
    pub slave_target: [f64; 4],
    /// Force-guided set-point, N.
    pub setpoint_n: f64,
    /// The target was pulled back into the slave's workspace.
    pub workspace_limited: bool,
    /// The rendered force was limited.
    pub saturated: bool,
}

/// The master's coupling state.
#[derive(Clone, Debug)]
pub struct MasterCoupling {
    p: CouplingParams,
    /// The master port's passivity observer and controller.
    pub port: ImpedancePort,
    master_anchor: [f64; 4],
    slave_anchor: [f64; 4],
    last_target: [f64; 4],
    clutched: bool,
    started: bool,
    seq: u64,
    fade: f64,
    last_feedback_ns: Option<u64>,
    feedback: Option<Feedback>,
    normal: [f64; 3],
    last: MasterStep,
    velocity: [f64; 3],
    /// The handle position at the start of the last cycle and the link force held over it
    /// (booked by the port once the cycle's displacement is known).
    disp_prev: Option<([f64; 3], [f64; 3])>,
    offset_mm: [f64; 3],
    filtered_n: [f64; 3],
    /// The local contact model (model-mediated rendering).
    pub model: ContactModel,
    /// The slave targets sent, by sequence number (ring; allocated once).
    sent: Vec<(u64, [f64; 3])>,
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

/// Commands remembered for the contact model (≥ the longest round trip in cycles).
const SENT_HISTORY: usize = 8192;

impl MasterCoupling {
    /// A coupling; the master's first reading becomes its anchor.
    pub fn new(p: CouplingParams) -> Self {
        MasterCoupling {
            port: ImpedancePort::from_params(&p.passivity_params),
            master_anchor: [0.0; 4],
            slave_anchor: p.slave_anchor,
            last_target: p.slave_anchor,
            clutched: false,
            started: false,
            seq: 0,
            fade: 0.0,
            last_feedback_ns: None,
            feedback: None,
            normal: [0.0, 0.0, 1.0],
            last: MasterStep::default(),
            velocity: [0.0; 3],
            disp_prev: None,
            offset_mm: [0.0; 3],
            filtered_n: [0.0; 3],
            model: ContactModel::default(),
            sent: vec![(0, [0.0; 3]); SENT_HISTORY],
            p,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &CouplingParams {
        &self.p
    }

    /// Speaks for another arm: its commands carry `arm_id`.
    pub fn set_arm_id(&mut self, arm_id: u16) {
        self.p.arm_id = arm_id;
    }

    /// κ = force scale / motion scale: slave energy × κ = master energy.
    pub fn kappa(&self) -> f64 {
        self.p.force_scale / self.p.motion_scale
    }

    /// The offset added to this cycle's slave target by the contact model
    /// ([`ContactModel::offset_mm`]), slave frame, mm: part of the master–slave position
    /// mismatch.
    pub fn model_offset_mm(&self) -> [f64; 3] {
        self.offset_mm
    }

    /// Hands the coupling a feedback message the gate accepted at `now_ns`.
    pub fn receive(&mut self, fb: &Feedback, now_ns: u64) {
        self.port.receive_remote_in(fb.energy_in_j * self.kappa());
        let slot = &self.sent[(fb.echo_seq % SENT_HISTORY as u64) as usize];
        if slot.0 == fb.echo_seq && fb.echo_seq > 0 {
            self.model.observe(&self.p.model, fb, slot.1);
        }
        self.feedback = Some(*fb);
        self.last_feedback_ns = Some(now_ns);
    }

    fn map_into_workspace(&self, target: [f64; 4]) -> ([f64; 4], bool) {
        let ws = &self.p.slave_workspace;
        if ws.ik(&Pose::from(target)).is_ok() {
            return (target, false);
        }
        let from = self.last_target;
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..12 {
            let mid = 0.5 * (lo + hi);
            let mut p = [0.0; 4];
            for i in 0..4 {
                p[i] = from[i] + (target[i] - from[i]) * mid;
            }
            if ws.ik(&Pose::from(p)).is_ok() {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let mut p = [0.0; 4];
        for i in 0..4 {
            p[i] = from[i] + (target[i] - from[i]) * lo;
        }
        (p, true)
    }

    /// One cycle at `now_ns`: returns the wrench to write. Call [`MasterCoupling::finish`]
    /// with the wrench the device actually applied to get the command to send.
    pub fn step(&mut self, dev: &DeviceState, now_ns: u64, dt_s: f64) -> MasterStep {
        let p = self.p;
        if !self.started {
            self.master_anchor = dev.pose;
            self.started = true;
        }
        let mut step = MasterStep::default();
        // Feedback freshness: fade out after the timeout, back in when it returns.
        let silent_ms = self
            .last_feedback_ns
            .map_or(f64::INFINITY, |t| now_ns.saturating_sub(t) as f64 * 1e-6);
        let rate = dt_s * 1e3 / p.fade_ms.max(1e-3);
        // The local model needs no fresh feedback to render the contact: it holds through
        // a longer silence than the delayed force would.
        let timeout_ms = if p.mode == CouplingMode::PositionForce && p.model.enabled {
            p.model.hold_ms
        } else {
            p.feedback_timeout_ms
        };
        self.fade = if silent_ms > timeout_ms {
            (self.fade - rate).max(0.0)
        } else {
            (self.fade + rate).min(1.0)
        };
        // Clutch and indexing.
        let clutch = dev.clutch;
        if clutch {
            self.clutched = true;
        } else if self.clutched {
            self.clutched = false;
            self.master_anchor = dev.pose;
            self.slave_anchor = self.last_target;
        }
        let v_m = [dev.velocity[0], dev.velocity[1], dev.velocity[2]];
        if let Some(fb) = &self.feedback {
            let wd = [
                fb.wrench_desired[0],
                fb.wrench_desired[1],
                fb.wrench_desired[2],
            ];
            let n = norm3(&wd);
            if n > 1e-3 {
                self.normal = [wd[0] / n, wd[1] / n, wd[2] / n];
            }
        }
        let mut link_force = [0.0; 3];
        let mut offset = [0.0; 3];
        let mut target = self.last_target;
        let mut vel = [0.0; 3];
        if !self.clutched {
            let mut t = [0.0; 4];
            for i in 0..3 {
                t[i] =
                    self.slave_anchor[i] + p.motion_scale * (dev.pose[i] - self.master_anchor[i]);
                vel[i] = p.motion_scale * v_m[i];
            }
            t[3] = self.slave_anchor[3] + (dev.pose[3] - self.master_anchor[3]);
            if p.mode == CouplingMode::ForceGuided {
                // Along the normal the slave's force loop rules: keep the target's normal
                // component at the anchor's, beyond the surface by the approach depth.
                let n = self.normal;
                let d: [f64; 3] = [
                    t[0] - self.slave_anchor[0],
                    t[1] - self.slave_anchor[1],
                    t[2] - self.slave_anchor[2],
                ];
                let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
                let vn = vel[0] * n[0] + vel[1] * n[1] + vel[2] * n[2];
                for i in 0..3 {
                    t[i] -= n[i] * (dn + p.guide_approach_depth_mm);
                    vel[i] -= n[i] * vn;
                }
            }
            let (mapped, limited) = self.map_into_workspace(t);
            target = mapped;
            step.workspace_limited = limited;
            if limited {
                vel = [0.0; 3];
            }
            let speed = norm3(&vel);
            if speed > p.slave_speed_limit_mm_per_s {
                let s = p.slave_speed_limit_mm_per_s / speed;
                for v in vel.iter_mut() {
                    *v *= s;
                }
            }
            if p.mode == CouplingMode::PositionForce && p.model.enabled && self.model.valid() {
                if self.fade < 1.0 {
                    // Feedback silent: on its return the plane is placed where the handle
                    // is and moves out only at the plane rate (no force step).
                    self.model.reset_used();
                }
                let k_max_slave = p.model.stiffness_max_n_per_mm / (p.force_scale * p.motion_scale);
                let d = [target[0], target[1], target[2]];
                // What the model's update may put into the handle this cycle: a share of
                // the observer's surplus (none without a surplus), in slave units.
                let budget_n_mm = if p.passivity {
                    let share = p.passivity_params.drift_energy_share;
                    (self.port.observed_j() - p.passivity_params.energy_reserve_j).max(0.0)
                        * share
                        * 1e3
                        / (self.kappa() * self.fade.max(1e-3))
                } else {
                    f64::INFINITY
                };
                let f = self
                    .model
                    .force_at(&p.model, &d, k_max_slave, dt_s, budget_n_mm);
                // Along the normal only: friction along the surface is not rendered (the
                // delayed measured friction, tried, made the handle wander sideways).
                for (lf, fi) in link_force.iter_mut().zip(f.iter()) {
                    *lf = p.force_scale * fi * self.fade;
                }
                let o = self.model.offset_mm();
                if o != [0.0; 3] {
                    let shifted = [
                        target[0] + o[0],
                        target[1] + o[1],
                        target[2] + o[2],
                        target[3],
                    ];
                    if p.slave_workspace.ik(&Pose::from(shifted)).is_ok() {
                        target = shifted;
                        offset = o;
                    }
                }
            } else if p.mode == CouplingMode::PositionForce
                && let Some(fb) = &self.feedback
            {
                for (lf, w) in link_force.iter_mut().zip(fb.wrench_measured.iter()) {
                    *lf = p.force_scale * w * self.fade;
                }
            }
        }
        // First-order low-pass of the force to render (the sensor's noise and the contact's
        // high-frequency content are not rendered; a filter is passive-neutral here since the
        // port observes the force actually applied).
        if p.force_filter_hz > 0.0 {
            let a = 1.0 - (-2.0 * std::f64::consts::PI * p.force_filter_hz * dt_s).exp();
            for (f, lf) in self.filtered_n.iter_mut().zip(link_force.iter_mut()) {
                *f += a * (*lf - *f);
                *lf = *f;
            }
        }
        self.last_target = target;
        self.offset_mm = offset;
        self.velocity = vel;
        // `passivity.damping_step_fraction` (0: off): the passivity controller's damping,
        // with the local damping, stays within what the handle's mass takes in one cycle
        // (discrete-time bound).
        let frac = p.passivity_params.damping_step_fraction;
        self.port.damping_step_limit_n_s_per_mm = if frac > 0.0 && dev.effective_mass_kg > 0.0 {
            let local = if p.mode == CouplingMode::PositionForce && !self.clutched {
                p.master_damping_n_s_per_mm * self.fade
            } else {
                0.0
            };
            Some((frac * dev.effective_mass_kg * 1e-3 / dt_s - local).max(0.0))
        } else {
            None
        };
        let pc = self.port.step(link_force, v_m, dt_s, p.passivity);
        let mut force = pc.force_n;
        if p.mode == CouplingMode::PositionForce && !self.clutched {
            // Faded with the feedback: with no slave there is no loop to stabilise, and the
            // operator holds a free handle (the feedback-loss safe state renders nothing).
            for (f, v) in force.iter_mut().zip(v_m.iter()) {
                *f -= p.master_damping_n_s_per_mm * self.fade * v;
            }
        }
        // Force-guided: the local virtual spring sets the set-point.
        if p.mode == CouplingMode::ForceGuided && !self.clutched {
            let n = self.normal;
            let depth = -((dev.pose[0] - self.master_anchor[0]) * n[0]
                + (dev.pose[1] - self.master_anchor[1]) * n[1]
                + (dev.pose[2] - self.master_anchor[2]) * n[2]);
            let spring = (p.guide_stiffness_n_per_mm * depth)
                .clamp(0.0, p.force_scale * p.guide_setpoint_max_n);
            for i in 0..3 {
                force[i] += spring * n[i];
            }
            step.setpoint_n = spring / p.force_scale;
        }
        let fmag = norm3(&force);
        if fmag > p.force_limit_n {
            let s = p.force_limit_n / fmag;
            for f in force.iter_mut() {
                *f *= s;
            }
            step.saturated = true;
        }
        step.wrench = [force[0], force[1], force[2], 0.0];
        step.link_force_n = link_force;
        step.damping_n_s_per_mm = pc.damping_n_s_per_mm;
        step.observed_j = pc.observed_j;
        step.fade = self.fade;
        step.slave_target = target;
        self.last = step;
        step
    }

    /// Books the link force of the previous cycle against the handle's displacement since
    /// (`dev` is this cycle's reading), keeps the wrench the device applied this cycle
    /// (after its own limits) for the next, and returns the command to send, stamped
    /// `now_ns`.
    pub fn finish(&mut self, applied: &[f64; 4], dev: &DeviceState, now_ns: u64) -> Command {
        // Position–force: all of the applied force (the local damping included) is the
        // master port's. Force-guided: the local spring is not the link's, and the link
        // renders nothing.
        let link = if self.p.mode == CouplingMode::PositionForce {
            [applied[0], applied[1], applied[2]]
        } else {
            [0.0; 3]
        };
        // The link force of the previous cycle, held over it, did `F · Δx` on the handle.
        let x = [dev.pose[0], dev.pose[1], dev.pose[2]];
        if let Some((x0, f0)) = self.disp_prev {
            self.port
                .commit_displacement(f0, [x[0] - x0[0], x[1] - x0[1], x[2] - x0[2]]);
        }
        self.disp_prev = Some((x, link));
        self.seq += 1;
        let mode = if self.clutched {
            Mode::Hold
        } else {
            match self.p.mode {
                CouplingMode::PositionForce => Mode::Position,
                CouplingMode::ForceGuided => Mode::ForceGuided,
            }
        };
        let t = self.last.slave_target;
        self.sent[(self.seq % SENT_HISTORY as u64) as usize] = (self.seq, [t[0], t[1], t[2]]);
        Command {
            seq: self.seq,
            send_time_ns: now_ns,
            pose: t,
            velocity: [self.velocity[0], self.velocity[1], self.velocity[2], 0.0],
            force_setpoint_n: self.last.setpoint_n,
            // On the wire in slave units (the slave needs no scaling).
            energy_in_j: self.port.energy.in_j / self.kappa(),
            energy_out_j: self.port.energy.out_j / self.kappa(),
            protocol_version: PROTOCOL_VERSION,
            arm_id: self.p.arm_id,
            mode: mode as u8,
            reserved: 0,
            flags: if self.clutched { CMD_FLAG_CLUTCH } else { 0 },
        }
    }
}

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
