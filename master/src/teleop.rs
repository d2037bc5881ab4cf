//! The master's teleoperation endpoint: everything the master does in one cycle of a
//! teleoperation session, on any [`Link`]. The lockstep session simulation (`h4-master sim`)
//! and the real process (`h4-master run`, and so `h4-master loopback`) both step this, so
//! there is one piece of code for the master's per-cycle logic. It mirrors the slave's
//! endpoint, `h4_slave::teleop::SlaveTeleop`.
//!
//! One [`MasterTeleop::step`]:
//! 1. the cycle begins at the device ([`HapticDevice::begin_cycle`]: on the simulated
//!    device the operator's hand acts on the handle), and the handle is read;
//! 2. drains the link through the receive gate, the only check of incoming feedback (wrong
//!    version, wrong arm, undecodable, reserved bits, length, session, sequence number or
//!    energy is counted by reason and dropped); each accepted message goes to the coupling and to the round-trip
//!    figure ([`RoundTrip`]);
//! 3. the coupling step ([`MasterCoupling`]: mapping of the handle into the slave's
//!    workspace, the rendered force with its passivity port, clutch, fade);
//! 4. writes the wrench to the device and publishes the command.
//!
//! It allocates nothing, blocks on nothing, logs nothing and never panics; link errors are
//! counted, not returned.

use h4_shared::config::ArmConfig;
use h4_shared::kinematics::{KinError, Workspace};
use h4_shared::passivity::PassivityParams;
use h4_shared::wire::{Command, Feedback, SlaveState};
use h4_telemetry::rt::Histogram;
use h4_transport::Link;
use h4_transport::gate::{EnergyBound, Gate, GateCounters};
use serde::Serialize;

use crate::coupling::{CouplingConfig, CouplingParams, MasterCoupling, MasterStep, ScaleConfig};
use crate::device::{DeviceState, HapticDevice};

/// After this much feedback silence a message whose sequence number went backwards is taken
/// as a restarted slave, ms.
const RESTART_SILENCE_MS: f64 = 1000.0;

/// Share of the slave controller's speed limit the master commands at most.
const SLAVE_SPEED_MARGIN: f64 = 0.9;

/// The largest force limit a slave accepts, N (the bound of the feedback's energy check).
const SLAVE_FORCE_LIMIT_BOUND_N: f64 = 1000.0;

/// What the master's endpoint is built from: the master's sections of a session file
/// (coupling, scale, passivity) and the slave it maps into. The device is built apart
/// (the simulated one from `master.*` and `operator.*`, `h4_master_sim::hand`).
#[derive(Clone, Debug, PartialEq)]
pub struct MasterTeleopConfig {
    /// Arm id: commands carry it, feedback for another arm is rejected.
    pub arm_id: u16,
    /// The coupling (`coupling.*`).
    pub coupling: CouplingConfig,
    /// Motion and force scaling (`scale.*`).
    pub scale: ScaleConfig,
    /// Passivity control (`passivity.*`).
    pub passivity: PassivityParams,
    /// The slave arm (`slave.arm.*`): targets are mapped into its workspace.
    pub slave_arm: ArmConfig,
    /// The slave pose the master's home pose maps to (the anchor of the master→slave
    /// mapping), slave frame, `[x_mm, y_mm, z_mm, theta_rad]`.
    pub slave_anchor_pose: [f64; 4],
    /// The slave controller's speed limit (`slave.controller.max_speed_mm_per_s`), mm/s:
    /// the master commands at most 90 % of it.
    pub slave_max_speed_mm_per_s: f64,
}

impl MasterTeleopConfig {
    /// The slave's workspace.
    pub fn slave_workspace(&self) -> Workspace {
        self.slave_arm.workspace()
    }

    /// The coupling's parameters.
    pub fn coupling_params(&self) -> CouplingParams {
        CouplingParams::from_config(
            &self.coupling,
            &self.scale,
            &self.passivity,
            self.slave_workspace(),
            self.slave_anchor_pose,
            self.slave_max_speed_mm_per_s * SLAVE_SPEED_MARGIN,
            self.arm_id,
        )
    }
}

/// Why the endpoint could not be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum MasterTeleopError {
    /// The master arm's geometry or home pose is not usable.
    #[error("master arm: {0}")]
    Device(KinError),
}

