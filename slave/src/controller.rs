//! The slave's 1 kHz controller: a pure step, no clock reads, no I/O, no allocation, no
//! panic.
//!
//! * **Position** mode follows the commanded pose with velocity and acceleration limits
//!   (per axis), through the checked inverse kinematics of the [`Workspace`].
//! * **ForceGuided** mode is the paper's implicit force control (§3, figures 2 and 3): the
//!   contact normal comes from the measured force (with the friction component along the
//!   tracking direction removed), the tracking direction is the commanded direction of
//!   motion projected onto the tangent plane (figure 2), and the position command moves
//!   into the surface by the compliance times the force error,
//!   `Δd = c · (ΔF_r + k_p Δe + k_i e dt)`, with `c = nᵀ Λ(x) n + ĉ_env`: the arm's
//!   compliance along the normal from the kinematics (with the *assumed* actuator
//!   stiffness) plus the environment's compliance, estimated online by recursive least
//!   squares on force and position increments (as in Chiaverini–Siciliano–Villani's
//!   stiffness adaptation). `F_r` is the set-point after a critically damped second-order
//!   prefilter, fed forward. Before contact the arm approaches the commanded pose at the
//!   approach speed; on contact loss it re-approaches along the last normal, without a jump.
//! * **Hold** (or the clutch) holds the commanded pose.
//! * [`SlaveController::safe_stop`] ramps the force to zero, retracts along the contact
//!   normal and holds.
//!
//! Limits always hold: commanded set-points above the force limit, speeds above the speed
//! limit, non-finite inputs and poses outside the workspace are rejected with a
//! [`Rejection`] (the actuators then hold their last valid command); a measured force above
//! the limit makes the arm back off; the command moves no faster than the speed limit.

use h4_shared::kinematics::{ActuatorStiffness, KinError, Pose, Workspace};
use h4_shared::wire::Mode;
use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};
use serde::{Deserialize, Serialize};

use crate::filter::Butterworth2;

/// Tuning of the controller (`controller.*` in experiment files).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ControllerParams {
    /// Use the arm's compliance matrix Λ(x) (deflection-corrected pose, arm compliance in
    /// the loop gain). `false` treats the arm as rigid.
    pub compliance_model: bool,
    /// Largest speed of the commanded tool point, mm/s.
    pub max_speed_mm_per_s: f64,
    /// Largest acceleration in position mode, mm/s².
    pub max_accel_mm_per_s2: f64,
    /// Acceleration of the motion along the surface in ForceGuided mode, mm/s².
    pub track_accel_mm_per_s2: f64,
    /// Largest acceleration of the force loop's motion along the contact normal, mm/s²
    /// (a rate limit's corners would ring the tool on the arm's stiffness; the force
    /// limit's back-off ignores it).
    pub force_accel_mm_per_s2: f64,
    /// Largest rate of theta, rad/s.
    pub max_theta_rate_rad_per_s: f64,
    /// Speed of the approach towards an unknown surface and of re-approach, mm/s.
    pub approach_speed_mm_per_s: f64,
    /// Force limit: set-points above it are rejected, measured forces above it make the arm
    /// back off, N.
    pub force_limit_n: f64,
    /// Force that signals contact, N.
    pub contact_threshold_n: f64,
    /// Normal force below which contact counts as lost, N.
    pub contact_lost_n: f64,
    /// Consecutive cycles below `contact_lost_n` before contact is declared lost.
    pub contact_lost_cycles: u32,
    /// Time constant of the set-point prefilter (critically damped, 2nd order), s.
    pub setpoint_time_constant_s: f64,
    /// Mass of the platform with sensor and tool, kg (for the contact resonance).
    pub tool_mass_kg: f64,
    /// Share of the set-point change fed forward through the compliance (0 to 1.5); below 1
    /// keeps an over-estimated compliance from overshooting, the PI terms close the rest.
    pub feedforward_gain: f64,
    /// Proportional gain of the force loop, relative (dimensionless).
    pub kp: f64,
    /// Integral gain of the force loop, 1/s.
    pub ki_per_s: f64,
    /// Environment stiffness assumed before the estimator has data, N/mm.
    pub initial_env_stiffness_n_per_mm: f64,
    /// Lower bound of the environment stiffness estimate, N/mm.
    pub env_stiffness_min_n_per_mm: f64,
    /// Upper bound of the environment stiffness estimate, N/mm.
    pub env_stiffness_max_n_per_mm: f64,
    /// Turn the online estimation of the environment's stiffness on.
    pub estimate_env_stiffness: bool,
    /// Forgetting factor of the estimator, per update (0.5 to 1).
    pub estimator_forgetting: f64,
    /// Window of the force/position increments the estimator uses, cycles (2 to 64).
    pub estimator_window_cycles: u32,
    /// Smallest force increment over the window that updates the estimate, N.
    pub estimator_excitation_n: f64,
    /// Time constant of the contact-normal filter, s.
    pub normal_time_constant_s: f64,
    /// Time constant of the low-pass filter on the difference between the measured force
    /// and the prefiltered set-point in the compensation of the arm's tangential
    /// deflection, s (0 to 1; below one cycle: no filtering).
    pub deflection_comp_time_constant_s: f64,
    /// Cut-off of the filter applied to the measured position so it lines up with the
    /// force sensor's filtered signal, Hz (set it to the sensor filter's cut-off).
    pub sensor_filter_cutoff_hz: f64,
    /// Cycles at start-up averaged (in free space) to estimate the sensor's bias.
    pub tare_cycles: u32,
    /// Safe stop: time to ramp the force to zero, s.
    pub safe_stop_ramp_s: f64,
    /// Safe stop: retraction along the contact normal, mm.
    pub safe_stop_retract_mm: f64,
    /// Safe stop out of a position-mode contact: the farthest the arm backs away along the
    /// measured force before giving up and holding, mm.
    pub safe_stop_release_max_mm: f64,
}

impl Default for ControllerParams {
    fn default() -> Self {
        ControllerParams {
            compliance_model: true,
            max_speed_mm_per_s: 100.0,
            max_accel_mm_per_s2: 1000.0,
            max_theta_rate_rad_per_s: 1.0,
            track_accel_mm_per_s2: 5.0,
            force_accel_mm_per_s2: 5000.0,
            approach_speed_mm_per_s: 2.0,
            force_limit_n: 80.0,
            contact_threshold_n: 0.8,
            contact_lost_n: 0.3,
            contact_lost_cycles: 20,
            setpoint_time_constant_s: 0.015,
            tool_mass_kg: 1.0,
            feedforward_gain: 1.0,
            kp: 0.3,
            ki_per_s: 80.0,
            initial_env_stiffness_n_per_mm: 200.0,
            env_stiffness_min_n_per_mm: 1.0,
            env_stiffness_max_n_per_mm: 20_000.0,
            estimate_env_stiffness: true,
            estimator_forgetting: 0.98,
            estimator_window_cycles: 10,
            estimator_excitation_n: 0.4,
            normal_time_constant_s: 0.1,
            deflection_comp_time_constant_s: 0.03,
            sensor_filter_cutoff_hz: 80.0,
            tare_cycles: 100,
            safe_stop_ramp_s: 0.2,
            safe_stop_retract_mm: 3.0,
            safe_stop_release_max_mm: 50.0,
        }
    }
}

/// What the master (or an experiment) asks of the slave this cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlaveCommand {
    /// Hold, Position or ForceGuided.
    pub mode: Mode,
    /// Desired pose `[x, y, z, theta]`, mm and rad. In ForceGuided mode the point is the
    /// target of the approach before contact; theta is followed in every mode.
    pub pose: [f64; 4],
    /// Desired velocity `[vx, vy, vz, ω]`, mm/s and rad/s. In ForceGuided mode its
    /// translational part gives the direction and speed of motion along the surface.
    pub velocity: [f64; 4],
    /// Desired contact force along the normal, N (ForceGuided).
    pub force_setpoint_n: f64,
    /// Operator clutch: hold still while pressed.
    pub clutch: bool,
}

