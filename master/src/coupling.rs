//! The master's coupling: a pure 1 kHz step from the device's state and the latest slave
//! feedback to the command sent and the wrench rendered. No clock reads, no I/O, no
//! allocation.
//!
//! * **Position–force**: the slave target (slave frame) follows `slave_anchor_pose +
//!   scale.motion · (handle_pose − handle_anchor_pose)` (handle: master frame; the two
//!   frames' axes are aligned); the master renders `scale.force · F_slave` through the master port's
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

use h4_shared::config::{ConfigError, Section, check_range};
use h4_shared::kinematics::{Pose, Workspace};
use h4_shared::vec3::norm3;
use h4_shared::wire::{
    CMD_FLAG_ACK_SAFE_STOP, CMD_FLAG_CLUTCH, Command, Feedback, Mode, PROTOCOL_VERSION, SlaveState,
};
use serde::{Deserialize, Serialize};

use h4_shared::passivity::{ImpedancePort, PassivityParams};

pub use crate::contact_model::{ContactModel, ModelParams};
use crate::device::DeviceState;

/// Coupling mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum CouplingMode {
    /// The slave follows the master's pose; the master renders the slave's force.
    PositionForce,
    /// The master guides motion along the surface and sets the contact force by pushing.
    ForceGuided,
}

/// The coupling.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CouplingConfig {
    /// `position-force` or `force-guided`.
    pub mode: CouplingMode,
    /// Largest force rendered to the operator, N.
    pub force_limit_n: f64,
    /// Feedback silence after which the rendered force fades, ms.
    pub feedback_timeout_ms: f64,
    /// Duration of the fade, ms.
    pub fade_ms: f64,
    /// Force-guided: stiffness of the virtual spring the operator pushes, N/mm.
    pub guide_stiffness_n_per_mm: f64,
    /// Force-guided: largest contact-force set-point, N.
    pub guide_setpoint_max_n: f64,
    /// Force-guided: how far beyond the surface the slave's approach target lies, mm.
    pub guide_approach_depth_mm: f64,
    /// Local damping the master renders against the handle's velocity (position–force),
    /// N·s/mm.
    pub master_damping_n_s_per_mm: f64,
    /// Extra local damping while the slave reports a contact held by its force loop (its
    /// desired wrench is not zero), N·s/mm: the delayed virtual wall of the slave's contact
    /// hand-over needs more damping at the handle than free motion should feel.
    pub contact_damping_n_s_per_mm: f64,
    /// Position–force: while the feedback is lost or the slave is in its safe stop the
    /// local damping stays on (a viscous brake: the operator's push does not run the
    /// handle away while the slave holds; damping only dissipates). Off: it fades with the
    /// feedback and the handle is free.
    pub brake_on_loss: bool,
    /// Cut-off of the first-order low-pass on the slave force rendered (position–force), Hz
    /// (0: unfiltered). 40 Hz halves the sensor's noise above 20 Hz at the handle (0.032 to
    /// 0.013 N RMS in a wall-push hold) for 4 ms of lag, but tips one more long-delay metal
    /// cell into the hand-over's slow oscillation
    /// (`a_told_round_trip_steadies_the_hand_over_on_metal_over_long_links`); 20 Hz let the
    /// second wall-push hold at 100 ms round trip oscillate. Off by default.
    pub force_filter_hz: f64,
    /// The local damping (`master_damping_n_s_per_mm`, `contact_damping_n_s_per_mm`)
    /// acts on the handle's mean velocity over the shortest window, of at least 3 and at most
    /// 32 cycles, in which it has moved this far, mm (0: on the device's velocity as it is).
    /// At rest or creeping the encoders' quantised velocity flickers by a count per cycle
    /// (0.002 mm in 1 ms through the device's 50 Hz velocity filter: up to 0.54 mm/s); damped
    /// as it is, the 1.0 N·s/mm of a wall-push hold rendered it as 0.25 N RMS above 20 Hz,
    /// eight times the slave force's noise. The window (adaptive windowing, after Brown,
    /// Schneider and Mulligan's and Janabi-Sharifi, Hayward and Chen's encoder velocity
    /// estimators) is long only when the handle is slow, so fast motion is damped with a
    /// 3 ms mean's lag (a 10 Hz low-pass on the damped velocity, tried, made the 0 ms hold
    /// on resin unstable, and a dead band let a creeping hold oscillate at 100 ms).
    pub damping_window_mm: f64,
    /// Force-guided: share of the slave's measured force along the feed (the cutting
    /// resistance: its component against the direction the tool is guided along the
    /// surface) rendered at the handle, × `scale.force`, through the master port's
    /// passivity controller (0 to 1; 0: nothing from the slave is rendered).
    #[serde(skip_serializing_if = "is_zero")]
    #[schemars(!skip_serializing_if)]
    pub feed_force_gain: f64,
    /// Model-mediated rendering (position–force): a local model of the slave's contact.
    pub model: bool,
    /// Largest stiffness the local model renders at the handle, N/mm.
    pub model_stiffness_max_n_per_mm: f64,
    /// Stiffness the model assumes before its first estimate, N/mm at the slave.
    pub model_stiffness_initial_n_per_mm: f64,
    /// Slave force above which feedback counts as contact for the model, N.
    pub model_contact_n: f64,
    /// Forgetting time constant of the model's stiffness estimator, s.
    pub model_estimator_time_constant_s: f64,
    /// Largest speed at which the model's plane pushes the handle out, mm/s at the slave.
    pub model_plane_rate_mm_per_s: f64,
    /// Feedback silence after which the model's force fades out, ms.
    pub model_hold_ms: f64,
}

