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
    /// Arm id in the commands.
    pub arm_id: u16,
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
    local_n: [f64; 3],
    filtered_n: [f64; 3],
}

fn norm3(v: &[f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

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
            local_n: [0.0; 3],
            filtered_n: [0.0; 3],
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

    /// Hands the coupling a feedback message the gate accepted at `now_ns`.
    pub fn receive(&mut self, fb: &Feedback, now_ns: u64) {
        self.port.receive_remote_in(fb.energy_in_j * self.kappa());
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
        self.fade = if silent_ms > p.feedback_timeout_ms {
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
            if p.mode == CouplingMode::PositionForce
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
        self.velocity = vel;
        let pc = self.port.step(link_force, v_m, dt_s, p.passivity);
        let mut force = pc.force_n;
        let mut local = [0.0; 3];
        if p.mode == CouplingMode::PositionForce && !self.clutched {
            // Faded with the feedback: with no slave there is no loop to stabilise, and the
            // operator holds a free handle (the feedback-loss safe state renders nothing).
            for i in 0..3 {
                local[i] = -p.master_damping_n_s_per_mm * self.fade * v_m[i];
                force[i] += local[i];
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
            for l in local.iter_mut() {
                *l *= s;
            }
            step.saturated = true;
        }
        self.local_n = local;
        step.wrench = [force[0], force[1], force[2], 0.0];
        step.link_force_n = link_force;
        step.damping_n_s_per_mm = pc.damping_n_s_per_mm;
        step.observed_j = pc.observed_j;
        step.fade = self.fade;
        step.slave_target = target;
        self.last = step;
        step
    }

    /// Books the wrench the device applied (after its own limits) against the measured
    /// velocity, and returns the command to send, stamped `now_ns`.
    pub fn finish(
        &mut self,
        applied: &[f64; 4],
        dev: &DeviceState,
        now_ns: u64,
        dt_s: f64,
    ) -> Command {
        let v_m = [dev.velocity[0], dev.velocity[1], dev.velocity[2]];
        // Only the link's share of the force passes through the two-port: in force-guided
        // mode the local spring is not the link's.
        let link = if self.p.mode == CouplingMode::PositionForce {
            [
                applied[0] - self.local_n[0],
                applied[1] - self.local_n[1],
                applied[2] - self.local_n[2],
            ]
        } else {
            [0.0; 3]
        };
        self.port.commit(link, v_m, dt_s);
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