impl Default for SlaveCommand {
    fn default() -> Self {
        SlaveCommand {
            mode: Mode::Hold,
            pose: [0.0; 4],
            velocity: [0.0; 4],
            force_setpoint_n: 0.0,
            clutch: false,
        }
    }
}

/// One cycle's input: the arm's measurements and the current command.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ControllerInput {
    /// Measured actuator positions (encoders), mm.
    pub actuators_mm: [f64; 4],
    /// Measured wrench `[Fx, Fy, Fz, My]` (N, N·mm) in the base frame, as the sensor reports it.
    pub wrench: [f64; 4],
    /// The current command.
    pub command: SlaveCommand,
}

/// The controller's state, reported every cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Estimating the sensor bias at start-up (holding still).
    Taring,
    /// Holding (Hold mode, clutch, or after a safe stop).
    Holding,
    /// Moving freely (Position mode, no contact force).
    Free,
    /// ForceGuided, moving towards the surface.
    Approaching,
    /// ForceGuided, in contact, controlling force.
    Contact,
    /// ForceGuided, contact lost: re-approaching along the last normal.
    ContactLost,
    /// The measured force exceeded the limit: backing off.
    ForceLimited,
    /// Safe stop in progress (force ramp-down or retraction).
    SafeStop,
    /// This cycle's command was rejected; the actuators hold.
    Rejected,
}

impl Status {
    /// A small number per state, for plotting.
    pub fn code(self) -> u8 {
        self as u8
    }
}

/// Why a command was rejected (the actuators hold their last valid command).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum Rejection {
    /// An input (measurement, command or dt) is NaN or infinite, or dt ≤ 0.
    #[error("non-finite input or non-positive dt")]
    NonFiniteInput,
    /// The force set-point is negative or above the force limit.
    #[error("force set-point {value_n} N outside 0 to {limit_n} N")]
    SetpointOutOfRange {
        /// The set-point asked for.
        value_n: f64,
        /// The limit.
        limit_n: f64,
    },
    /// The commanded speed is above the speed limit.
    #[error("commanded speed {value_mm_per_s} mm/s above the limit {limit_mm_per_s} mm/s")]
    SpeedOutOfRange {
        /// The speed asked for.
        value_mm_per_s: f64,
        /// The limit.
        limit_mm_per_s: f64,
    },
    /// The commanded (or next) pose is outside the workspace.
    #[error("pose outside the workspace: {0}")]
    Workspace(KinError),
    /// The measured actuator positions have no forward kinematics.
    #[error("measured actuator positions invalid: {0}")]
    MeasuredPose(KinError),
}

impl Rejection {
    /// Machine-readable reason.
    pub fn reason_code(&self) -> &'static str {
        match self {
            Rejection::NonFiniteInput => "non_finite_input",
            Rejection::SetpointOutOfRange { .. } => "setpoint_out_of_range",
            Rejection::SpeedOutOfRange { .. } => "speed_out_of_range",
            Rejection::Workspace(e) => e.reason_code(),
            Rejection::MeasuredPose(_) => "measured_pose_invalid",
        }
    }
}

/// One cycle's output.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ControllerOutput {
    /// Actuator position commands, mm (the last valid ones when rejected).
    pub actuators_cmd_mm: [f64; 4],
    /// The commanded (undeflected) pose whose IK gives the actuator commands.
    pub commanded_pose: [f64; 4],
    /// The measured pose: FK of the encoders, plus Λ(x)F when the compliance model is on.
    pub measured_pose: [f64; 4],
    /// Estimated outward contact normal (zero before the first contact).
    pub contact_normal: [f64; 3],
    /// Tracking direction on the surface (zero when not tracking).
    pub tracking_direction: [f64; 3],
    /// Measured wrench with the sensor bias removed.
    pub wrench_measured: [f64; 4],
    /// Desired wrench: the (prefiltered) set-point along the normal.
    pub wrench_desired: [f64; 4],
    /// Measured force along the estimated normal, N.
    pub normal_force_n: f64,
    /// Set-point after the prefilter, N.
    pub setpoint_n: f64,
    /// The environment stiffness the loop uses, N/mm.
    pub env_stiffness_n_per_mm: f64,
    /// Total compliance along the normal the loop uses, mm/N.
    pub compliance_mm_per_n: f64,
    /// State.
    pub status: Status,
    /// Set when this cycle's command was rejected.
    #[serde(skip)]
    pub rejection: Option<Rejection>,
}

const WINDOW_MAX: usize = 64;
/// Smoothing of a rising cycle-to-cycle force-error swing (per cycle).
const SWING_ATTACK: f64 = 0.3;
/// Smoothing of the cycle-to-cycle force-error swing (per cycle).
const SWING_FILTER: f64 = 0.05;
/// Mean second difference of the force error (per cycle) that counts as oscillation, N
/// (≈ 0.2 × the amplitude the sensor shows of a 90 Hz oscillation; filtered noise gives
/// ≈ 0.01).
const SWING2_LIMIT_N: f64 = 0.1;
/// Per-cycle gain reduction while oscillating, and recovery afterwards.
const GUARD_DECAY: f64 = 0.98;
const GUARD_RECOVERY: f64 = 1.0005;
/// Smallest gain factor of the oscillation guard.
const GUARD_MIN: f64 = 0.05;
/// The motion direction is used only while the depth correction is below this share of
/// the displacement.
const DEPTH_TRUST: f64 = 0.3;
/// Largest normal-force change over the motion window that counts as steady, N.
const STEADY_FORCE_CHANGE_N: f64 = 0.5;
/// Cycles right after touching during which the normal follows the force's direction.
const ONSET_CYCLES: u32 = 20;
/// Force guard: ratio of an oscillation's peak to its mean cycle-to-cycle swing as the
/// filtered sensor shows it (a sine of amplitude A near 100 Hz swings ≈ 0.4 A per 1 ms,
/// and the 80 Hz filter shows ≈ 0.55 A of it).
const GUARD_PEAK_PER_SWING: f64 = 5.0;
/// Share of `contact_threshold_n` that counts as contact when the force stays above it
/// for [`CONTACT_ONSET_CYCLES`] cycles (0.3 N at the default: ≈ 7 × the standard deviation
/// of the filtered sensor noise per axis).
const CONTACT_ONSET_FRACTION: f64 = 0.375;
/// Consecutive cycles above the onset level that count as contact.
const CONTACT_ONSET_CYCLES: u32 = 3;
/// Length of the input shaper's history, cycles (its longest span, a full period of the
/// contact mode, is at most `SHAPER_LEN − 2`: modes down to ≈ 33 Hz).
const SHAPER_LEN: usize = 32;
/// Share of the contact mode's stiffness held by the environment up to which the motion
/// into the surface is fully shaped (k_env ≤ k_arm / 9: 5–35 N/mm on the prototype).
const SHAPER_FULL_SHARE: f64 = 0.1;
/// Share from which it is not shaped at all (k_env ≥ 0.43 k_arm: ≈ 140 N/mm and stiffer).
const SHAPER_NONE_SHARE: f64 = 0.3;
/// Touch-down estimate: the force along the normal below which the approach counts as not
/// yet touching (≈ 2.5 × the filtered noise: the fit averages the noise), N.
const TOUCHDOWN_FLOOR_N: f64 = 0.1;
/// Touch-down estimate: fewest cycles of force build-up before contact.
const TOUCHDOWN_MIN_CYCLES: usize = 10;
/// Share of the force limit at which the measured force's magnitude (whatever the normal
/// estimate) backs the force-guided command off.
const MAGNITUDE_LIMIT_SHARE: f64 = 0.95;
/// Force guard: the arm may be this much stiffer than assumed.
const GUARD_ARM_STIFFNESS_MARGIN: f64 = 1.5;
/// Force guard: estimator updates on this contact before its figure is used.
const GUARD_TRUST_UPDATES: u32 = 10;
/// Force guard: share of the measured compliance it counts on.
const GUARD_MEASURED_COMPLIANCE_SHARE: f64 = 0.5;
/// Force guard: compliance along the normal when Λ(x) cannot be evaluated, mm/N.
const GUARD_FALLBACK_COMPLIANCE_MM_PER_N: f64 = 1e-3;
/// Resonance gain assumed for the contact mode (the tool's mass between the arm and the
/// surface) where only the arm's structural damping damps it (ζ ≈ 0.05).
const MODE_Q: f64 = 10.0;
/// Largest loop gain at the contact mode.
const MODE_LOOP_GAIN: f64 = 0.6;
/// The sliding normal's time constant grows by this factor times the estimated
/// environment compliance (mm/N): ×3 on 5 N/mm, ×1.5 on 20 N/mm, ×1.01 on aluminium.
const SOFT_NORMAL_SLOWDOWN_N_PER_MM: f64 = 10.0;
/// Time constant of the normal estimate at a standstill under a steady force (force
/// direction), s.
const STANDSTILL_NORMAL_TIME_CONSTANT_S: f64 = 0.1;
/// Time constant of the normal estimate right after touching (force direction), s.
const ONSET_NORMAL_TIME_CONSTANT_S: f64 = 0.01;
/// Per-cycle fade of the deflection compensation outside force control.
const COMP_FADE: f64 = 0.98;
/// Smallest displacement over the motion window that counts as sliding, mm.
const MOTION_MIN_MM: f64 = 0.01;
/// Displacement over the motion window from which the normal update has full weight, mm.
const MOTION_FULL_MM: f64 = 0.1;