impl Default for CouplingConfig {
    fn default() -> Self {
        CouplingConfig {
            mode: CouplingMode::PositionForce,
            force_limit_n: 30.0,
            feedback_timeout_ms: 100.0,
            fade_ms: 50.0,
            guide_stiffness_n_per_mm: 1.0,
            guide_setpoint_max_n: 50.0,
            guide_approach_depth_mm: 20.0,
            master_damping_n_s_per_mm: 0.3,
            contact_damping_n_s_per_mm: 0.0,
            brake_on_loss: true,
            force_filter_hz: 0.0,
            damping_window_mm: 0.016,
            feed_force_gain: 0.0,
            model: ModelParams::default().enabled,
            model_stiffness_max_n_per_mm: ModelParams::default().stiffness_max_n_per_mm,
            model_stiffness_initial_n_per_mm: ModelParams::default().stiffness_initial_n_per_mm,
            model_contact_n: ModelParams::default().contact_n,
            model_estimator_time_constant_s: ModelParams::default().estimator_time_constant_s,
            model_plane_rate_mm_per_s: ModelParams::default().plane_rate_mm_per_s,
            model_hold_ms: ModelParams::default().hold_ms,
        }
    }
}

/// Motion and force scaling.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ScaleConfig {
    /// Slave translation per master translation.
    pub motion: f64,
    /// Master force per slave force.
    pub force: f64,
}

impl Default for ScaleConfig {
    fn default() -> Self {
        ScaleConfig {
            motion: 1.0,
            force: 0.5,
        }
    }
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Section for CouplingConfig {
    /// The section's own ranges; `guide_setpoint_max_n` is also bounded by the slave's
    /// force limit, a check across sections (`SessionConfig`'s).
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |name: &str| format!("{prefix}{name}");
        check_range(&f("force_limit_n"), self.force_limit_n, 0.0, 200.0, "N")?;
        check_range(&f("feed_force_gain"), self.feed_force_gain, 0.0, 1.0, "")?;
        check_range(
            &f("feedback_timeout_ms"),
            self.feedback_timeout_ms,
            1.0,
            1e5,
            "ms",
        )?;
        check_range(&f("fade_ms"), self.fade_ms, 1.0, 1e4, "ms")?;
        check_range(
            &f("guide_stiffness_n_per_mm"),
            self.guide_stiffness_n_per_mm,
            0.01,
            100.0,
            "N/mm",
        )?;
        check_range(
            &f("guide_setpoint_max_n"),
            self.guide_setpoint_max_n,
            0.0,
            1000.0,
            "N",
        )?;
        check_range(
            &f("master_damping_n_s_per_mm"),
            self.master_damping_n_s_per_mm,
            0.0,
            1.0,
            "N·s/mm",
        )?;
        check_range(
            &f("contact_damping_n_s_per_mm"),
            self.contact_damping_n_s_per_mm,
            0.0,
            1.0,
            "N·s/mm",
        )?;
        check_range(
            &f("force_filter_hz"),
            self.force_filter_hz,
            0.0,
            500.0,
            "Hz",
        )?;
        check_range(
            &f("damping_window_mm"),
            self.damping_window_mm,
            0.0,
            10.0,
            "mm",
        )?;
        check_range(
            &f("model_stiffness_max_n_per_mm"),
            self.model_stiffness_max_n_per_mm,
            0.01,
            1000.0,
            "N/mm",
        )?;
        check_range(
            &f("model_stiffness_initial_n_per_mm"),
            self.model_stiffness_initial_n_per_mm,
            0.01,
            1e4,
            "N/mm",
        )?;
        check_range(
            &f("model_contact_n"),
            self.model_contact_n,
            0.01,
            100.0,
            "N",
        )?;
        check_range(
            &f("model_estimator_time_constant_s"),
            self.model_estimator_time_constant_s,
            0.001,
            100.0,
            "s",
        )?;
        check_range(
            &f("model_plane_rate_mm_per_s"),
            self.model_plane_rate_mm_per_s,
            0.0,
            1e4,
            "mm/s",
        )?;
        check_range(&f("model_hold_ms"), self.model_hold_ms, 1.0, 1e5, "ms")?;
        check_range(
            &f("guide_approach_depth_mm"),
            self.guide_approach_depth_mm,
            0.0,
            100.0,
            "mm",
        )
    }
}

impl Section for ScaleConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        check_range(&format!("{prefix}motion"), self.motion, 0.01, 100.0, "")?;
        check_range(&format!("{prefix}force"), self.force, 0.01, 100.0, "")
    }
}

/// Parameters of the coupling: the session's `[coupling]`, `[scale]` and `[passivity]`
/// sections as given (one struct per section, not copied field by field), and what the
/// endpoint adds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CouplingParams {
    /// The `[coupling]` section.
    pub config: CouplingConfig,
    /// The `[scale]` section: slave motion per master motion, master force per slave force.
    pub scale: ScaleConfig,
    /// The master port's passivity controller settings (`[passivity]`; the observer always
    /// runs, the controller when `enabled`).
    pub passivity_params: PassivityParams,
    /// The slave's workspace (targets are mapped into it).
    pub slave_workspace: Workspace,
    /// Slave pose that corresponds to the master's start pose.
    pub slave_anchor_pose: [f64; 4],
    /// Largest slave speed commanded, mm/s (below the slave's speed limit).
    pub slave_speed_limit_mm_per_s: f64,
    /// Model-mediated rendering (position–force), the contact model's parameters from the
    /// section's `model*` keys.
    pub model: ModelParams,
    /// Arm id in the commands.
    pub arm_id: u16,
}

