//! The session's recording: one channel per side (every cycle) and one for the link's
//! events. Topic, schema and field names are a public interface (`docs/sessions.md`).

use h4_shared::passivity::PortEnergy;
use h4_slave::teleop::{SlaveTeleop, TeleopCycle};
use h4_slave_sim::cut::CutTeleop;
use h4_slave_sim::plant::SimArm;
use h4_telemetry::recording::{ChannelId, Recorder, RecordingError};
use h4_transport::impair::LinkEvent;
use serde::Serialize;

use super::SimMasterCycle;

/// One master cycle of the simulation (topic `/master/cycle`, schema `h4.MasterCycle`).
#[derive(Serialize, schemars::JsonSchema)]
struct MasterMsg {
    /// Handle pose [x, y, z, theta], mm, rad, master frame.
    pose: [f64; 4],
    /// Handle velocity [mm/s, mm/s, mm/s, rad/s].
    velocity: [f64; 4],
    /// The operator's grip force on the handle [Fx, Fy, Fz, My], N, N·mm.
    hand_wrench: [f64; 4],
    /// Where the scripted operator wants the handle, mm.
    intent_target_mm: [f64; 3],
    /// The operator holds the clutch.
    clutch: bool,
    /// scale.force × the slave's force (or the contact model's), before the passivity
    /// controller, N.
    link_force_n: [f64; 3],
    /// Wrench applied by the device [Fx, Fy, Fz, My], N, N·mm.
    rendered_wrench: [f64; 4],
    /// The master port's passivity damping, N·s/mm.
    damping_n_s_per_mm: f64,
    /// The master port's passivity observer, J.
    observed_j: f64,
    /// Feedback-loss fade of the rendered force (1 full, 0 faded out).
    fade: f64,
    /// The slave target sent this cycle [x, y, z, theta], mm, rad, slave frame.
    slave_target: [f64; 4],
    /// Force set-point sent (force-guided mode), N.
    setpoint_n: f64,
    /// Energy that entered the link at the master port so far, J.
    energy_in_j: f64,
    /// Energy the link delivered at the master port so far, J.
    energy_out_j: f64,
    /// Energy the master's passivity controller dissipated so far, J.
    dissipated_j: f64,
    /// The newest round trip the master measured (`teleop::RoundTrip`, the same figure as the
    /// process's `h4.MasterProcessCycle`): now − the send time of the command the newest
    /// echoing feedback echoed, µs; null (so not a required field) until a feedback message
    /// has echoed a command.
    round_trip_us: Option<f64>,
}

/// One slave cycle of the simulation (topic `/slave/cycle`, schema `h4.SlaveCycle`; the slave
/// process's own shape is `h4.SlaveProcessCycle`).
#[derive(Serialize, schemars::JsonSchema)]
struct SlaveMsg {
    /// Position the link asks for, mm, slave frame.
    desired_mm: [f64; 3],
    /// Pose commanded to the arm after the passivity controller, mm, rad.
    commanded_pose: [f64; 4],
    /// Measured pose (forward kinematics of the measured actuators), mm, rad.
    measured_pose: [f64; 4],
    /// The simulated arm's true pose, mm, rad (simulation truth).
    true_pose: [f64; 4],
    /// Measured contact wrench [Fx, Fy, Fz, My], N, N·mm (filtered sensor).
    wrench_measured: [f64; 4],
    /// True contact force, N (simulation truth).
    true_force_n: [f64; 3],
    /// The controller's status code.
    status: u8,
    /// The slave port's passivity admittance, mm/(N·s).
    admittance_mm_per_n_s: f64,
    /// The slave port's passivity observer, J.
    observed_j: f64,
    /// Commanded minus desired position (the passivity controller's drift), mm.
    drift_mm: [f64; 3],
    /// Energy that entered the link at the slave port so far, J.
    energy_in_j: f64,
    /// Energy the link delivered at the slave port so far, J.
    energy_out_j: f64,
    /// Energy the slave's passivity controller dissipated so far, J.
    dissipated_j: f64,
}

/// One impairment event (topic `/link/events`, schema `h4.LinkEvent`).
#[derive(Serialize, schemars::JsonSchema)]
struct LinkMsg {
    /// `command` (master → slave) or `feedback` (slave → master).
    direction: &'static str,
    /// What happened to which message when.
    event: LinkEvent,
}

/// The session's channels in a recording.
pub(super) struct Channels {
    master: ChannelId,
    slave: ChannelId,
    link: ChannelId,
    cut: Option<ChannelId>,
}

impl Channels {
    /// Adds the channels to `r` (`/slave/cut` when the slave `cutting`).
    pub(super) fn add(r: &mut Recorder, cutting: bool) -> Result<Self, RecordingError> {
        Ok(Channels {
            master: r.add_channel_for::<MasterMsg>("/master/cycle", "h4.MasterCycle")?,
            slave: r.add_channel_for::<SlaveMsg>("/slave/cycle", "h4.SlaveCycle")?,
            link: r.add_channel_for::<LinkMsg>("/link/events", "h4.LinkEvent")?,
            cut: if cutting {
                Some(r.add_channel_for::<h4_slave_sim::cut::CutCycle>("/slave/cut", "h4.CutCycle")?)
            } else {
                None
            },
        })
    }

    /// Writes one cycle of the cut at `t_ns`, if the slave cuts.
    pub(super) fn write_cut(
        &self,
        r: &mut Recorder,
        t_ns: u64,
        slave: &SlaveTeleop<SimArm>,
    ) -> Result<(), RecordingError> {
        let (Some(ch), Some(cut)) = (self.cut, slave.cut_cycle()) else {
            return Ok(());
        };
        r.write(ch, t_ns, &cut)
    }

    /// Writes one cycle of both sides at `t_ns`: the master's cycle `m` with its port's
    /// energies, the slave's cycle `s` with its endpoint, and the true contact force at the
    /// slave, N.
    pub(super) fn write_cycle(
        &self,
        r: &mut Recorder,
        t_ns: u64,
        (m, master_energy): (&SimMasterCycle, PortEnergy),
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
                round_trip_us: Some(m.round_trip_us).filter(|r| r.is_finite()),
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