/// The round trip the master measures, one definition for the simulation's summary and the
/// process's: for every feedback message the gate accepts that echoes a command
/// (`echo_send_time_ns > 0`), the age of the echoed command at reception, `now −
/// echo_send_time_ns` on the master's clock. It includes the link's delay both ways and the
/// phase of both loops; a command echoed by several feedback messages (the slave repeats its
/// newest command while no newer one arrives) is counted at every one of them. Feedback
/// from a slave in its safe stop is not counted: it echoes the last command it followed,
/// and it follows none until the master acknowledges (after a stall, until the spindle
/// turns again), so that age is the safe stop's, not the link's (a stall's safe stop put
/// 650 ms into the p99 of a loopback on shared memory).
#[derive(Clone, Debug)]
pub struct RoundTrip {
    samples: u64,
    sum_ms: f64,
    last_ns: u64,
    histogram: Histogram,
}

impl RoundTrip {
    fn new() -> Self {
        RoundTrip {
            samples: 0,
            sum_ms: 0.0,
            last_ns: 0,
            histogram: Histogram::new(),
        }
    }

    fn record(&mut self, fb: &Feedback, now_ns: u64) {
        if fb.echo_send_time_ns > 0 && fb.state != SlaveState::SafeStop as u8 {
            let ns = now_ns.saturating_sub(fb.echo_send_time_ns);
            self.sum_ms += ns as f64 * 1e-6;
            self.samples += 1;
            self.last_ns = ns;
            self.histogram.record(ns);
        }
    }

    /// Round trips measured.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Mean round trip, ms (NaN before the first).
    pub fn mean_ms(&self) -> f64 {
        if self.samples > 0 {
            self.sum_ms / self.samples as f64
        } else {
            f64::NAN
        }
    }

    /// The newest round trip, ns (0 before the first).
    pub fn last_ns(&self) -> u64 {
        self.last_ns
    }

    /// The newest round trip, µs (NaN before the first): the per-cycle figure both the
    /// simulation's and the process's `/master/cycle` record as `round_trip_us`.
    pub fn last_us(&self) -> f64 {
        if self.samples > 0 {
            self.last_ns as f64 * 1e-3
        } else {
            f64::NAN
        }
    }

    /// All round trips, ns.
    pub fn histogram(&self) -> &Histogram {
        &self.histogram
    }
}

/// Counters over the endpoint's life.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MasterTeleopCounters {
    /// Cycles stepped.
    pub cycles: u64,
    /// Feedback messages the link delivered, before the gate (payloads the link dropped
    /// undecoded are in the gate's `undecodable`).
    pub feedback_received: u64,
    /// Link errors while receiving or publishing.
    pub link_errors: u64,
    /// Commands published.
    pub commands_published: u64,
    /// Cycles the device had not answered for [`DEVICE_STALE_CYCLES`] cycles or more (its
    /// reading's time did not move on): the rendered force fades out through them.
    pub device_stale_cycles: u64,
    /// Cycles whose command the slave's feedback echoed before the master's next cycle
    /// ([`MasterTeleop::await_feedback`]): the slave answered within the master's period.
    pub feedback_in_period_cycles: u64,
}

/// What one master cycle did (plain data, no allocation).
#[derive(Clone, Copy, Debug)]
pub struct MasterCycle {
    /// The coupling's step.
    pub step: MasterStep,
    /// The wrench the device applied to the handle, master frame, `[Fx_n, Fy_n, Fz_n,
    /// My_n_mm]` (after the device's own limits).
    pub rendered_wrench: [f64; 4],
    /// The handle: pose, velocity and clutch as read this cycle, master frame.
    pub handle: DeviceState,
    /// A feedback message was accepted this cycle.
    pub fresh: bool,
    /// The newest round trip after this cycle's reception ([`RoundTrip::last_us`]), µs;
    /// NaN until a feedback message has echoed a command.
    pub round_trip_us: f64,
}

/// The master's teleoperation endpoint over the haptic device `D`: the device, the receive
/// gate, the coupling.
pub struct MasterTeleop<D: HapticDevice> {
    session_id: u64,
    device: D,
    gate: Gate<Feedback>,
    coupling: MasterCoupling,
    round_trip: RoundTrip,
    counters: MasterTeleopCounters,
    /// The time of the device's last reading, and the cycles in a row it has not moved on.
    last_reading_ns: Option<u64>,
    stale_cycles: u32,
    /// The sequence number of the last command published (0: none yet).
    last_command_seq: u64,
}