impl CouplingParams {
    /// The coupling of the sections `coupling`, `scale` and `passivity` of a session file,
    /// mapping into `slave_workspace` with the master's home at `slave_anchor_pose` (slave
    /// frame), commanding at most `slave_speed_limit_mm_per_s`, for arm `arm_id`.
    pub fn from_config(
        c: &CouplingConfig,
        scale: &ScaleConfig,
        passivity: &PassivityParams,
        slave_workspace: Workspace,
        slave_anchor_pose: [f64; 4],
        slave_speed_limit_mm_per_s: f64,
        arm_id: u16,
    ) -> Self {
        CouplingParams {
            config: *c,
            scale: *scale,
            passivity_params: *passivity,
            slave_workspace,
            slave_anchor_pose,
            slave_speed_limit_mm_per_s,
            model: ModelParams {
                enabled: c.model,
                stiffness_max_n_per_mm: c.model_stiffness_max_n_per_mm,
                stiffness_initial_n_per_mm: c.model_stiffness_initial_n_per_mm,
                contact_n: c.model_contact_n,
                estimator_time_constant_s: c.model_estimator_time_constant_s,
                plane_rate_mm_per_s: c.model_plane_rate_mm_per_s,
                hold_ms: c.model_hold_ms,
            },
            arm_id,
        }
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
    /// The slave reports its safe stop: the rendering fades out, and once it has, the
    /// master starts a new energy ledger and acknowledges (`CMD_FLAG_ACK_SAFE_STOP`).
    pub slave_safe_stop: bool,
}

/// The master's coupling state.
#[derive(Clone, Debug)]
pub struct MasterCoupling {
    p: CouplingParams,
    /// The master port's passivity observer and controller.
    pub port: ImpedancePort,
    /// The handle pose the mapping is anchored at, master frame.
    handle_anchor_pose: [f64; 4],
    /// The slave pose the anchor maps to, slave frame.
    slave_anchor_pose: [f64; 4],
    /// The slave target of the last cycle, slave frame.
    last_slave_target: [f64; 4],
    clutched: bool,
    started: bool,
    seq: u64,
    fade: f64,
    /// The old slave's link force at a re-pairing, faded out by `handover_fade` while the
    /// new slave's fades in (no step in the rendered force), N.
    handover_n: [f64; 3],
    /// Fade factor of `handover_n` (1 at the re-pairing, falling to 0 over `fade_ms`).
    handover_fade: f64,
    /// The forces rendered beside the link this cycle, N, which the master port does not
    /// book: the brake's damping beyond the faded coupling's (`brake_on_loss` while the
    /// feedback is lost: a local dissipative element; booked, a brake flapping with a
    /// jittered link's safe stops drained the master's ledger by 6 mJ) and the old slave's
    /// fading force after a re-pairing.
    brake_extra_n: [f64; 3],
    /// Share of `contact_damping_n_s_per_mm` rendered: follows whether the newest feedback
    /// reports a contact over `fade_ms` (switched in one cycle, the damping stepped the
    /// rendered force by the whole damping times the handle's speed: 5–7 N in the restart
    /// storm, at a touch with the handle moving 7.6 mm/s).
    contact_damping_share: f64,
    last_feedback_ns: Option<u64>,
    feedback: Option<Feedback>,
    normal: [f64; 3],
    last: MasterStep,
    velocity: [f64; 3],
    /// The handle position at the start of the last cycle and the link force held over it
    /// (booked by the port once the cycle's displacement is known).
    disp_prev: Option<([f64; 3], [f64; 3])>,
    /// The master port's output force this cycle (after its passivity controller), N.
    port_force_n: [f64; 3],
    offset_mm: [f64; 3],
    filtered_n: [f64; 3],
    /// The handle's positions (mm) and their times (ns) over the last
    /// [`DAMPING_WINDOW_MAX`] cycles, newest at `window_head` (ring, no allocation).
    window: [([f64; 3], u64); DAMPING_WINDOW_MAX],
    window_head: usize,
    window_len: usize,
    /// The local contact model (model-mediated rendering).
    pub model: ContactModel,
    /// The slave targets sent, by sequence number (ring; allocated once).
    sent: Vec<(u64, [f64; 3])>,
    /// The newest feedback reports the slave's safe stop.
    slave_stopped: bool,
    /// The device stopped answering (`MasterTeleop`): the rendering fades out until its
    /// readings are fresh again.
    device_stale: bool,
    /// The master has faded out, started a new ledger and acknowledges the safe stop
    /// until the slave is active again.
    acking: bool,
    /// Safe stops of the slave seen (each counted once, when first reported).
    pub safe_stops_seen: u64,
    /// The step before's `now_ns`.
    last_step_ns: Option<u64>,
    /// The time a force is expected to be held, s: the longest recent cycle interval,
    /// its excess over the nominal period decaying over `damping_hold_memory_ms`.
    hold_s: f64,
}

/// The longest window of the local damping's velocity, cycles
/// ([`CouplingConfig::damping_window_mm`]).
const DAMPING_WINDOW_MAX: usize = 32;

/// Feedback silence after which the local damping acts on the device's velocity instead of
/// the window's (the brake, `coupling.brake_on_loss`), ms.
const WINDOW_SILENCE_MS: f64 = 20.0;

/// The shortest window of the local damping's velocity, cycles.
const DAMPING_WINDOW_MIN: usize = 3;

/// Commands remembered for the contact model (≥ the longest round trip in cycles).
const SENT_HISTORY: usize = 8192;

impl MasterCoupling {
    /// A coupling; the master's first reading becomes its anchor.
    pub fn new(p: CouplingParams) -> Self {
        MasterCoupling {
            port: ImpedancePort::from_params(&p.passivity_params),
            handle_anchor_pose: [0.0; 4],
            slave_anchor_pose: p.slave_anchor_pose,
            last_slave_target: p.slave_anchor_pose,
            clutched: false,
            started: false,
            seq: 0,
            fade: 0.0,
            handover_n: [0.0; 3],
            handover_fade: 0.0,
            brake_extra_n: [0.0; 3],
            contact_damping_share: 0.0,
            last_feedback_ns: None,
            feedback: None,
            normal: [0.0, 0.0, 1.0],
            last: MasterStep::default(),
            velocity: [0.0; 3],
            disp_prev: None,
            port_force_n: [0.0; 3],
            offset_mm: [0.0; 3],
            filtered_n: [0.0; 3],
            window: [([0.0; 3], 0); DAMPING_WINDOW_MAX],
            window_head: 0,
            window_len: 0,
            model: ContactModel::default(),
            last_step_ns: None,
            hold_s: 0.0,
            sent: vec![(0, [0.0; 3]); SENT_HISTORY],
            slave_stopped: false,
            device_stale: false,
            acking: false,
            safe_stops_seen: 0,
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
        self.p.scale.force / self.p.scale.motion
    }

    /// The offset added to this cycle's slave target by the contact model
    /// ([`ContactModel::offset_mm`]), slave frame, mm: part of the master–slave position
    /// mismatch.
    pub fn model_offset_mm(&self) -> [f64; 3] {
        self.offset_mm
    }

    /// A new pairing (the slave restarted; a session id can call it too): the port starts
    /// a new ledger, taking the newest feedback's energy as its first, and the rendering
    /// fades in again from zero.
    /// The force rendered from the old slave does not vanish in one cycle: it fades out over
    /// `fade_ms` while the new slave's fades in (a slave replaced within the feedback
    /// timeout rendered a step of up to 6 N before).
    pub fn new_pairing(&mut self) {
        self.port.new_pairing();
        if let Some(fb) = &self.feedback {
            self.port.receive_remote_in(fb.energy_in_j * self.kappa());
        }
        let old = self.last.link_force_n;
        for (h, o) in self.handover_n.iter_mut().zip(old.iter()) {
            *h = *h * self.handover_fade + o;
        }
        self.handover_fade = 1.0;
        self.fade = 0.0;
        self.model.reset_used();
    }

    /// The old slave's fading force after a re-pairing (see [`Self::new_pairing`]), N: rendered
    /// beside the port (the new pairing's ledger starts empty and would cut it in one cycle)
    /// and not booked; its work is bounded by its size times the handle's travel over
    /// `fade_ms`.
    fn handover_force(&mut self, dt_s: f64) -> [f64; 3] {
        if self.handover_fade <= 0.0 {
            return [0.0; 3];
        }
        let k = self.handover_fade;
        self.handover_fade =
            (self.handover_fade - dt_s * 1e3 / self.p.config.fade_ms.max(1e-3)).max(0.0);
        [
            self.handover_n[0] * k,
            self.handover_n[1] * k,
            self.handover_n[2] * k,
        ]
    }

    /// The device has stopped answering (true) or answers again (false): while it is silent
    /// the rendered force fades out as it does when feedback stops.
    pub fn set_device_stale(&mut self, stale: bool) {
        self.device_stale = stale;
    }

    /// The master is acknowledging the slave's safe stop (it has faded out and started a new
    /// ledger; the slave starts its own on the acknowledgement).
    pub fn acking(&self) -> bool {
        self.acking
    }

    /// The slave is in its safe stop (as the newest feedback reports).
    pub fn slave_safe_stop(&self) -> bool {
        self.slave_stopped
    }

    /// Hands the coupling a feedback message the gate accepted at `now_ns`. Feedback that
    /// reports the slave's safe stop carries the old ledger's energy: it is not taken (the
    /// master starts a new ledger before it acknowledges; the slave, on the acknowledgement).
    pub fn receive(&mut self, fb: &Feedback, now_ns: u64) {
        if fb.state == SlaveState::SafeStop as u8 {
            if !self.slave_stopped {
                self.safe_stops_seen += 1;
            }
            self.slave_stopped = true;
        } else {
            if fb.state == SlaveState::Active as u8 {
                self.acking = false;
            }
            self.slave_stopped = false;
            self.port.receive_remote_in(fb.energy_in_j * self.kappa());
        }
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
        let from = self.last_slave_target;
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

    /// Feedback freshness: the fade factor falls after the feedback timeout and rises again
    /// when feedback returns.
    fn update_fade(&mut self, now_ns: u64, dt_s: f64) {
        let p = &self.p;
        let silent_ms = self
            .last_feedback_ns
            .map_or(f64::INFINITY, |t| now_ns.saturating_sub(t) as f64 * 1e-6);
        let rate = dt_s * 1e3 / p.config.fade_ms.max(1e-3);
        // The local model needs no fresh feedback to render the contact: it holds through
        // a longer silence than the delayed force would.
        let timeout_ms = if p.config.mode == CouplingMode::PositionForce && p.model.enabled {
            p.model.hold_ms
        } else {
            p.config.feedback_timeout_ms
        };
        self.fade = if silent_ms > timeout_ms || self.slave_stopped || self.device_stale {
            (self.fade - rate).max(0.0)
        } else {
            (self.fade + rate).min(1.0)
        };
        // Faded out in the slave's safe stop: a new ledger, then the acknowledgement.
        if self.slave_stopped && self.fade == 0.0 && !self.acking {
            self.acking = true;
            self.port.new_pairing();
            self.model.reset_used();
        }
    }

    /// Clutch and indexing: on release the handle's pose and the slave target become the
    /// anchors of the mapping (no jump).
    fn update_clutch(&mut self, dev: &DeviceState) {
        if dev.clutch {
            self.clutched = true;
        } else if self.clutched {
            self.clutched = false;
            self.handle_anchor_pose = dev.pose;
            self.slave_anchor_pose = self.last_slave_target;
        }
    }

    /// The contact normal from the slave's desired wrench (slave frame; the handle's axes
    /// are the slave's).
    fn update_normal(&mut self) {
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
    }

    /// The slave target for the handle at `handle_pose` moving at `handle_velocity`
    /// (master frame): the scaled mapping from the anchors, in force-guided mode held
    /// beyond the surface along the normal, pulled back into the slave's workspace, with
    /// its velocity limited. Returns the target pose and velocity (slave frame) and whether
    /// the workspace limited it.
    fn slave_from_master(
        &self,
        handle_pose: &[f64; 4],
        handle_velocity: &[f64; 3],
    ) -> ([f64; 4], [f64; 3], bool) {
        let p = &self.p;
        let anchor = self.slave_anchor_pose;
        let mut t = [0.0; 4];
        let mut vel = [0.0; 3];
        for i in 0..3 {
            t[i] = anchor[i] + p.scale.motion * (handle_pose[i] - self.handle_anchor_pose[i]);
            vel[i] = p.scale.motion * handle_velocity[i];
        }
        t[3] = anchor[3] + (handle_pose[3] - self.handle_anchor_pose[3]);
        if p.config.mode == CouplingMode::ForceGuided {
            // Along the normal the slave's force loop rules: keep the target's normal
            // component at the anchor's, beyond the surface by the approach depth.
            let n = self.normal;
            let d: [f64; 3] = [t[0] - anchor[0], t[1] - anchor[1], t[2] - anchor[2]];
            let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
            let vn = vel[0] * n[0] + vel[1] * n[1] + vel[2] * n[2];
            for i in 0..3 {
                t[i] -= n[i] * (dn + p.config.guide_approach_depth_mm);
                vel[i] -= n[i] * vn;
            }
        }
        let (target, limited) = self.map_into_workspace(t);
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
        (target, vel, limited)
    }

    /// The local contact model's force at the slave target `target` (slave frame), scaled
    /// and faded for the handle, and the target moved out of the surface by the model's
    /// offset where the workspace allows. Returns the link force (N, at the handle), the
    /// target and the offset applied (mm, slave frame).
    fn model_rendering(&mut self, target: [f64; 4], dt_s: f64) -> ([f64; 3], [f64; 4], [f64; 3]) {
        let p = self.p;
        if self.fade < 1.0 {
            // Feedback silent: on its return the plane is placed where the handle is and
            // moves out only at the plane rate (no force step).
            self.model.reset_used();
        }
        let k_max_slave = p.model.stiffness_max_n_per_mm / (p.scale.force * p.scale.motion);
        let d = [target[0], target[1], target[2]];
        // What the model's update may put into the handle this cycle: a share of the
        // observer's surplus (none without a surplus), in slave units.
        let budget_n_mm = if p.passivity_params.enabled {
            let share = p.passivity_params.drift_energy_share;
            (self.port.observed_j() - p.passivity_params.energy_reserve_j).max(0.0) * share * 1e3
                / (self.kappa() * self.fade.max(1e-3))
        } else {
            f64::INFINITY
        };
        let f = self
            .model
            .force_at(&p.model, &d, k_max_slave, dt_s, budget_n_mm);
        // Along the normal only: friction along the surface is not rendered (the delayed
        // measured friction, tried, made the handle wander sideways).
        let mut link_force = [0.0; 3];
        for (lf, fi) in link_force.iter_mut().zip(f.iter()) {
            *lf = p.scale.force * fi * self.fade;
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
                return (link_force, shifted, o);
            }
        }
        (link_force, target, [0.0; 3])
    }

    /// First-order low-pass of the force to render (the sensor's noise and the contact's
    /// high-frequency content are not rendered; a filter is passive-neutral here since the
    /// port observes the force actually applied).
    fn filter_force(&mut self, link_force: &mut [f64; 3], dt_s: f64) {
        let hz = self.p.config.force_filter_hz;
        if hz > 0.0 && self.p.config.mode == CouplingMode::PositionForce {
            let a = 1.0 - (-2.0 * std::f64::consts::PI * hz * dt_s).exp();
            for (f, lf) in self.filtered_n.iter_mut().zip(link_force.iter_mut()) {
                *f += a * (*lf - *f);
                *lf = *f;
            }
        }
    }

    /// The handle velocity the local damping acts on, mm/s: the mean over the shortest
    /// window of the recent positions, from `DAMPING_WINDOW_MIN` to `DAMPING_WINDOW_MAX`
    /// cycles back, over which the handle moved at least `coupling.damping_window_mm` (the
    /// longest when it moved less). The device's velocity with no window set, until there
    /// are `DAMPING_WINDOW_MIN` positions, and for a non-finite reading (which also empties
    /// the window).
    fn damping_velocity(&mut self, dev: &DeviceState, now_ns: u64) -> [f64; 3] {
        let v = [dev.velocity[0], dev.velocity[1], dev.velocity[2]];
        let x = [dev.pose[0], dev.pose[1], dev.pose[2]];
        if !x.iter().all(|c| c.is_finite()) {
            self.window_len = 0;
            return v;
        }
        self.window_head = (self.window_head + 1) % DAMPING_WINDOW_MAX;
        self.window[self.window_head] = (x, now_ns);
        self.window_len = (self.window_len + 1).min(DAMPING_WINDOW_MAX);
        let reach = self.p.config.damping_window_mm;
        if reach <= 0.0 || self.window_len <= DAMPING_WINDOW_MIN {
            return v;
        }
        let mut back = self.window[self.window_head];
        for n in DAMPING_WINDOW_MIN..self.window_len {
            back = self.window[(self.window_head + DAMPING_WINDOW_MAX - n) % DAMPING_WINDOW_MAX];
            let d = [x[0] - back.0[0], x[1] - back.0[1], x[2] - back.0[2]];
            if norm3(&d) >= reach {
                break;
            }
        }
        let dt_s = now_ns.saturating_sub(back.1) as f64 * 1e-9;
        if dt_s <= 0.0 {
            return v;
        }
        [
            (x[0] - back.0[0]) / dt_s,
            (x[1] - back.0[1]) / dt_s,
            (x[2] - back.0[2]) / dt_s,
        ]
    }

    /// The local damping at the handle: `master_damping_n_s_per_mm`, plus
    /// `contact_damping_n_s_per_mm` while the newest feedback reports a contact held by the
    /// slave's force loop.
    fn local_damping(&self) -> f64 {
        self.p.config.master_damping_n_s_per_mm
            + self.contact_damping_share * self.p.config.contact_damping_n_s_per_mm
    }

    /// The contact damping's share: towards whether the newest feedback reports a contact
    /// held by the slave's force loop, over `fade_ms`.
    fn update_contact_damping(&mut self, dt_s: f64) {
        let contact = self.feedback.is_some_and(|fb| {
            let w = fb.wrench_desired;
            w[0] * w[0] + w[1] * w[1] + w[2] * w[2] > 1e-6
        });
        let target = if contact { 1.0 } else { 0.0 };
        let rate = dt_s * 1e3 / self.p.config.fade_ms.max(1e-3);
        let d = (target - self.contact_damping_share).clamp(-rate, rate);
        self.contact_damping_share += d;
    }

    /// The share of the local damping rendered: all of it while the feedback is fresh and
    /// while it is lost (the handle brakes instead of running free under the operator's
    /// push; damping only dissipates), faded with the feedback only when
    /// `coupling.brake_on_loss` is off.
    fn brake(&self) -> f64 {
        if self.p.config.brake_on_loss && self.feedback.is_some() {
            1.0
        } else {
            self.fade
        }
    }

    /// The local damping along each of the handle's principal directions
    /// (`dev.principal_masses`), N·s/mm: [`MasterCoupling::local_damping`], bounded by
    /// `passivity.damping_step_fraction · m / dt` along a direction of effective mass `m`
    /// (0: unbounded). The bound is the discrete-time one: a damping held over a cycle
    /// with the velocity estimated from the encoders (a backward difference through a
    /// low-pass) is unstable above about `2 m / dt` along the light direction. Unbounded, the
    /// wall-push contact's 1.0 N·s/mm against the lightest 0.39 kg of the shipped handle
    /// chattered at 125 Hz with ±25 N once a stalled host kicked the handle sideways
    /// (process delay matrix, CI, 2026-12-02); along the heavy directions the full damping
    /// stays. `dt_s` is the time the force is expected to be held
    /// ([`MasterCoupling::update_hold`]), not always the nominal period.
    fn local_damping_along(&self, dev: &DeviceState, dt_s: f64) -> [f64; 3] {
        let b = self.local_damping();
        let frac = self.p.passivity_params.damping_step_fraction;
        let mut out = [b; 3];
        if frac > 0.0 {
            for (o, m) in out.iter_mut().zip(dev.principal_masses.mass_kg.iter()) {
                if *m > 0.0 {
                    *o = o.min(frac * m * 1e-3 / dt_s);
                }
            }
        }
        out
    }

    /// The local damping's force, N: `−Σ bₖ uₖ aₖ` over the principal directions `aₖ` with
    /// the bounded dampings `b` of [`MasterCoupling::local_damping_along`], where `uₖ` is the
    /// windowed velocity `v_window`'s component along `aₖ` where it agrees in sign with the
    /// device velocity's `v` and is no larger, the device's where that is smaller, and 0
    /// where they disagree: never more damping than on the device's velocity, and never a
    /// force along the motion (a window's mean lags a reversal: damped as it was, it fed
    /// the handle energy the port could not take back, −3.6 mJ at scale 1 on aluminium).
    fn local_damping_force(
        dev: &DeviceState,
        b: &[f64; 3],
        v_window: &[f64; 3],
        v: &[f64; 3],
    ) -> [f64; 3] {
        let mut f = [0.0; 3];
        for (a, bk) in dev.principal_masses.axes.iter().zip(b.iter()) {
            let u_w = a[0] * v_window[0] + a[1] * v_window[1] + a[2] * v_window[2];
            let u_d = a[0] * v[0] + a[1] * v[1] + a[2] * v[2];
            let u = if u_w * u_d > 0.0 {
                u_d.signum() * u_w.abs().min(u_d.abs())
            } else if u_w == u_d {
                u_d
            } else {
                0.0
            };
            let along = bk * u;
            for (fi, ai) in f.iter_mut().zip(a.iter()) {
                *fi -= along * ai;
            }
        }
        f
    }

    /// The time this cycle's force is expected to be held: the nominal `dt_s`, or the
    /// longest recent interval between two steps (a late, starved or stalled loop), its
    /// excess decaying over `passivity.damping_hold_memory_ms` (0: `dt_s` only).
    fn update_hold(&mut self, now_ns: u64, dt_s: f64) {
        let memory_s = self.p.passivity_params.damping_hold_memory_ms * 1e-3;
        let interval_s = match self.last_step_ns {
            // On time (within 1 %): the nominal period, exactly.
            Some(t) if now_ns > t && (now_ns - t) as f64 * 1e-9 > 1.01 * dt_s => {
                (now_ns - t) as f64 * 1e-9
            }
            _ => dt_s,
        };
        self.last_step_ns = Some(now_ns);
        self.hold_s = if memory_s > 0.0 {
            let excess = (self.hold_s - dt_s).max(0.0) * (-interval_s / memory_s).exp();
            (dt_s + excess).max(interval_s)
        } else {
            dt_s
        };
    }

    /// `passivity.damping_step_fraction` (0: off): the passivity controller's damping, with
    /// the local damping, stays within what the handle's mass takes in one cycle along each
    /// principal direction (discrete-time bound; `dt_s` the expected hold).
    fn bound_damping(&mut self, dev: &DeviceState, local: &[f64; 3], dt_s: f64) {
        let p = &self.p;
        self.port.mass_estimate_kg = (dev.effective_mass_kg > 0.0).then_some(dev.effective_mass_kg);
        let frac = p.passivity_params.damping_step_fraction;
        self.port.damping_step_limit_n_s_per_mm = if frac > 0.0 && dev.effective_mass_kg > 0.0 {
            let share = if p.config.mode == CouplingMode::PositionForce && !self.clutched {
                self.brake()
            } else {
                0.0
            };
            let room = dev
                .principal_masses
                .mass_kg
                .iter()
                .zip(local.iter())
                .map(|(m, b)| frac * m * 1e-3 / dt_s - share * b)
                .fold(f64::INFINITY, f64::min);
            Some(room.max(0.0))
        } else {
            None
        };
    }

    /// Force-guided: the cutting resistance the slave measures along the feed `vel` (slave
    /// frame, along the surface), scaled for the handle: the component of its force against
    /// the direction of motion only (a resistance never pulls the hand along), faded with
    /// the feedback.
    fn feed_resistance(&self, vel: &[f64; 3]) -> [f64; 3] {
        let Some(fb) = &self.feedback else {
            return [0.0; 3];
        };
        let speed = norm3(vel);
        if speed < 1e-3 {
            return [0.0; 3];
        }
        let e = [vel[0] / speed, vel[1] / speed, vel[2] / speed];
        let w = fb.wrench_measured;
        let along = (w[0] * e[0] + w[1] * e[1] + w[2] * e[2]).min(0.0);
        let k = self.p.scale.force * self.p.config.feed_force_gain * self.fade * along;
        [k * e[0], k * e[1], k * e[2]]
    }

    /// One cycle at `now_ns`: returns the wrench to write. Call [`MasterCoupling::finish`]
    /// with the wrench the device actually applied to get the command to send.
    pub fn step(&mut self, dev: &DeviceState, now_ns: u64, dt_s: f64) -> MasterStep {
        let p = self.p;
        if !self.started {
            self.handle_anchor_pose = dev.pose;
            self.started = true;
        }
        let mut step = MasterStep::default();
        self.update_hold(now_ns, dt_s);
        self.update_fade(now_ns, dt_s);
        self.update_contact_damping(dt_s);
        self.update_clutch(dev);
        let handle_velocity = [dev.velocity[0], dev.velocity[1], dev.velocity[2]];
        let damping_velocity = self.damping_velocity(dev, now_ns);
        self.update_normal();
        let mut link_force = [0.0; 3];
        let mut offset = [0.0; 3];
        let mut target = self.last_slave_target;
        let mut vel = [0.0; 3];
        if !self.clutched {
            let limited;
            (target, vel, limited) = self.slave_from_master(&dev.pose, &handle_velocity);
            step.workspace_limited = limited;
            if p.config.mode == CouplingMode::PositionForce && p.model.enabled && self.model.valid()
            {
                (link_force, target, offset) = self.model_rendering(target, dt_s);
            } else if p.config.mode == CouplingMode::PositionForce
                && let Some(fb) = &self.feedback
            {
                for (lf, w) in link_force.iter_mut().zip(fb.wrench_measured.iter()) {
                    *lf = p.scale.force * w * self.fade;
                }
            } else if p.config.mode == CouplingMode::ForceGuided && p.config.feed_force_gain > 0.0 {
                link_force = self.feed_resistance(&vel);
            }
        }
        let handover = if self.clutched {
            [0.0; 3]
        } else {
            self.handover_force(dt_s)
        };
        self.filter_force(&mut link_force, dt_s);
        self.last_slave_target = target;
        self.offset_mm = offset;
        self.velocity = vel;
        let hold_s = self.hold_s;
        let local_damping = self.local_damping_along(dev, hold_s);
        self.bound_damping(dev, &local_damping, hold_s);
        // Faded out there is nothing to render: the port only observes (its controller's
        // damping, released over `damping_release_ms`, would otherwise push the handle).
        let pc = self.port.step(
            link_force,
            handle_velocity,
            hold_s,
            p.passivity_params.enabled && self.fade > 0.0,
        );
        let mut force = pc.force_n;
        for (f, h) in force.iter_mut().zip(handover.iter()) {
            *f += h;
        }
        self.port_force_n = pc.force_n;
        self.brake_extra_n = [0.0; 3];
        if p.config.mode == CouplingMode::PositionForce && !self.clutched {
            // The local damping: faded with the feedback, except that the brake
            // (`brake_on_loss`) keeps it on while the feedback is lost; the brake's share
            // beyond the fade is not the link's (see `brake_extra_n`).
            // Braking through a feedback silence the damping acts on the device's velocity:
            // the window's mean, smaller at low speed, let the push on steel run the handle
            // in (tests/coupling_behaviour.rs, a blackout mid-hold).
            let silent = self
                .last_feedback_ns
                .is_none_or(|t| now_ns.saturating_sub(t) as f64 * 1e-6 > WINDOW_SILENCE_MS);
            let v_damped = if silent {
                &handle_velocity
            } else {
                &damping_velocity
            };
            let d = Self::local_damping_force(dev, &local_damping, v_damped, &handle_velocity);
            let brake = self.brake();
            let extra = (brake - self.fade).max(0.0);
            for ((f, e), di) in force.iter_mut().zip(self.brake_extra_n.iter_mut()).zip(d) {
                *f += brake * di;
                *e = extra * di;
            }
        }
        for (e, h) in self.brake_extra_n.iter_mut().zip(handover.iter()) {
            *e += h;
        }
        // Force-guided: the local virtual spring sets the set-point.
        if p.config.mode == CouplingMode::ForceGuided && !self.clutched {
            let n = self.normal;
            let a = self.handle_anchor_pose;
            let depth = -((dev.pose[0] - a[0]) * n[0]
                + (dev.pose[1] - a[1]) * n[1]
                + (dev.pose[2] - a[2]) * n[2]);
            let spring = (p.config.guide_stiffness_n_per_mm * depth)
                .clamp(0.0, p.scale.force * p.config.guide_setpoint_max_n);
            for i in 0..3 {
                force[i] += spring * n[i];
            }
            step.setpoint_n = spring / p.scale.force;
        }
        let fmag = norm3(&force);
        if fmag > p.config.force_limit_n {
            let s = p.config.force_limit_n / fmag;
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
        step.slave_safe_stop = self.slave_stopped;
        self.last = step;
        step
    }

    /// Books the link force of the previous cycle against the handle's displacement since
    /// (`dev` is this cycle's reading), keeps the wrench the device applied this cycle
    /// (after its own limits) for the next, and returns the command to send, stamped
    /// `now_ns`.
    pub fn finish(&mut self, applied: &[f64; 4], dev: &DeviceState, now_ns: u64) -> Command {
        // Position–force: all of the applied force (the local damping included, except the
        // brake's share beyond the fade) is the master port's. Force-guided: the local spring is not the link's, and the link
        // renders nothing.
        let link = if self.p.config.mode == CouplingMode::PositionForce {
            let e = self.brake_extra_n;
            [applied[0] - e[0], applied[1] - e[1], applied[2] - e[2]]
        } else if self.p.config.feed_force_gain > 0.0 {
            // Force-guided: the port's force (the feed resistance after the passivity
            // controller), not the local spring's.
            self.port_force_n
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
            match self.p.config.mode {
                CouplingMode::PositionForce => Mode::Position,
                CouplingMode::ForceGuided => Mode::ForceGuided,
            }
        };
        let t = self.last.slave_target;
        self.sent[(self.seq % SENT_HISTORY as u64) as usize] = (self.seq, [t[0], t[1], t[2]]);
        Command {
            // Set by the endpoint (`MasterTeleop`) that owns the session.
            session_id: 0,
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
            flags: if self.clutched { CMD_FLAG_CLUTCH } else { 0 }
                | if self.acking {
                    CMD_FLAG_ACK_SAFE_STOP
                } else {
                    0
                },
            // Set by the endpoint (`MasterTeleop`), which holds the newest feedback.
            echo_seq: 0,
            echo_send_time_ns: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use h4_shared::config::ArmConfig;

    fn coupling(hold_memory_ms: f64) -> MasterCoupling {
        let passivity = PassivityParams {
            damping_hold_memory_ms: hold_memory_ms,
            ..PassivityParams::default()
        };
        MasterCoupling::new(CouplingParams::from_config(
            &CouplingConfig::default(),
            &ScaleConfig::default(),
            &passivity,
            ArmConfig::default().workspace(),
            [0.0, 0.0, -245.0, 0.0],
            50.0,
            1,
        ))
    }

    /// The damping's velocity: a handle at rest whose encoder flickers by a count every
    /// other cycle reads at most a count over the longest window (0.06 mm/s for 0.002 mm,
    /// where the device's filtered velocity reads 0.5 mm/s); one moving at 50 mm/s reads its
    /// speed over the shortest window; no window set: the device's velocity.
    #[test]
    fn the_damping_velocity_is_a_mean_over_a_window_long_only_when_slow() {
        let mut c = coupling(100.0);
        let mut dev = DeviceState::default();
        let mut now = 0u64;
        let mut largest = 0.0_f64;
        for k in 0..200 {
            now += 1_000_000;
            dev.pose[2] = if k % 2 == 0 { -220.0 } else { -220.002 };
            dev.velocity[2] = if k % 2 == 0 { 0.5 } else { -0.5 };
            let v = c.damping_velocity(&dev, now);
            if k > 40 {
                largest = largest.max(norm3(&v));
            }
        }
        assert!(largest <= 0.002 / 0.031 + 1e-9, "{largest}");
        for _ in 0..40 {
            now += 1_000_000;
            dev.pose[2] -= 0.05;
            dev.velocity[2] = -40.0;
            let v = c.damping_velocity(&dev, now);
            assert!(v[2] < 0.0, "{v:?}");
        }
        let v = c.damping_velocity(&dev, now + 1_000_000);
        // The same position a cycle later: the mean over the 3-cycle window, 2/3 of 50.
        assert!((v[2] + 100.0 / 3.0).abs() < 1e-6, "{v:?}");
        let off = CouplingConfig {
            damping_window_mm: 0.0,
            ..CouplingConfig::default()
        };
        let mut c = MasterCoupling::new(CouplingParams {
            config: off,
            ..*c.params()
        });
        dev.velocity[2] = 0.7;
        for _ in 0..10 {
            now += 1_000_000;
            assert_eq!(c.damping_velocity(&dev, now)[2], 0.7);
        }
    }

    /// On time the hold is the period exactly; a late cycle sets it to its interval, which
    /// then decays back over the memory; with no memory it is always the period.
    #[test]
    fn the_expected_hold_follows_late_cycles_and_decays_back() {
        let dt = 1e-3;
        let mut c = coupling(100.0);
        let mut now = 0u64;
        for _ in 0..10 {
            now += 1_000_000;
            c.update_hold(now, dt);
            assert_eq!(c.hold_s, dt);
        }
        now += 8_000_000;
        c.update_hold(now, dt);
        assert!((c.hold_s - 8e-3).abs() < 1e-12, "{}", c.hold_s);
        for _ in 0..100 {
            now += 1_000_000;
            c.update_hold(now, dt);
        }
        // 100 ms later: 1 + 7 e⁻¹ ms.
        let expected = dt + 7e-3 * (-1.0f64).exp();
        assert!((c.hold_s - expected).abs() < 1e-4, "{}", c.hold_s);
        for _ in 0..2000 {
            now += 1_000_000;
            c.update_hold(now, dt);
        }
        assert!(c.hold_s - dt < 1e-9, "{}", c.hold_s);

        let mut off = coupling(0.0);
        off.update_hold(1_000_000, dt);
        off.update_hold(9_000_000, dt);
        assert_eq!(off.hold_s, dt);
    }
}
