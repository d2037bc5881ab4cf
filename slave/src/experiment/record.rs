//! The experiment's recording: every cycle on `/slave/force`, `/slave/pose` and
//! `/slave/contact`, stamped with the simulated time.

use h4_shared::recording::{ChannelId, Recorder, RecordingError};
use serde::Serialize;

use super::run::Truth;
use crate::controller::ControllerOutput;

/// The three channels.
pub(super) struct Channels {
    force: ChannelId,
    pose: ChannelId,
    contact: ChannelId,
}

const FORCE_SCHEMA: &str = r#"{"type":"object","title":"h4.SlaveForce","properties":{
"fn_measured_n":{"type":"number","description":"measured force along the estimated normal, N"},
"fn_true_n":{"type":"number","description":"true contact force along the true normal, N"},
"fn_desired_n":{"type":"number","description":"prefiltered set-point, N"},
"setpoint_n":{"type":"number","description":"commanded set-point, N"},
"wrench_measured":{"type":"array","items":{"type":"number"},"description":"[Fx,Fy,Fz,My] bias-corrected, N, N·mm"},
"wrench_desired":{"type":"array","items":{"type":"number"},"description":"[Fx,Fy,Fz,My] desired, N, N·mm"},
"env_stiffness_n_per_mm":{"type":"number"},
"compliance_mm_per_n":{"type":"number"},
"status":{"type":"integer"}}}"#;

const POSE_SCHEMA: &str = r#"{"type":"object","title":"h4.SlavePose","properties":{
"measured":{"type":"array","items":{"type":"number"},"description":"[x,y,z,theta] mm, rad"},
"commanded":{"type":"array","items":{"type":"number"},"description":"[x,y,z,theta] mm, rad"},
"true_pose":{"type":"array","items":{"type":"number"},"description":"[x,y,z,theta] mm, rad (simulation truth)"},
"actuators_cmd_mm":{"type":"array","items":{"type":"number"}}}}"#;

const CONTACT_SCHEMA: &str = r#"{"type":"object","title":"h4.SlaveContact","properties":{
"normal":{"type":"array","items":{"type":"number"},"description":"estimated outward contact normal"},
"tracking_direction":{"type":"array","items":{"type":"number"}},
"true_normal":{"type":"array","items":{"type":"number"}},
"penetration_mm":{"type":"number"}}}"#;

#[derive(Serialize)]
struct ForceMsg {
    fn_measured_n: f64,
    fn_true_n: f64,
    fn_desired_n: f64,
    setpoint_n: f64,
    wrench_measured: [f64; 4],
    wrench_desired: [f64; 4],
    env_stiffness_n_per_mm: f64,
    compliance_mm_per_n: f64,
    status: u8,
}

#[derive(Serialize)]
struct PoseMsg {
    measured: [f64; 4],
    commanded: [f64; 4],
    true_pose: [f64; 4],
    actuators_cmd_mm: [f64; 4],
}

#[derive(Serialize)]
struct ContactMsg {
    normal: [f64; 3],
    tracking_direction: [f64; 3],
    true_normal: [f64; 3],
    penetration_mm: f64,
}

impl Channels {
    /// Adds the channels to `r`.
    pub(super) fn add(r: &mut Recorder) -> Result<Self, RecordingError> {
        Ok(Channels {
            force: r.add_channel("/slave/force", "h4.SlaveForce", FORCE_SCHEMA)?,
            pose: r.add_channel("/slave/pose", "h4.SlavePose", POSE_SCHEMA)?,
            contact: r.add_channel("/slave/contact", "h4.SlaveContact", CONTACT_SCHEMA)?,
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