impl<D: HapticDevice> MasterTeleop<D> {
    /// An endpoint from its configuration, over `device`.
    pub fn new(cfg: &MasterTeleopConfig, device: D) -> Self {
        // The slave's energy fields are bounded by the largest force limit a slave accepts
        // (1000 N) at its speed limit, four times over (docs/wire.md).
        let energy =
            EnergyBound::from_limits(SLAVE_FORCE_LIMIT_BOUND_N, cfg.slave_max_speed_mm_per_s, 4.0);
        MasterTeleop {
            session_id: h4_shared::wire::new_session_id(),
            device,
            gate: Gate::new(cfg.arm_id, (RESTART_SILENCE_MS * 1e6) as u64)
                .with_energy_bound(energy),
            coupling: MasterCoupling::new(cfg.coupling_params()),
            round_trip: RoundTrip::new(),
            counters: MasterTeleopCounters::default(),
            last_reading_ns: None,
            stale_cycles: 0,
            last_command_seq: 0,
        }
    }

    /// The device.
    pub fn device(&self) -> &D {
        &self.device
    }

    /// The device, mutable (a simulated one is advanced by its owner).
    pub fn device_mut(&mut self) -> &mut D {
        &mut self.device
    }

    /// The coupling.
    pub fn coupling(&self) -> &MasterCoupling {
        &self.coupling
    }

    /// What the receive gate accepted and rejected.
    pub fn gate_counters(&self) -> &GateCounters {
        &self.gate.counters
    }

    /// The newest feedback the gate accepted.
    pub fn latest_feedback(&self) -> Option<&Feedback> {
        self.gate.latest()
    }

    /// The round trip.
    pub fn round_trip(&self) -> &RoundTrip {
        &self.round_trip
    }

    /// Counters.
    pub fn counters(&self) -> &MasterTeleopCounters {
        &self.counters
    }

    /// Receives one feedback message through the gate only (nothing reaches the coupling):
    /// true once one was accepted. For waiting until a slave answers, before the first
    /// [`MasterTeleop::step`].
    pub fn poll_peer<L: Link<Command, Feedback>>(&mut self, link: &mut L, now_ns: u64) -> bool {
        let d = self.gate.drain(link, now_ns, 1, |_| {});
        self.counters.feedback_received += d.received;
        if d.link_error {
            self.counters.link_errors += 1;
        }
        d.accepted > 0
    }

    /// The receive gate (its paired session, last rejection).
    pub fn gate(&self) -> &Gate<Feedback> {
        &self.gate
    }

    /// This master's session id (sent in every command).
    pub fn session_id(&self) -> u64 {
        self.session_id
    }

    /// Drains the link through the gate; true if a message was accepted.
    fn receive<L: Link<Command, Feedback>>(&mut self, link: &mut L, now_ns: u64) -> bool {
        // Acknowledging the slave's safe stop: its feedback may start a new ledger.
        self.gate
            .set_peer_ledger_may_restart(self.coupling.acking());
        let coupling = &mut self.coupling;
        let round_trip = &mut self.round_trip;
        let restarts = self.gate.counters.repaired;
        let d = self
            .gate
            .drain(link, now_ns, MAX_RECEIVED_PER_CYCLE, |f: &Feedback| {
                coupling.receive(f, now_ns);
                round_trip.record(f, now_ns);
            });
        self.counters.feedback_received += d.received;
        if self.gate.counters.repaired > restarts {
            // The slave restarted: a new ledger on this side (it starts its own).
            self.coupling.new_pairing();
        }
        if d.link_error {
            self.counters.link_errors += 1;
        }
        d.accepted > 0
    }

    /// After a cycle's [`MasterTeleop::step`]: waits for the feedback that echoes the command
    /// it published, blocking on the link ([`Link::wait_message`]) at most until `until` (the
    /// loop's next deadline less its spin margin), and takes what arrives through the gate at
    /// the time it arrives (`now_ns()`, the loop's clock): the round trip is then the reply's
    /// true age, not rounded up to the next cycle, and the next step's coupling has the reply.
    /// True if the echo arrived in time ([`MasterTeleopCounters::feedback_in_period_cycles`]).
    /// Allocates nothing; on a link that cannot wake it returns false at once.
    pub fn await_feedback<L: Link<Command, Feedback>>(
        &mut self,
        link: &mut L,
        until: std::time::Instant,
        now_ns: impl Fn() -> u64,
    ) -> bool {
        let want = self.last_command_seq;
        if want == 0 || !link.can_wake() {
            return false;
        }
        loop {
            if self.gate.latest().is_some_and(|f| f.echo_seq >= want) {
                self.counters.feedback_in_period_cycles += 1;
                return true;
            }
            // Never past the deadline: a link that keeps saying a message waits while none
            // can be taken (a receive error, a dead peer's last samples) must not hold the
            // loop (it held `h4-master run` at its last cycle against a replayed slave).
            if std::time::Instant::now() >= until {
                return false;
            }
            match link.wait_message(until) {
                Ok(true) => {
                    let errors = self.counters.link_errors;
                    let received = self.counters.feedback_received;
                    self.receive(link, now_ns());
                    if self.counters.link_errors > errors
                        || self.counters.feedback_received == received
                    {
                        return false;
                    }
                }
                Ok(false) => return false,
                Err(_) => {
                    self.counters.link_errors += 1;
                    return false;
                }
            }
        }
    }