#[derive(Clone, Copy, Debug, PartialEq)]
enum SafeStopPhase {
    Inactive,
    RampDown {
        remaining_s: f64,
        from_n: f64,
    },
    Retract {
        remaining_mm: f64,
    },
    /// Pressed against something without force control (position mode): back away along
    /// the measured force until it falls below the contact threshold.
    Release {
        moved_mm: f64,
    },
    Done,
}

/// The slave controller. Build it once; call [`SlaveController::step`] every cycle.
#[derive(Clone, Debug)]
pub struct SlaveController {
    ws: Workspace,
    /// 1/k of each actuator (the assumed stiffness), mm/N.
    actuator_compliance: [f64; 4],
    p: ControllerParams,
    initialised: bool,
    cycles: u64,
    // Tare.
    tare_sum: Vector4<f64>,
    tare_n: u32,
    bias: Vector4<f64>,
    // Command state.
    x_cmd: Pose,
    comp: Pose,
    comp_err: f64,
    v_ref: Pose,
    l_cmd: [f64; 4],
    // Contact state.
    in_contact: bool,
    ever_contact: bool,
    lost: bool,
    below_cycles: u32,
    normal: Vector3<f64>,
    tangent: Vector3<f64>,
    sp1: f64,
    sp2: f64,
    track_speed: f64,
    swing: f64,
    swing2: f64,
    de_prev: f64,
    gain_guard: f64,
    e_prev: f64,
    depth_step_mm: f64,
    // Estimator.
    c_env: f64,
    c_tot: f64,
    p_rls: f64,
    est_updates: u32,
    pos_filters: [Butterworth2; 3],
    hist_x: [[f64; 3]; WINDOW_MAX],
    hist_f: [Vector3<f64>; WINDOW_MAX],
    hist_head: usize,
    /// Past increments of the motion into the surface (input shaper), newest at
    /// `shaper_head`, mm.
    shaper_hist: [f64; SHAPER_LEN],
    shaper_head: usize,
    contact_cycles: u32,
    /// Consecutive approach cycles with the force above [`CONTACT_ONSET_FRACTION`] of the
    /// contact threshold.
    onset_cycles: u32,
    safe: SafeStopPhase,
    last: ControllerOutput,
}

impl SlaveController {
    /// A controller for the arm `ws` whose actuators it assumes to have stiffness
    /// `assumed_stiffness`.
    pub fn new(
        ws: Workspace,
        assumed_stiffness: ActuatorStiffness,
        params: ControllerParams,
    ) -> Self {
        let pf = Butterworth2::new(params.sensor_filter_cutoff_hz, 1000.0);
        let c_env = 1.0 / params.initial_env_stiffness_n_per_mm.max(1e-6);
        SlaveController {
            ws,
            actuator_compliance: assumed_stiffness.n_per_mm.map(|k| 1.0 / k).into(),
            p: params,
            initialised: false,
            cycles: 0,
            tare_sum: Vector4::zeros(),
            tare_n: 0,
            bias: Vector4::zeros(),
            x_cmd: Pose::zeros(),
            comp: Pose::zeros(),
            comp_err: 0.0,
            v_ref: Pose::zeros(),
            l_cmd: [0.0; 4],
            in_contact: false,
            ever_contact: false,
            lost: false,
            below_cycles: 0,
            normal: Vector3::zeros(),
            tangent: Vector3::zeros(),
            sp1: 0.0,
            sp2: 0.0,
            track_speed: 0.0,
            swing: 0.0,
            swing2: 0.0,
            de_prev: 0.0,
            gain_guard: 1.0,
            e_prev: 0.0,
            depth_step_mm: 0.0,
            c_env,
            c_tot: c_env,
            p_rls: 100.0,
            est_updates: 0,
            pos_filters: [pf; 3],
            hist_x: [[0.0; 3]; WINDOW_MAX],
            hist_f: [Vector3::zeros(); WINDOW_MAX],
            hist_head: 0,
            shaper_hist: [0.0; SHAPER_LEN],
            shaper_head: 0,
            contact_cycles: 0,
            onset_cycles: 0,
            safe: SafeStopPhase::Inactive,
            last: ControllerOutput {
                actuators_cmd_mm: [0.0; 4],
                commanded_pose: [0.0; 4],
                measured_pose: [0.0; 4],
                contact_normal: [0.0; 3],
                tracking_direction: [0.0; 3],
                wrench_measured: [0.0; 4],
                wrench_desired: [0.0; 4],
                normal_force_n: 0.0,
                setpoint_n: 0.0,
                env_stiffness_n_per_mm: 1.0 / c_env,
                compliance_mm_per_n: c_env,
                status: Status::Taring,
                rejection: None,
            },
        }
    }

    /// The parameters.
    pub fn params(&self) -> &ControllerParams {
        &self.p
    }

    /// Starts a safe stop (for a watchdog): the force set-point ramps to zero, the arm
    /// retracts along the contact normal by `safe_stop_retract_mm`, then holds. Commands
    /// are ignored until [`SlaveController::clear_safe_stop`].
    pub fn safe_stop(&mut self) {
        if matches!(self.safe, SafeStopPhase::Inactive) {
            self.safe = if self.in_contact {
                SafeStopPhase::RampDown {
                    remaining_s: self.p.safe_stop_ramp_s,
                    from_n: self.sp2,
                }
            } else {
                // Not in force control, but possibly pressed into a surface by a position
                // command: released in `step`, where the measured force is known.
                SafeStopPhase::Release { moved_mm: 0.0 }
            };
            self.v_ref = Pose::zeros();
        }
    }

    /// True while a safe stop is in progress or holding.
    pub fn is_safe_stopped(&self) -> bool {
        !matches!(self.safe, SafeStopPhase::Inactive)
    }

    /// Leaves the safe stop; the next command is followed from the current pose.
    pub fn clear_safe_stop(&mut self) {
        self.safe = SafeStopPhase::Inactive;
        self.v_ref = Pose::zeros();
        self.in_contact = false;
        self.lost = false;
    }

