//! The experiment's recording: every cycle on `/slave/force`, `/slave/pose` and
//! `/slave/contact`, stamped with the simulated time; the schemas are generated from the
//! message types.

use h4_telemetry::recording::{ChannelId, Recorder, RecordingError};
use schemars::JsonSchema;
use serde::Serialize;

use super::run::Truth;
use h4_slave::controller::ControllerOutput;

/// The three channels.
pub(super) struct Channels {
    force: ChannelId,
    pose: ChannelId,
    contact: ChannelId,
}

/// `/slave/force` (`h4.SlaveForce`).
#[derive(Serialize, JsonSchema)]
struct ForceMsg {
    /// Measured force along the estimated normal, N.
    fn_measured_n: f64,
    /// True contact force along the true normal, N.
    fn_true_n: f64,
    /// Prefiltered set-point, N.
    fn_desired_n: f64,
    /// Commanded set-point, N.
    setpoint_n: f64,
    /// `[Fx, Fy, Fz, My]` bias-corrected, N, N·mm.
    wrench_measured: [f64; 4],
    /// `[Fx, Fy, Fz, My]` desired, N, N·mm.
    wrench_desired: [f64; 4],
    /// The environment stiffness the loop uses, N/mm.
    env_stiffness_n_per_mm: f64,
    /// Total compliance along the normal the loop uses, mm/N.
    compliance_mm_per_n: f64,
    /// The controller's state (`Status::code`).
    status: u8,
}

/// `/slave/pose` (`h4.SlavePose`).
#[derive(Serialize, JsonSchema)]
struct PoseMsg {
    /// Measured `[x, y, z, theta]`, mm, rad.
    measured: [f64; 4],
    /// Commanded `[x, y, z, theta]`, mm, rad.
    commanded: [f64; 4],
    /// True `[x, y, z, theta]`, mm, rad (simulation truth).
    true_pose: [f64; 4],
    /// Actuator commands, mm.
    actuators_cmd_mm: [f64; 4],
}

/// `/slave/contact` (`h4.SlaveContact`).
#[derive(Serialize, JsonSchema)]
struct ContactMsg {
    /// Estimated outward contact normal.
    normal: [f64; 3],
    /// Tracking direction on the surface.
    tracking_direction: [f64; 3],
    /// True outward normal (simulation truth).
    true_normal: [f64; 3],
    /// True penetration into the surface, mm.
    penetration_mm: f64,
}

impl Channels {
    /// Adds the channels to `r`.
    pub(super) fn add(r: &mut Recorder) -> Result<Self, RecordingError> {
        Ok(Channels {
            force: r.add_channel_for::<ForceMsg>("/slave/force", "h4.SlaveForce")?,
            pose: r.add_channel_for::<PoseMsg>("/slave/pose", "h4.SlavePose")?,
            contact: r.add_channel_for::<ContactMsg>("/slave/contact", "h4.SlaveContact")?,
        })
    }

    /// Writes one cycle at `t_ns`: the controller's output, the simulation's truth and the
    /// commanded set-point.
    pub(super) fn write(
        &self,
        r: &mut Recorder,
        t_ns: u64,
        out: &ControllerOutput,
        truth: &Truth,
        setpoint_n: f64,
    ) -> Result<(), RecordingError> {
        let pose = truth.pose;
        let n_true = truth.normal;
        r.write(
            self.force,
            t_ns,
            &ForceMsg {
                fn_measured_n: out.normal_force_n,
                fn_true_n: truth.fn_true_n,
                fn_desired_n: out.setpoint_n,
                setpoint_n,
                wrench_measured: out.wrench_measured,
                wrench_desired: out.wrench_desired,
                env_stiffness_n_per_mm: out.env_stiffness_n_per_mm,
                compliance_mm_per_n: out.compliance_mm_per_n,
                status: out.status.code(),
            },
        )?;
        r.write(
            self.pose,
            t_ns,
            &PoseMsg {
                measured: out.measured_pose,
                commanded: out.commanded_pose,
                true_pose: [pose[0], pose[1], pose[2], pose[3]],
                actuators_cmd_mm: out.actuators_cmd_mm,
            },
        )?;
        r.write(
            self.contact,
            t_ns,
            &ContactMsg {
                normal: out.contact_normal,
                tracking_direction: out.tracking_direction,
                true_normal: [n_true[0], n_true[1], n_true[2]],
                penetration_mm: truth.penetration_mm,
            },
        )
    }
}