    /// The `missed` periods of `period_ns` before the cycle at `now_ns` that a stalled host
    /// did not run ([`HapticDevice::stalled`]: the simulated device's hand goes on).
    pub fn stalled(&mut self, now_ns: u64, period_ns: u64, missed: u64) {
        if missed > 0 {
            self.device.stalled(now_ns, period_ns, missed);
        }
    }

    /// One cycle at `now_ns` of `dt_s` seconds on `link`.
    pub fn step<L: Link<Command, Feedback>>(
        &mut self,
        link: &mut L,
        now_ns: u64,
        dt_s: f64,
    ) -> MasterCycle {
        self.device.begin_cycle(now_ns, dt_s);
        let dev = self.device.read();
        if self.last_reading_ns == Some(dev.time_ns) {
            self.stale_cycles = self.stale_cycles.saturating_add(1);
        } else {
            self.stale_cycles = 0;
        }
        self.last_reading_ns = Some(dev.time_ns);
        let stale = self.stale_cycles >= DEVICE_STALE_CYCLES;
        if stale {
            self.counters.device_stale_cycles += 1;
        }
        self.coupling.set_device_stale(stale);
        let fresh = self.receive(link, now_ns);
        let step = self.coupling.step(&dev, now_ns, dt_s);
        let rendered_wrench = self.device.write_wrench(&step.wrench);
        let mut cmd = self.coupling.finish(&rendered_wrench, &dev, now_ns);
        cmd.session_id = self.session_id;
        // Protocol 3: echo the newest feedback accepted, so the slave measures its round trip.
        if let Some(f) = self.gate.latest() {
            cmd.echo_seq = f.seq;
            cmd.echo_send_time_ns = f.send_time_ns;
        }
        self.last_command_seq = cmd.seq;
        match link.publish(&cmd) {
            Ok(()) => self.counters.commands_published += 1,
            Err(_) => self.counters.link_errors += 1,
        }
        self.counters.cycles += 1;
        MasterCycle {
            step,
            rendered_wrench,
            handle: dev,
            fresh,
            round_trip_us: self.round_trip.last_us(),
        }
    }
}

/// Most feedback messages taken from the link in one cycle.
const MAX_RECEIVED_PER_CYCLE: usize = 4096;

