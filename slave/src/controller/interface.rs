//! What one step takes and gives: the command, the measurements, the output, the state
//! reported and the reasons a command is rejected.

use h4_shared::kinematics::KinError;
use h4_shared::wire::Mode;
use serde::Serialize;

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
