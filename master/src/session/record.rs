//! The session's recording: one channel per side (every cycle) and one for the link's
//! events. Topic, schema and field names are a public interface (`docs/sessions.md`).

use h4_shared::passivity::PortEnergy;
use h4_shared::recording::{ChannelId, Recorder, RecordingError};
use h4_slave::plant::SimArm;
use h4_slave::teleop::{SlaveTeleop, TeleopCycle};
use h4_transport::impair::LinkEvent;
use serde::Serialize;

use crate::teleop::MasterCycle;

#[derive(Serialize)]
struct MasterMsg {
    pose: [f64; 4],
    velocity: [f64; 4],
    hand_wrench: [f64; 4],
    intent_target_mm: [f64; 3],
    clutch: bool,
    link_force_n: [f64; 3],
    rendered_wrench: [f64; 4],
    damping_n_s_per_mm: f64,
    observed_j: f64,
    fade: f64,
    slave_target: [f64; 4],
    setpoint_n: f64,
    energy_in_j: f64,
    energy_out_j: f64,
    dissipated_j: f64,
}

#[derive(Serialize)]
struct SlaveMsg {
    desired_mm: [f64; 3],
    commanded_pose: [f64; 4],
    measured_pose: [f64; 4],
    true_pose: [f64; 4],
    wrench_measured: [f64; 4],
    true_force_n: [f64; 3],
    status: u8,
    admittance_mm_per_n_s: f64,
    observed_j: f64,
    drift_mm: [f64; 3],
    energy_in_j: f64,
    energy_out_j: f64,
    dissipated_j: f64,
}

#[derive(Serialize)]
struct LinkMsg {
    direction: &'static str,
    event: LinkEvent,
}

const MASTER_SCHEMA: &str = r#"{"type":"object","title":"h4.MasterCycle","properties":{
"pose":{"type":"array","items":{"type":"number"},"description":"handle [x,y,z,theta] mm, rad"},
"velocity":{"type":"array","items":{"type":"number"}},
"hand_wrench":{"type":"array","items":{"type":"number"},"description":"grip force on the handle, N, N·mm"},
"intent_target_mm":{"type":"array","items":{"type":"number"}},
"clutch":{"type":"boolean"},
"link_force_n":{"type":"array","items":{"type":"number"},"description":"scale.force × slave force, before the passivity controller"},
"rendered_wrench":{"type":"array","items":{"type":"number"},"description":"applied by the device, N, N·mm"},
"damping_n_s_per_mm":{"type":"number"},
"observed_j":{"type":"number"},
"fade":{"type":"number"},
"slave_target":{"type":"array","items":{"type":"number"}},
"setpoint_n":{"type":"number"},
"energy_in_j":{"type":"number"},"energy_out_j":{"type":"number"},"dissipated_j":{"type":"number"}}}"#;

const SLAVE_SCHEMA: &str = r#"{"type":"object","title":"h4.SlaveCycle","properties":{
"desired_mm":{"type":"array","items":{"type":"number"},"description":"position the link asks for"},
"commanded_pose":{"type":"array","items":{"type":"number"},"description":"after the passivity controller"},
"measured_pose":{"type":"array","items":{"type":"number"}},
"true_pose":{"type":"array","items":{"type":"number"}},
"wrench_measured":{"type":"array","items":{"type":"number"}},
"true_force_n":{"type":"array","items":{"type":"number"}},
"status":{"type":"integer"},
"admittance_mm_per_n_s":{"type":"number"},
"observed_j":{"type":"number"},
"drift_mm":{"type":"array","items":{"type":"number"}},
"energy_in_j":{"type":"number"},"energy_out_j":{"type":"number"},"dissipated_j":{"type":"number"}}}"#;

const LINK_SCHEMA: &str = r#"{"type":"object","title":"h4.LinkEvent","properties":{
"direction":{"type":"string"},
"event":{"type":"object","properties":{"time_ns":{"type":"integer"},"seq":{"type":"integer"},"kind":{"type":"string"}}}}}"#;

/// The session's channels in a recording.
pub(super) struct Channels {
    master: ChannelId,
    slave: ChannelId,
    link: ChannelId,
}

impl Channels {
    /// Adds the channels to `r`.
    pub(super) fn add(r: &mut Recorder) -> Result<Self, RecordingError> {
        Ok(Channels {
            master: r.add_channel("/master/cycle", "h4.MasterCycle", MASTER_SCHEMA)?,
            slave: r.add_channel("/slave/cycle", "h4.SlaveCycle", SLAVE_SCHEMA)?,
            link: r.add_channel("/link/events", "h4.LinkEvent", LINK_SCHEMA)?,
        })
    }

    /// Writes one cycle of both sides at `t_ns`: the master's cycle `m` with its port's
    /// energies, the slave's cycle `s` with its endpoint, and the true contact force at the
    /// slave, N.
    pub(super) fn write_cycle(
        &self,
        r: &mut Recorder,
        t_ns: u64,
        (m, master_energy): (&MasterCycle, PortEnergy),
        (s, slave): (&TeleopCycle, &SlaveTeleop<SimArm>),
        true_force_n: [f64; 3],
    ) -> Result<(), RecordingError> {
        let me = master_energy;
        r.write(
            self.master,
            t_ns,
            &MasterMsg {
                pose: m.handle.pose,
                velocity: m.handle.velocity,
                hand_wrench: m.hand.wrench,
                intent_target_mm: m.hand.intent.target_mm,
                clutch: m.handle.clutch,
                link_force_n: m.step.link_force_n,
                rendered_wrench: m.rendered_wrench,
                damping_n_s_per_mm: m.step.damping_n_s_per_mm,
                observed_j: m.step.observed_j,
                fade: m.step.fade,
                slave_target: m.step.slave_target,
                setpoint_n: m.step.setpoint_n,
                energy_in_j: me.in_j,
                energy_out_j: me.out_j,
                dissipated_j: me.dissipated_j,
            },
        )?;
        let se = slave.port().energy;
        let tp = slave.arm().true_pose();
        r.write(
            self.slave,
            t_ns,
            &SlaveMsg {
                desired_mm: s.desired_mm,
                commanded_pose: s.out.commanded_pose,
                measured_pose: s.out.measured_pose,
                true_pose: [tp[0], tp[1], tp[2], tp[3]],
                wrench_measured: s.out.wrench_measured,
                true_force_n,
                status: s.out.status.code(),
                admittance_mm_per_n_s: s.port.admittance_mm_per_n_s,
                observed_j: s.port.observed_j,
                drift_mm: s.drift_mm,
                energy_in_j: se.in_j,
                energy_out_j: se.out_j,
                dissipated_j: se.dissipated_j,
            },
        )
    }

    /// Writes the link events of one `direction` that `drain` hands over.
    pub(super) fn write_link_events(
        &self,
        r: &mut Recorder,
        direction: &'static str,
        drain: impl FnOnce(&mut dyn FnMut(&LinkEvent)),
    ) -> Result<(), RecordingError> {
        let mut result = Ok(());
        let link = self.link;
        drain(&mut |e| {
            if result.is_ok() {
                result = r.write(
                    link,
                    e.time_ns.max(1),
                    &LinkMsg {
                        direction,
                        event: *e,
                    },
                );
            }
        });
        result
    }
}