/// Cycles in a row without a fresh device reading (its time not moving on) after which the
/// device counts as silent and the rendered force fades out.
pub const DEVICE_STALE_CYCLES: u32 = 2;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::PrincipalMasses;
    use h4_transport::inproc;

    /// A handle held still (the test needs no physics); its readings' time moves on by
    /// 1 ms a read unless `frozen`.
    #[derive(Default)]
    struct StillHandle {
        time_ns: u64,
        frozen: bool,
    }

    impl HapticDevice for StillHandle {
        fn read(&mut self) -> DeviceState {
            if !self.frozen {
                self.time_ns += 1_000_000;
            }
            DeviceState {
                time_ns: self.time_ns,
                effective_mass_kg: 0.5,
                principal_masses: PrincipalMasses::isotropic(0.5),
                ..DeviceState::default()
            }
        }
        fn write_wrench(&mut self, wrench: &[f64; 4]) -> [f64; 4] {
            *wrench
        }
    }

    /// A device whose readings stop moving on fades the rendering out, counted from its
    /// second stale cycle; fresh again, it fades back in. Control: a fresh device keeps
    /// the fade at 1 with the same feedback.
    #[test]
    fn a_silent_device_fades_the_rendering_out() {
        let run = |freeze_at: Option<u64>| {
            let mut ep = MasterTeleop::new(&config(0), StillHandle::default());
            let (mut master_end, mut slave_end) = inproc::pair(1024);
            let mut fades = Vec::new();
            for k in 1..=450u64 {
                let t_ns = k * 1_000_000;
                ep.device_mut().frozen = freeze_at.is_some_and(|f| (f..f + 200).contains(&k));
                slave_end
                    .publish(&Feedback {
                        seq: k,
                        send_time_ns: t_ns,
                        state: SlaveState::Active as u8,
                        ..Feedback::default()
                    })
                    .unwrap();
                fades.push(ep.step(&mut master_end, t_ns, 1e-3).step.fade);
                while slave_end.try_recv().unwrap().is_some() {}
            }
            (fades, ep.counters().device_stale_cycles)
        };
        let (fresh, fresh_stale) = run(None);
        assert_eq!(fresh_stale, 0);
        assert!(
            fresh[100..].iter().all(|&f| f == 1.0),
            "{:?}",
            &fresh[100..110]
        );
        let (frozen, stale) = run(Some(150));
        // Frozen from cycle 150: its first read is still new (cycle 149's time + 0), then
        // stale from the second; 200 frozen cycles, the first one not stale.
        assert_eq!(stale, 199);
        assert!(
            frozen[148] == 1.0 && frozen[170] < 1.0,
            "fading from the second stale cycle"
        );
        assert_eq!(frozen[240], 0.0, "faded out while the device is silent");
        assert_eq!(frozen[449], 1.0, "faded back in once it answers again");
    }

    fn config(arm_id: u16) -> MasterTeleopConfig {
        MasterTeleopConfig {
            arm_id,
            coupling: CouplingConfig::default(),
            scale: ScaleConfig::default(),
            passivity: PassivityParams::default(),
            slave_arm: ArmConfig::default(),
            slave_anchor_pose: [0.0, 0.0, -245.0, 0.0],
            slave_max_speed_mm_per_s: 100.0,
        }
    }

    /// A master for arm 3 commands arm 3 and takes only arm 3's feedback; each accepted
    /// feedback that echoes a command is one round trip.
    #[test]
    fn speaks_for_its_arm_and_measures_round_trips() {
        let mut ep = MasterTeleop::new(&config(3), StillHandle::default());
        let (mut master_end, mut slave_end) = inproc::pair(16);
        let mut t_ns = 0;
        for _ in 0..5 {
            t_ns += 1_000_000;
            ep.step(&mut master_end, t_ns, 1e-3);
        }
        let cmd = slave_end.recv_latest().unwrap().unwrap();
        assert_eq!(cmd.arm_id, 3);
        // Feedback of another arm is rejected, of this arm accepted.
        for (seq, arm_id) in [(1, 0), (2, 3)] {
            let fb = Feedback {
                seq,
                send_time_ns: t_ns,
                echo_seq: cmd.seq,
                echo_send_time_ns: cmd.send_time_ns,
                arm_id,
                ..Feedback::default()
            };
            slave_end.publish(&fb).unwrap();
            t_ns += 1_000_000;
            let c = ep.step(&mut master_end, t_ns, 1e-3);
            assert_eq!(c.fresh, arm_id == 3);
            // The cycle carries the newest round trip: none before the first echo.
            if arm_id == 3 {
                assert_eq!(c.round_trip_us, (t_ns - cmd.send_time_ns) as f64 * 1e-3);
            } else {
                assert!(c.round_trip_us.is_nan(), "{}", c.round_trip_us);
            }
        }
        let counters = ep.gate_counters();
        assert_eq!(counters.wrong_arm, 1, "{counters:?}");
        assert_eq!(counters.accepted, 1, "{counters:?}");
        assert_eq!(ep.counters().feedback_received, 2);
        assert_eq!(ep.counters().commands_published, 7);
        assert_eq!(ep.round_trip().samples(), 1);
        assert_eq!(ep.round_trip().last_ns(), t_ns - cmd.send_time_ns);
        assert!((ep.round_trip().mean_ms() - 2.0).abs() < 1e-9);
        // A safe-stopped slave's feedback echoes the last command it followed, however old:
        // not a round trip. Once active again its echo is one.
        for (seq, state) in [(3, SlaveState::SafeStop), (4, SlaveState::Active)] {
            t_ns += 500_000_000;
            slave_end
                .publish(&Feedback {
                    seq,
                    send_time_ns: t_ns,
                    echo_seq: cmd.seq,
                    echo_send_time_ns: cmd.send_time_ns,
                    arm_id: 3,
                    state: state as u8,
                    ..Feedback::default()
                })
                .unwrap();
            t_ns += 1_000_000;
            ep.step(&mut master_end, t_ns, 1e-3);
        }
        assert_eq!(ep.round_trip().samples(), 2);
        assert_eq!(ep.round_trip().last_ns(), t_ns - cmd.send_time_ns);
    }
}