    fn reject(&mut self, r: Rejection) -> ControllerOutput {
        let mut out = self.last;
        out.status = Status::Rejected;
        out.rejection = Some(r);
        out
    }

    /// One control cycle of `dt_s` seconds (normally 0.001).
    pub fn step(&mut self, input: &ControllerInput, dt_s: f64) -> ControllerOutput {
        let cmd = &input.command;
        let finite = input.actuators_mm.iter().all(|v| v.is_finite())
            && input.wrench.iter().all(|v| v.is_finite())
            && cmd.pose.iter().all(|v| v.is_finite())
            && cmd.velocity.iter().all(|v| v.is_finite())
            && cmd.force_setpoint_n.is_finite()
            && dt_s.is_finite()
            && dt_s > 0.0;
        if !finite {
            return self.reject(Rejection::NonFiniteInput);
        }
        let dt = dt_s.min(0.1);
        self.cycles += 1;
        let q = Vector4::from(input.actuators_mm);
        let pose_fk = match self.ws.params.fk(&q) {
            Ok(p) => p,
            Err(e) => return self.reject(Rejection::MeasuredPose(e)),
        };
        if !self.initialised {
            self.x_cmd = pose_fk;
            self.l_cmd = input.actuators_mm;
            self.initialised = true;
            let x = [pose_fk[0], pose_fk[1], pose_fk[2]];
            for (i, f) in self.pos_filters.iter_mut().enumerate() {
                f.reset(x[i]);
            }
            for h in self.hist_x.iter_mut() {
                *h = x;
            }
        }
        // Sensor bias: averaged over the first cycles, in free space, holding still.
        let raw = Vector4::from(input.wrench);
        if self.tare_n < self.p.tare_cycles {
            self.tare_sum += raw;
            self.tare_n += 1;
            self.bias = self.tare_sum / f64::from(self.tare_n);
            let mut out = self.output(pose_fk, raw - self.bias, 0.0, Status::Taring);
            out.actuators_cmd_mm = self.l_cmd;
            self.last = out;
            return out;
        }
        let wrench = raw - self.bias;
        let f3 = Vector3::new(wrench[0], wrench[1], wrench[2]);
        // Out of force control the deflection compensation fades out (no jump).
        if !(self.in_contact && cmd.mode == Mode::ForceGuided) {
            self.comp *= COMP_FADE;
        }

        // Compliance of the arm at the measured pose (assumed actuator stiffness).
        let full_lambda = if self.p.compliance_model {
            self.compliance(&pose_fk)
        } else {
            None
        };
        let lambda: Option<Matrix3<f64>> =
            full_lambda.map(|m| m.fixed_view::<3, 3>(0, 0).into_owned());
        // The force guard needs the arm's compliance even without the model.
        let guard_lambda: Option<Matrix3<f64>> = match lambda {
            Some(l) => Some(l),
            None => self
                .compliance(&pose_fk)
                .map(|m| m.fixed_view::<3, 3>(0, 0).into_owned()),
        };
        let measured_pose = match &full_lambda {
            Some(full) => pose_fk + mat4_vec(full, [wrench[0], wrench[1], wrench[2], wrench[3]]),
            None => pose_fk,
        };

        // Position history, filtered like the force, for the stiffness estimator.
        let xf = [
            self.pos_filters[0].update(pose_fk[0]),
            self.pos_filters[1].update(pose_fk[1]),
            self.pos_filters[2].update(pose_fk[2]),
        ];
        let win = (self.p.estimator_window_cycles as usize).clamp(2, WINDOW_MAX - 1);
        self.hist_head = (self.hist_head + 1) % WINDOW_MAX;
        self.hist_x[self.hist_head] = xf;
        self.hist_f[self.hist_head] = f3;
        let old = (self.hist_head + WINDOW_MAX - win) % WINDOW_MAX;

        // Safe stop overrides the command.
        let mut eff = *cmd;
        let mut safe_status = false;
        match self.safe {
            SafeStopPhase::Inactive => {}
            SafeStopPhase::RampDown {
                remaining_s,
                from_n,
            } => {
                safe_status = true;
                let rem = remaining_s - dt;
                let frac = (rem / self.p.safe_stop_ramp_s.max(1e-6)).clamp(0.0, 1.0);
                eff.mode = Mode::ForceGuided;
                eff.force_setpoint_n = from_n * frac;
                eff.velocity = [0.0; 4];
                eff.pose = [self.x_cmd[0], self.x_cmd[1], self.x_cmd[2], self.x_cmd[3]];
                eff.clutch = false;
                self.safe = if rem <= 0.0 {
                    SafeStopPhase::Retract {
                        remaining_mm: self.p.safe_stop_retract_mm,
                    }
                } else {
                    SafeStopPhase::RampDown {
                        remaining_s: rem,
                        from_n,
                    }
                };
            }
            SafeStopPhase::Retract { remaining_mm } => {
                let step = (self.p.approach_speed_mm_per_s * 2.0 * dt).min(remaining_mm);
                let n = if self.normal.norm() > 0.5 {
                    self.normal
                } else {
                    Vector3::z()
                };
                let mut next = self.x_cmd;
                for i in 0..3 {
                    next[i] += n[i] * step;
                }
                let rem = remaining_mm - step;
                self.safe = if rem <= 1e-9 {
                    SafeStopPhase::Done
                } else {
                    SafeStopPhase::Retract { remaining_mm: rem }
                };
                self.in_contact = false;
                return self.commit(next, pose_fk, measured_pose, wrench, 0.0, Status::SafeStop);
            }
            SafeStopPhase::Release { moved_mm } => {
                let f_mag = f3.norm();
                let mut next = self.x_cmd;
                let status = if f_mag > self.p.contact_threshold_n
                    && moved_mm < self.p.safe_stop_release_max_mm
                {
                    // Back away along the measured force, as fast as a retract.
                    let step = self.p.approach_speed_mm_per_s * 2.0 * dt;
                    self.normal = f3 / f_mag;
                    for i in 0..3 {
                        next[i] += self.normal[i] * step;
                    }
                    self.safe = SafeStopPhase::Release {
                        moved_mm: moved_mm + step,
                    };
                    Status::SafeStop
                } else if moved_mm > 0.0 {
                    // Free: the usual retract along the last force direction, then hold.
                    self.safe = SafeStopPhase::Retract {
                        remaining_mm: self.p.safe_stop_retract_mm,
                    };
                    Status::SafeStop
                } else {
                    self.safe = SafeStopPhase::Done;
                    Status::Holding
                };
                self.in_contact = false;
                return self.commit(next, pose_fk, measured_pose, wrench, 0.0, status);
            }
            SafeStopPhase::Done => {
                self.in_contact = false;
                return self.commit(
                    self.x_cmd,
                    pose_fk,
                    measured_pose,
                    wrench,
                    0.0,
                    Status::Holding,
                );
            }
        }

        // Command checks.
        let speed = Vector3::new(eff.velocity[0], eff.velocity[1], eff.velocity[2]).norm();
        if speed > self.p.max_speed_mm_per_s {
            return self.reject(Rejection::SpeedOutOfRange {
                value_mm_per_s: speed,
                limit_mm_per_s: self.p.max_speed_mm_per_s,
            });
        }
        if eff.mode == Mode::ForceGuided
            && !(eff.force_setpoint_n >= 0.0 && eff.force_setpoint_n <= self.p.force_limit_n)
        {
            return self.reject(Rejection::SetpointOutOfRange {
                value_n: eff.force_setpoint_n,
                limit_n: self.p.force_limit_n,
            });
        }
        // A Position target must lie in the workspace. (A ForceGuided approach target
        // may lie beyond the surface: every commanded step is still checked in `commit`.)
        if eff.mode == Mode::Position
            && let Err(e) = self.ws.ik(&Pose::from(eff.pose))
        {
            return self.reject(Rejection::Workspace(e));
        }

        let f_mag = f3.norm();
        if eff.mode != Mode::ForceGuided {
            self.in_contact = false;
            self.lost = false;
        }
        if eff.mode == Mode::Hold || eff.clutch {
            self.v_ref = Pose::zeros();
            let status = if safe_status {
                Status::SafeStop
            } else {
                Status::Holding
            };
            let mut next = self.x_cmd;
            if f_mag > self.p.force_limit_n {
                self.back_off(&mut next, f3, f_mag, lambda.as_ref());
            }
            return self.commit(next, pose_fk, measured_pose, wrench, 0.0, status);
        }

        if eff.mode == Mode::Position {
            let mut next = self.x_cmd;
            let target = Pose::from(eff.pose);
            for j in 0..4 {
                let (vmax, amax) = if j < 3 {
                    (
                        self.p.max_speed_mm_per_s / 3f64.sqrt(),
                        self.p.max_accel_mm_per_s2 / 3f64.sqrt(),
                    )
                } else {
                    (
                        self.p.max_theta_rate_rad_per_s,
                        self.p.max_theta_rate_rad_per_s * 10.0,
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
            if f_mag > self.p.contact_threshold_n
                && self.position_force_guard(&mut next, xf, f3, f_mag, lambda.as_ref(), dt)
            {
                status = Status::ForceLimited;
            }
            if f_mag > self.p.force_limit_n {
                self.v_ref = Pose::zeros();
                next = self.x_cmd;
                self.back_off(&mut next, f3, f_mag, lambda.as_ref());
                status = Status::ForceLimited;
            }
            return self.commit(next, pose_fk, measured_pose, wrench, 0.0, status);
        }

        // ForceGuided.
        self.v_ref = Pose::zeros();
        let mut next = self.x_cmd;
        // theta follows the command, rate limited.
        let dth = (eff.pose[3] - next[3]).clamp(
            -self.p.max_theta_rate_rad_per_s * dt,
            self.p.max_theta_rate_rad_per_s * dt,
        );
        next[3] += dth;
        let status;
        if !self.in_contact {
            // Contact: the force crosses the threshold, or it has stayed above 3/8 of it
            // for a few cycles in a row (a soft surface, on which the force builds up
            // slowly: 0.8 N takes ≈ 80 ms of the approach on 5 N/mm). A stiff surface
            // crosses the threshold itself within a cycle or two.
            if f_mag > CONTACT_ONSET_FRACTION * self.p.contact_threshold_n {
                self.onset_cycles = self.onset_cycles.saturating_add(1);
            } else {
                self.onset_cycles = 0;
            }
            if f_mag > self.p.contact_threshold_n || self.onset_cycles >= CONTACT_ONSET_CYCLES {
                // First touch (or touch again): bumpless start of the force loop.
                self.onset_cycles = 0;
                self.in_contact = true;
                self.ever_contact = true;
                self.lost = false;
                self.below_cycles = 0;
                self.normal = f3 / f_mag;
                self.sp1 = f_mag;
                self.sp2 = f_mag;
                self.comp_err = 0.0;
                self.e_prev = 0.0;
                self.de_prev = 0.0;
                self.depth_step_mm = 0.0;
                self.shaper_hist = [0.0; SHAPER_LEN];
                self.contact_cycles = 0;
                self.track_speed = 0.0;
                self.p_rls = 100.0;
                self.est_updates = 0;
                let c_arm_touch = self.arm_compliance(lambda.as_ref());
                self.c_tot = c_arm_touch + self.c_env;
                if self.p.estimate_env_stiffness {
                    self.seed_from_touchdown(c_arm_touch);
                }
                status = Status::Contact;
            } else {
                // Approach: towards the commanded point, or along the last normal.
                let step = self.p.approach_speed_mm_per_s * dt;
                let mv = if self.lost && self.normal.norm() > 0.5 {
                    -self.normal * step
                } else {
                    let d = Vector3::new(
                        eff.pose[0] - next[0],
                        eff.pose[1] - next[1],
                        eff.pose[2] - next[2],
                    );
                    let dn = d.norm();
                    if dn > 1e-12 {
                        d * (step.min(dn) / dn)
                    } else {
                        Vector3::zeros()
                    }
                };
                for i in 0..3 {
                    next[i] += mv[i];
                }
                self.tangent = Vector3::zeros();
                let st = if self.lost {
                    Status::ContactLost
                } else {
                    Status::Approaching
                };
                return self.commit(
                    next,
                    pose_fk,
                    measured_pose,
                    wrench,
                    0.0,
                    if safe_status { Status::SafeStop } else { st },
                );
            }
        } else {
            status = Status::Contact;
        }
        self.contact_cycles = self.contact_cycles.saturating_add(1);

        // Contact normal. While the tool slides, friction acts along its motion, so the
        // normal is the measured force without its component along the measured direction
        // of motion (figure 2's construction, made friction-proof). Right after touching
        // it is the force's direction; at a standstill it is held (the friction force of
        // a stuck tool says nothing about the normal).
        let oldest = (self.hist_head + 1) % WINDOW_MAX;
        let xo = self.hist_x[oldest];
        // The tool sinks deeper or rises as the force changes: add back that part of the
        // displacement (compliance × force change along the normal), so what is left is
        // the motion of the contact point along the surface.
        let d_fn_window = (f3 - self.hist_f[oldest]).dot(&self.normal);
        let c_prev = self.arm_compliance(lambda.as_ref()) + self.c_env;
        let depth_change = c_prev * d_fn_window;
        let disp =
            Vector3::new(xf[0] - xo[0], xf[1] - xo[1], xf[2] - xo[2]) + self.normal * depth_change;
        // Without a commanded motion along the surface the displacement is trusted only
        // while the force is steady (the depth correction is then small): what is left is
        // the tool creeping along the surface under a tilted push, and removing friction
        // along it turns the normal towards the true one.
        let steady = d_fn_window.abs() < STEADY_FORCE_CHANGE_N;
        let disp = if speed > 0.0 || steady {
            disp
        } else {
            Vector3::zeros()
        };
        let disp_n = disp.norm();
        // A large depth correction rests on the compliance estimate: then the direction of
        // motion is not trusted (soft surfaces while the force still changes).
        let moving = self.contact_cycles as usize >= WINDOW_MAX
            && disp_n > MOTION_MIN_MM
            && depth_change.abs() < DEPTH_TRUST * disp_n;
        let n_raw = if moving {
            let tm = disp / disp_n;
            Some(f3 - tm * f3.dot(&tm))
        } else if self.contact_cycles < ONSET_CYCLES {
            Some(f3)
        } else if speed == 0.0 && steady && self.contact_cycles as usize >= WINDOW_MAX {
            // At a standstill under a steady force the normal is only known to lie in the
            // friction cone around the force; the force's direction is the best guess (the
            // cone's centre), and it turns to the true normal as a tilted touch-down's
            // friction relaxes. Slowly: the friction left over is not a measurement.
            Some(f3)
        } else {
            None
        };
        let standstill = !moving && self.contact_cycles >= ONSET_CYCLES;
        if let Some(v) = n_raw {
            let vn = v.norm();
            if vn > self.p.contact_lost_n.max(0.1) {
                let tau = if moving {
                    // Deep in a soft surface the motion's direction carries the depth
                    // corrections (millimetres): trust it more slowly there.
                    self.p.normal_time_constant_s
                        * (1.0 + SOFT_NORMAL_SLOWDOWN_N_PER_MM * self.c_env)
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
                let a = (dt / tau.max(dt) * weight).min(1.0);
                let n_new = self.normal + (v / vn - self.normal) * a;
                let nn = n_new.norm();
                if nn > 1e-9 {
                    self.normal = n_new / nn;
                }
            }
        }
        let n = self.normal;
        let f_n = f3.dot(&n);

        // Tracking direction: commanded direction projected on the tangent plane (fig. 2).
        let v3 = Vector3::new(eff.velocity[0], eff.velocity[1], eff.velocity[2]);
        let vt = v3 - n * v3.dot(&n);
        let vt_n = vt.norm();
        self.tangent = if speed > 1e-9 && vt_n > 1e-9 {
            vt / vt_n
        } else {
            Vector3::zeros()
        };

        // Set-point prefilter.
        // Gain schedule (docs/slave-results.md, "Gain schedule"). With the compliance
        // right, the loop (command c·ΔF → force) is an integrator of gain ki at low
        // frequency: the same bandwidth on every surface. What limits the gains is the
        // contact mode, the tool's mass between the arm's and the surface's stiffness (in
        // parallel: both hold the tool), ω_m = sqrt((k_arm + k_env)/m), which only the
        // arm's structural damping damps on a soft surface (resonance gain up to
        // MODE_Q). The controller's gain at ω_m, |kp + ki/(jω_m)|, times the resonance
        // gain and the sensor filter's |H(jω_m)| must stay below MODE_LOOP_GAIN. On a
        // stiff surface ω_m is far above the filter's cut-off and the tuned gains pass;
        // on a soft one ω_m sits at the cut-off: the proportional gain (which acts at
        // high frequency) goes first, then the integral gain.
        // The arm's compliance along the (updated) normal, from the model.
        let c_arm = self.arm_compliance(lambda.as_ref());
        let c_arm_s = c_arm.max(1e-9);
        let k_par = 1.0 / c_arm_s + 1.0 / self.c_env.max(1e-9);
        let omega_m = (1000.0 * k_par / self.p.tool_mass_kg.max(1e-6)).sqrt();
        let w_f = omega_m / (2.0 * std::f64::consts::PI * self.p.sensor_filter_cutoff_hz.max(1.0));
        let h_f = 1.0 / (1.0 + w_f * w_f * w_f * w_f).sqrt();
        let allowed = MODE_LOOP_GAIN / (MODE_Q * h_f);
        let ki_w = self.p.ki_per_s / omega_m;
        let ki_scale = (allowed / ki_w.max(1e-12)).min(1.0);
        let kp_scale = if self.p.kp > 0.0 {
            ((allowed - ki_w).max(0.0) / self.p.kp).min(1.0)
        } else {
            1.0
        };
        let tau_sp = self.p.setpoint_time_constant_s;
        let a_sp = (dt / tau_sp.max(dt)).min(1.0);
        let sp_prev = self.sp2;
        self.sp1 += (eff.force_setpoint_n - self.sp1) * a_sp;
        self.sp2 += (self.sp1 - self.sp2) * a_sp;
        let d_sp = self.sp2 - sp_prev;

        // Compliance along the normal: the arm's (model) plus the environment's (estimate).
        if self.p.estimate_env_stiffness && self.contact_cycles as usize > win {
            let d_f = self.hist_f[self.hist_head].dot(&n) - self.hist_f[old].dot(&n);
            let xo = self.hist_x[old];
            let d_p = n[0] * (xf[0] - xo[0]) + n[1] * (xf[1] - xo[1]) + n[2] * (xf[2] - xo[2]);
            // Pushing in can only raise the force: increments of the other sign are lag or
            // noise and would drag the estimate through zero.
            if d_f.abs() > self.p.estimator_excitation_n && -d_p * d_f > 0.0 {
                let lam = self.p.estimator_forgetting.clamp(0.5, 1.0);
                let y = -d_p;
                let g = self.p_rls * d_f / (lam + d_f * self.p_rls * d_f);
                self.c_tot += g * (y - self.c_tot * d_f);
                self.p_rls = ((self.p_rls - g * d_f * self.p_rls) / lam).clamp(1e-9, 100.0);
                let c_min = 1.0 / self.p.env_stiffness_max_n_per_mm.max(1e-6);
                let c_max = 1.0 / self.p.env_stiffness_min_n_per_mm.max(1e-6);
                self.c_env = (self.c_tot - c_arm).clamp(c_min, c_max);
                self.est_updates = self.est_updates.saturating_add(1);
            }
        }
        let c = c_arm + self.c_env;

        // The arm's deflection under the measured wrench, Λ(x)F, moves the tool sideways
        // (Λ couples the axes): command the opposite of its tangential part (and of its
        // rotation), so the tool stays on its path and does not drag friction sideways.
        // The normal part is left to the force loop (compensating it would close a positive
        // feedback loop through the contact).
        // The force the compensation is for: the prefiltered set-point (smooth, no sensor
        // lag), corrected by the low-passed difference to the measured force. Fed the
        // measured force directly, its ripple (and its lag) would drive the arm's lightly
        // damped tangential modes, which off the centre line push back on the normal force
        // through the coupling of Λ (a closed loop that went unstable when tracking along
        // y at 10 mm/s); the set-point also leads the deflection at touch-down instead of
        // trailing it, so the tool does not slide sideways (and tilt the force by friction)
        // while the force builds up.
        let a_comp = (dt / self.p.deflection_comp_time_constant_s.max(dt)).min(1.0);
        self.comp_err += ((f_n - self.sp2) - self.comp_err) * a_comp;
        let f_comp = self.sp2 + self.comp_err;
        self.comp = match &full_lambda {
            Some(full) => {
                // The normal force's deflection only: friction's share is left alone, so
                // the compensation cannot drag the tool and feed friction back into itself.
                let d = mat4_vec(full, [n[0] * f_comp, n[1] * f_comp, n[2] * f_comp, 0.0]);
                let d3 = Vector3::new(d[0], d[1], d[2]);
                let dt3 = d3 - n * d3.dot(&n);
                Pose::new(-dt3[0], -dt3[1], -dt3[2], -d[3])
            }
            None => Pose::zeros(),
        };

        // Implicit force law (incremental form: bumpless when c changes).
        let e = self.sp2 - f_n;
        // Oscillation guard: a force error that swings from cycle to cycle far beyond the
        // sensor noise means a resonance inside the loop (e.g. the tool's mass between the
        // arm and a stiff surface): back the loop gains off until it calms down, then let
        // them recover slowly.
        // The detector uses the error's second difference, which a ramp (a soft surface's
        // fast, legitimate force rise) leaves alone; the first difference's swing is kept
        // for the force guard's estimate of an oscillation's peak.
        let de = e - self.e_prev;
        // Fast attack, slow release: a bounce's first swings already count.
        let k_swing = if de.abs() > self.swing {
            SWING_ATTACK
        } else {
            SWING_FILTER
        };
        self.swing += (de.abs() - self.swing) * k_swing;
        self.swing2 += ((de - self.de_prev).abs() - self.swing2) * SWING_FILTER;
        self.de_prev = de;
        if self.swing2 > SWING2_LIMIT_N {
            self.gain_guard = (self.gain_guard * GUARD_DECAY).max(GUARD_MIN);
        } else {
            self.gain_guard = (self.gain_guard * GUARD_RECOVERY).min(1.0);
        }
        let mut d_depth = c
            * (self.p.feedforward_gain * d_sp
                + self.gain_guard
                    * (kp_scale * self.p.kp * (e - self.e_prev)
                        + ki_scale * self.p.ki_per_s * e * dt));
        self.e_prev = e;
        let mut status = status;
        // The force the sensor does not show yet: a resonance's peaks are filtered down
        // (an oscillation's amplitude is a few times its mean cycle-to-cycle swing).
        let f_peak = f_n + GUARD_PEAK_PER_SWING * self.swing;
        if f_peak > self.p.force_limit_n {
            d_depth = -c.max(1e-6) * (f_peak - self.p.force_limit_n);
            status = Status::ForceLimited;
        }
        let dmax = self.p.max_speed_mm_per_s * dt;
        d_depth = d_depth.clamp(-dmax, dmax);
        if status != Status::ForceLimited {
            let amax = self.p.force_accel_mm_per_s2 * dt * dt;
            d_depth = d_depth.clamp(self.depth_step_mm - amax, self.depth_step_mm + amax);
        }
        self.depth_step_mm = d_depth;
        // The motion into the surface, shaped so that it does not ring the contact mode
        // (soft surfaces only; a force-limit back-off goes out unshaped).
        let env_share = (1.0 / self.c_env.max(1e-9)) / k_par;
        let d_shaped = self.shape_normal(d_depth, omega_m, env_share, dt);
        let d_depth = if status == Status::ForceLimited {
            d_depth
        } else {
            d_shaped
        };
        let mut mv = -n * d_depth;
        // Motion along the surface only while the force is established.
        // The speed along the surface ramps with the tracking acceleration limit, so the
        // contact normal (estimated from the motion) settles before the speed is high.
        let target_speed = if self.lost {
            0.0
        } else {
            vt_n.min(self.p.max_speed_mm_per_s)
        };
        let dv = self.p.track_accel_mm_per_s2 * dt;
        self.track_speed = (target_speed).clamp(self.track_speed - 4.0 * dv, self.track_speed + dv);
        mv += self.tangent * self.track_speed * dt;
        let mvn = mv.norm();
        if mvn > dmax {
            mv *= dmax / mvn;
        }
        for i in 0..3 {
            next[i] += mv[i];
        }
        // Once the estimator has measured this contact, the guard may count on half its
        // compliance (the contact up to twice as stiff as measured) instead of a rigid one.
        let c_measured = if self.p.estimate_env_stiffness && self.est_updates >= GUARD_TRUST_UPDATES
        {
            let c_arm_guard = if self.p.compliance_model {
                c_arm
            } else {
                self.arm_compliance(guard_lambda.as_ref())
            };
            GUARD_MEASURED_COMPLIANCE_SHARE * (c_arm_guard + self.c_env)
        } else {
            0.0
        };
        if self.force_guard(
            &mut next,
            xf,
            f_peak,
            guard_lambda.as_ref(),
            c_measured,
            dmax,
        ) {
            status = Status::ForceLimited;
        }

        // Whatever the normal estimate says, the measured force's magnitude near the limit
        // backs the command off along the force (as Hold and Position mode do). A normal
        // estimate tilted by friction (a soft surface with dry friction) otherwise let the
        // true force drift past the limit over seconds while the force along the estimate
        // stayed at the set-point. 5 % of the limit is kept for the filter's lag and noise.
        let magnitude_limit = MAGNITUDE_LIMIT_SHARE * self.p.force_limit_n;
        if f_mag > magnitude_limit {
            let dir = f3 / f_mag;
            let c_dir = guard_lambda
                .as_ref()
                .map_or(0.0, |l| quad_form(l, &dir).max(0.0))
                + self.c_env;
            let step = (c_dir * (f_mag - magnitude_limit)).min(dmax);
            for i in 0..3 {
                next[i] += dir[i] * step;
            }
            status = Status::ForceLimited;
        }

        // Contact loss.
        if f_n < self.p.contact_lost_n && eff.force_setpoint_n > self.p.contact_lost_n {
            self.below_cycles += 1;
            if self.below_cycles >= self.p.contact_lost_cycles {
                self.in_contact = false;
                self.lost = true;
                self.below_cycles = 0;
                self.e_prev = 0.0;
                self.tangent = Vector3::zeros();
                status = Status::ContactLost;
            }
        } else {
            self.below_cycles = 0;
        }
        if safe_status {
            status = Status::SafeStop;
        }
        self.commit(next, pose_fk, measured_pose, wrench, c, status)
    }

    /// Force guard, a safety limiter independent of the force law (and of whether the Λ
    /// model is used): the command may lead the encoders' position (filtered like the
    /// sensor, so that both lag alike) into the surface only by as much as would keep the
    /// force under the limit if the surface were rigid (or, once measured, `c_measured`
    /// compliant), the arm [`GUARD_ARM_STIFFNESS_MARGIN`] times stiffer than assumed and
    /// the tool's mass rang to twice the static force (a lightly damped step response).
    /// Returns whether it clipped the command.
    fn force_guard(
        &self,
        next: &mut Pose,
        xf: [f64; 3],
        f_peak: f64,
        lambda: Option<&Matrix3<f64>>,
        c_measured: f64,
        dmax: f64,
    ) -> bool {
        let n = self.normal;
        let c_rigid = (match lambda {
            Some(l) => quad_form(l, &n).max(0.0),
            None => GUARD_FALLBACK_COMPLIANCE_MM_PER_N,
        } / GUARD_ARM_STIFFNESS_MARGIN)
            .max(c_measured);
        let headroom = self.p.force_limit_n - f_peak;
        let allowed = 0.5 * headroom * c_rigid;
        let pending = (0..3)
            .map(|i| n[i] * (xf[i] - (next[i] + self.comp[i])))
            .sum::<f64>();
        if pending > allowed {
            let back = (pending - allowed).min(dmax);
            for i in 0..3 {
                next[i] += n[i] * back;
            }
            true
        } else {
            false
        }
    }

    /// Force guard of position mode (a teleoperated push into a wall: no force law runs):
    /// along the measured force, the command may lead the encoders' position (filtered like
    /// the sensor) into the surface only by as much as keeps the force under the limit if the
    /// surface were rigid, the arm [`GUARD_ARM_STIFFNESS_MARGIN`] times stiffer than assumed
    /// and the tool rang to twice the static force. The trajectory's speed into the surface is
    /// dropped when it clips. Returns whether it clipped the command.
    fn position_force_guard(
        &mut self,
        next: &mut Pose,
        xf: [f64; 3],
        f3: Vector3<f64>,
        f_mag: f64,
        lambda: Option<&Matrix3<f64>>,
        dt: f64,
    ) -> bool {
        let n = f3 / f_mag;
        let c_rigid = match lambda {
            Some(l) => quad_form(l, &n).max(0.0),
            None => GUARD_FALLBACK_COMPLIANCE_MM_PER_N,
        } / GUARD_ARM_STIFFNESS_MARGIN;
        // 5 % of the limit is kept for the sensor's filter lag and noise.
        let allowed = 0.5 * (0.95 * self.p.force_limit_n - f_mag).max(0.0) * c_rigid;
        let lead = (0..3).map(|i| n[i] * (xf[i] - next[i])).sum::<f64>();
        if lead <= allowed {
            return false;
        }
        let back = (lead - allowed).min(self.p.max_speed_mm_per_s * dt);
        let v_into = (0..3).map(|i| n[i] * self.v_ref[i]).sum::<f64>().min(0.0);
        for i in 0..3 {
            next[i] += n[i] * back;
            self.v_ref[i] -= n[i] * v_into;
        }
        true
    }

    /// Input shaper (zero vibration and derivative, ZVD) of the motion into the surface:
    /// the increment `d` is spread over three impulses half a period of the contact mode
    /// apart, weighted for the mode's damping ([`MODE_Q`]), so that the motion's corners (the
    /// speed and acceleration limits, the set-point's start) leave no vibration of the tool
    /// on the arm's stiffness. Only where the mode is the arm's own, lightly damped one:
    /// fully where the environment holds at most [`SHAPER_FULL_SHARE`] of the mode's
    /// stiffness, blended out up to [`SHAPER_NONE_SHARE`] (a stiffer surface damps the mode
    /// itself, and the delay would only cost phase). A weighted mean of past increments, so
    /// the speed and acceleration limits still hold. Returns the shaped increment.
    fn shape_normal(&mut self, d: f64, omega_m: f64, env_share: f64, dt: f64) -> f64 {
        self.shaper_head = (self.shaper_head + 1) % SHAPER_LEN;
        self.shaper_hist[self.shaper_head] = d;
        let blend = ((SHAPER_NONE_SHARE - env_share) / (SHAPER_NONE_SHARE - SHAPER_FULL_SHARE))
            .clamp(0.0, 1.0);
        if blend.is_nan() || blend <= 0.0 {
            return d;
        }
        let max_half = 0.5 * (SHAPER_LEN as f64 - 2.0);
        let half = (std::f64::consts::PI / (omega_m.max(1e-6) * dt)).clamp(0.0, max_half);
        let k = (-std::f64::consts::PI / (4.0 * MODE_Q * MODE_Q - 1.0).sqrt()).exp();
        let norm = 1.0 / ((1.0 + k) * (1.0 + k));
        let zvd = norm * (d + 2.0 * k * self.shaper_at(half) + k * k * self.shaper_at(2.0 * half));
        d + blend * (zvd - d)
    }

    /// The shaper's input `delay_cycles` ago, linearly interpolated.
    fn shaper_at(&self, delay_cycles: f64) -> f64 {
        let whole = delay_cycles.floor();
        let frac = delay_cycles - whole;
        let i = whole as usize;
        let at =
            |back: usize| self.shaper_hist[(self.shaper_head + SHAPER_LEN - back) % SHAPER_LEN];
        at(i) + (at(i + 1) - at(i)) * frac
    }

    /// On a soft surface the force builds up over many cycles of the approach before
    /// contact is declared: the force and the (filtered, like the force) position since the
    /// force left the noise floor (a least-squares fit) measure the contact's total
    /// compliance at touch-down, long before the estimator's window has data after it. Used only when the
    /// build-up lasted at least [`TOUCHDOWN_MIN_CYCLES`] (a stiff surface crosses the
    /// threshold within a cycle or two, too few to measure); the estimate then counts as
    /// measured for the force guard.
    fn seed_from_touchdown(&mut self, c_arm: f64) {
        let n = self.normal;
        let head = self.hist_head;
        let at = |back: usize| (head + WINDOW_MAX - back) % WINDOW_MAX;
        let onset = (1..WINDOW_MAX).find(|&back| self.hist_f[at(back)].dot(&n) < TOUCHDOWN_FLOOR_N);
        let Some(cycles) = onset else {
            return;
        };
        if cycles < TOUCHDOWN_MIN_CYCLES || self.cycles < WINDOW_MAX as u64 {
            return;
        }
        // Least-squares slope of the force over the depth (into the surface) since the
        // onset: the noise of a few samples averages out.
        let depth = |idx: usize| {
            let x = self.hist_x[idx];
            -(n[0] * x[0] + n[1] * x[1] + n[2] * x[2])
        };
        let m = cycles as f64;
        let (mut sp, mut sf) = (0.0, 0.0);
        for back in 0..cycles {
            sp += depth(at(back));
            sf += self.hist_f[at(back)].dot(&n);
        }
        let (mp, mf) = (sp / m, sf / m);
        let (mut spp, mut spf) = (0.0, 0.0);
        for back in 0..cycles {
            let dp = depth(at(back)) - mp;
            spp += dp * dp;
            spf += dp * (self.hist_f[at(back)].dot(&n) - mf);
        }
        if spp > 0.0 && spf > 0.0 {
            let c_min = 1.0 / self.p.env_stiffness_max_n_per_mm.max(1e-6);
            let c_max = 1.0 / self.p.env_stiffness_min_n_per_mm.max(1e-6);
            self.c_env = (spp / spf - c_arm).clamp(c_min, c_max);
            self.c_tot = c_arm + self.c_env;
            self.est_updates = GUARD_TRUST_UPDATES;
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

    fn arm_compliance(&self, lambda: Option<&Matrix3<f64>>) -> f64 {
        match lambda {
            Some(l) if self.normal.norm_squared() > 0.25 => quad_form(l, &self.normal).max(0.0),
            _ => 0.0,
        }
    }

    fn back_off(
        &self,
        next: &mut Pose,
        f3: Vector3<f64>,
        f_mag: f64,
        lambda: Option<&Matrix3<f64>>,
    ) {
        let dir = f3 / f_mag;
        let c = match lambda {
            Some(l) => quad_form(l, &dir).max(0.0),
            None => 0.0,
        } + self.c_env;
        let step = (c * (f_mag - self.p.force_limit_n)).min(self.p.max_speed_mm_per_s * 0.001);
        for i in 0..3 {
            next[i] += dir[i] * step;
        }
    }

    fn output(
        &self,
        pose_fk: Pose,
        wrench: Vector4<f64>,
        c: f64,
        status: Status,
    ) -> ControllerOutput {
        let n = self.normal;
        ControllerOutput {
            actuators_cmd_mm: self.l_cmd,
            commanded_pose: [
                self.x_cmd[0] + self.comp[0],
                self.x_cmd[1] + self.comp[1],
                self.x_cmd[2] + self.comp[2],
                self.x_cmd[3] + self.comp[3],
            ],
            measured_pose: [pose_fk[0], pose_fk[1], pose_fk[2], pose_fk[3]],
            contact_normal: [n[0], n[1], n[2]],
            tracking_direction: [self.tangent[0], self.tangent[1], self.tangent[2]],
            wrench_measured: [wrench[0], wrench[1], wrench[2], wrench[3]],
            wrench_desired: if self.in_contact {
                [n[0] * self.sp2, n[1] * self.sp2, n[2] * self.sp2, 0.0]
            } else {
                [0.0; 4]
            },
            normal_force_n: if self.in_contact {
                wrench[0] * n[0] + wrench[1] * n[1] + wrench[2] * n[2]
            } else {
                0.0
            },
            setpoint_n: if self.in_contact { self.sp2 } else { 0.0 },
            env_stiffness_n_per_mm: 1.0 / self.c_env,
            compliance_mm_per_n: c,
            status,
            rejection: None,
        }
    }

    /// Checks `next` against the workspace; on success it becomes the command.
    fn commit(
        &mut self,
        next: Pose,
        pose_fk: Pose,
        measured_pose: Pose,
        wrench: Vector4<f64>,
        c: f64,
        status: Status,
    ) -> ControllerOutput {
        let target = next + self.comp;
        match self.ws.ik(&target) {
            Ok(l) => {
                self.x_cmd = next;
                self.l_cmd = [l[0], l[1], l[2], l[3]];
                let mut out = self.output(pose_fk, wrench, c, status);
                out.measured_pose = [
                    measured_pose[0],
                    measured_pose[1],
                    measured_pose[2],
                    measured_pose[3],
                ];
                self.last = out;
                out
            }
            Err(e) => {
                self.v_ref = Pose::zeros();
                let mut out = self.output(pose_fk, wrench, c, Status::Rejected);
                out.measured_pose = [
                    measured_pose[0],
                    measured_pose[1],
                    measured_pose[2],
                    measured_pose[3],
                ];
                out.rejection = Some(Rejection::Workspace(e));
                self.last = out;
                out
            }
        }
    }
}

/// `M v` (written out: nalgebra's generic product is not inlined here).
#[inline]
fn mat4_vec(m: &Matrix4<f64>, v: [f64; 4]) -> Vector4<f64> {
    let row = |i: usize| m[(i, 0)] * v[0] + m[(i, 1)] * v[1] + m[(i, 2)] * v[2] + m[(i, 3)] * v[3];
    Vector4::new(row(0), row(1), row(2), row(3))
}

/// `nᵀ L n`.
#[inline]
fn quad_form(l: &Matrix3<f64>, n: &Vector3<f64>) -> f64 {
    let mut s = 0.0;
    for i in 0..3 {
        s += n[i] * (l[(i, 0)] * n[0] + l[(i, 1)] * n[1] + l[(i, 2)] * n[2]);
    }
    s
}
