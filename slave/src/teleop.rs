//! The slave's teleoperation endpoint: everything the slave does in one 1 kHz cycle of a
//! teleoperation session, on any [`ArmDriver`] and any [`Link`]. The lockstep session
//! simulation (`h4-master sim`) and the real process (`h4-slave run`) both step this, so
//! there is one piece of code for the slave's per-cycle logic.
//!
//! One [`SlaveTeleop::step`]:
//! 1. drains the link through the receive gate, which judges every command once (wire
//!    checks, arm, session, sequence number, the workspace/set-point/speed limits, energy
//!    plausibility) and counts each rejection by reason; rejected commands are dropped and
//!    their reasons go out in the next feedback's `rejected_reasons`;
//! 2. the watchdog: no valid command for `watchdog_ms` while active → the controller's safe
//!    stop (force ramped down, retract, hold), state `SafeStop`, `FAULT_COMMAND_TIMEOUT`;
//!    a fresh valid command after that → `clear_safe_stop()` and re-pairing with no jump
//!    (the gap between where the arm holds and where the master now points is taken as
//!    drift, closed by the energy-bounded drift compensation), counted;
//! 3. the slave's passivity port ([`AdmittancePort`]): observer always, controller in
//!    position mode when enabled;
//! 4. the controller step, the actuator command, the fault flags;
//! 5. publishes the feedback, with the port's cumulative energies.
//!
//! It allocates nothing, blocks on nothing, logs nothing and never panics; link errors are
//! counted, not returned. Energies on the wire are in slave units (J at the slave): the
//! master converts with κ = scale.force / scale.motion, so the slave needs no scaling.

use h4_shared::passivity::{AdmittancePort, AdmittanceStep, PassivityParams};
use h4_shared::vec3::norm3;
use h4_shared::watchdog::Watchdog;
use h4_shared::wire::{
    CMD_FLAG_ACK_SAFE_STOP, Command, CommandLimits, ContactState, FAULT_COMMAND_REJECTED,
    FAULT_COMMAND_TIMEOUT, FAULT_FORCE_LIMIT, FAULT_SAFETY_TRIP, FAULT_SENSOR, Feedback, Mode,
    PROTOCOL_VERSION, SURFACE_POINT_LIMIT_MM, SURFACE_STIFFNESS_MAX_N_PER_MM, SlaveState,
};
use h4_transport::Link;
use h4_transport::gate::{EnergyBound, Gate, GateCounters};
use serde::Serialize;

use crate::arm::ArmDriver;
use crate::controller::{ControllerInput, ControllerOutput, SlaveCommand, SlaveController, Status};
use crate::round_trip::RoundTripEstimator;
use crate::safety::{SafetyLimits, SafetyMonitor, SafetyTrips, TripReason};

/// Settings of the endpoint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TeleopParams {
    /// Arm id: commands for another arm are rejected, feedback carries it.
    pub arm_id: u16,
    /// No valid command for this long while active → safe stop, ms.
    pub watchdog_ms: f64,
    /// After this much silence a command whose sequence number went backwards is taken as
    /// a restarted master, ms.
    pub restart_silence_ms: f64,
    /// Passivity control (only `enabled`, `max_correction_mm_per_s`, `drift_gain_per_s`
    /// and `drift_energy_share` matter at the slave).
    pub passivity: PassivityParams,
    /// Commanded speeds are limited to this share of the controller's speed limit.
    pub speed_margin: f64,
    /// Contact hand-over: in position mode, the slave's own force loop holds a contact.
    pub contact: ContactHandover,
    /// The arm's ratings, the safety monitor and the override of the safety layers.
    pub safety: SafetyParams,
}

/// The safety layers' settings: the arm's ratings (from its arm file) that the monitor
/// enforces, and the override that alone may turn a safety layer off.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SafetyParams {
    /// The arm's ratings (`[ratings]` of the arm file).
    pub ratings: h4_shared::config::ArmRatings,
    /// The safety monitor runs (off only with `unsafe_test_override`).
    pub monitor: bool,
    /// `--unsafe-test-override`: passivity off, the spindle-stall stop off, the monitor off
    /// and controller gains beyond the arm's stable range are accepted (for the negative
    /// controls that show what the layers prevent). Never raises a rating.
    pub unsafe_test_override: bool,
}

impl Default for SafetyParams {
    fn default() -> Self {
        SafetyParams {
            ratings: h4_shared::config::ArmRatings::default(),
            monitor: true,
            unsafe_test_override: false,
        }
    }
}

/// Contact hand-over (position mode): when the slave meets a surface, its force controller
/// (the paper's implicit force control, `Mode::ForceGuided`) takes the contact over, so
/// that neither the wall's stiffness nor the link's delay is inside the loop that sets the
/// contact force. The master's command then sets the force through a virtual spring: the
/// force set-point is `hold_min_n + stiffness_n_per_mm · depth`, `depth` how far the
/// (passivity-shaped) commanded position lies beyond where the contact began, along the
/// contact normal; along the surface the arm follows the command's velocity. The
/// set-point never exceeds `force_share` of the controller's force limit. When the command
/// lies `release_mm` out of the surface the arm goes back to position control.
///
/// Over a long link the spring is delayed by the round trip `T` on its way to the operator's
/// hand and back, and the hand's damping cannot grow past what the handle's mass allows; the
/// delayed spring then holds only while `K·T` stays below about
/// `stiffness_delay_n_s_per_mm` (measured: docs/sessions.md, "The hand-over spring against
/// the round trip"). Since protocol 3 the slave measures `T` itself from the commands' echo
/// of its feedback ([`crate::round_trip`]) and the spring softens to
/// `min(stiffness_n_per_mm, stiffness_delay_n_s_per_mm / T)`; before the first echo (and with
/// `measure_round_trip = false`) it uses the figure the deployment tells it, `round_trip_ms`
/// (0: not told, the spring stays `stiffness_n_per_mm`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ContactHandover {
    /// Hand-over on.
    pub enabled: bool,
    /// The virtual spring's stiffness, N/mm at the slave (what the master's command
    /// feels like in contact, whatever the wall).
    pub stiffness_n_per_mm: f64,
    /// Set-point while the command is at the contact point, N (above the controller's
    /// contact threshold, so a light contact is held, not lost and re-touched).
    pub hold_min_n: f64,
    /// The command this far out of the surface ends the hand-over, mm.
    pub release_mm: f64,
    /// Largest set-point, as a share of the controller's force limit.
    pub force_share: f64,
    /// The link's round trip as the deployment knows it (the master's measured round trip,
    /// `round_trip_p50_us` in its summary), ms: the fallback before the slave has measured
    /// its own (the first echo arrives one round trip after the slave's first feedback);
    /// 0: not told, the spring stays `stiffness_n_per_mm` until then.
    pub round_trip_ms: f64,
    /// The slave measures its round trip from the commands' echo (protocol 3) and uses it
    /// instead of `round_trip_ms`; false: the told figure only (protocol 2's behaviour, for
    /// the controls).
    pub measure_round_trip: bool,
    /// The largest spring × round trip, N·s/mm: the spring softens to this over the told
    /// round trip.
    pub stiffness_delay_n_s_per_mm: f64,
}

impl Default for ContactHandover {
    fn default() -> Self {
        ContactHandover {
            enabled: true,
            stiffness_n_per_mm: 5.0,
            hold_min_n: 1.0,
            release_mm: 0.3,
            force_share: 0.8,
            round_trip_ms: 0.0,
            measure_round_trip: true,
            stiffness_delay_n_s_per_mm: 0.5,
        }
    }
}

impl ContactHandover {
    /// Checks every field; errors name the key with `prefix`.
    pub fn validate_at(&self, prefix: &str) -> Result<(), h4_shared::config::ConfigError> {
        use h4_shared::config::check_range;
        check_range(
            &format!("{prefix}stiffness_n_per_mm"),
            self.stiffness_n_per_mm,
            0.01,
            1e4,
            "N/mm",
        )?;
        check_range(
            &format!("{prefix}hold_min_n"),
            self.hold_min_n,
            0.0,
            100.0,
            "N",
        )?;
        check_range(
            &format!("{prefix}release_mm"),
            self.release_mm,
            0.0,
            100.0,
            "mm",
        )?;
        check_range(
            &format!("{prefix}force_share"),
            self.force_share,
            0.05,
            1.0,
            "",
        )?;
        check_range(
            &format!("{prefix}round_trip_ms"),
            self.round_trip_ms,
            0.0,
            60_000.0,
            "ms",
        )?;
        check_range(
            &format!("{prefix}stiffness_delay_n_s_per_mm"),
            self.stiffness_delay_n_s_per_mm,
            0.01,
            1e3,
            "N·s/mm",
        )
    }

    /// The virtual spring over the told round trip, N/mm: `stiffness_n_per_mm`, softened
    /// to `stiffness_delay_n_s_per_mm / T`.
    pub fn effective_stiffness_n_per_mm(&self) -> f64 {
        self.stiffness_at_n_per_mm(self.round_trip_ms)
    }

    /// The virtual spring over a round trip of `round_trip_ms` (measured or told), N/mm.
    pub fn stiffness_at_n_per_mm(&self, round_trip_ms: f64) -> f64 {
        let t_s = round_trip_ms / 1000.0;
        if t_s > 0.0 {
            self.stiffness_n_per_mm
                .min(self.stiffness_delay_n_s_per_mm / t_s)
        } else {
            self.stiffness_n_per_mm
        }
    }
}

/// A contact held by the slave's force loop.
#[derive(Clone, Copy, Debug, PartialEq)]
struct HeldContact {
    /// The commanded position when the contact began, mm.
    point_mm: [f64; 3],
    /// The outward contact normal (the measured force's direction at the touch).
    normal: [f64; 3],
    /// The virtual commanded position (the passivity port's), mm.
    virtual_mm: [f64; 3],
}

impl Default for TeleopParams {
    fn default() -> Self {
        TeleopParams {
            arm_id: 0,
            watchdog_ms: 20.0,
            restart_silence_ms: 100.0,
            passivity: PassivityParams::default(),
            speed_margin: 0.9,
            contact: ContactHandover::default(),
            safety: SafetyParams::default(),
        }
    }
}

/// Why the endpoint could not be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TeleopError {
    /// A setting is out of range.
    #[error("teleop endpoint: {field} = {value} is out of range ({allowed})")]
    OutOfRange {
        /// The setting.
        field: &'static str,
        /// Its value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
    /// A limit above the arm's rating (no setting may raise a rating).
    #[error(
        "teleop endpoint: {field} = {value} is above the arm's rating {rating} (ratings.{field} of the arm file): a setting may lower a rating, never raise it"
    )]
    AboveRating {
        /// The setting.
        field: &'static str,
        /// Its value.
        value: f64,
        /// The arm's rating.
        rating: f64,
    },
    /// A controller gain outside the range the controller is stable in on this arm.
    #[error(
        "teleop endpoint: controller.{field} = {value} is outside the range the controller is stable in on this arm (0 to {max}, ratings.{rating} of the arm file); only --unsafe-test-override accepts it"
    )]
    UnstableGain {
        /// The gain.
        field: &'static str,
        /// Its value.
        value: f64,
        /// The largest stable value.
        max: f64,
        /// The rating's name.
        rating: &'static str,
    },
    /// A safety layer turned off without the override.
    #[error(
        "teleop endpoint: {layer} is a safety layer: it may be turned off only with --unsafe-test-override"
    )]
    SafetyLayerOff {
        /// The setting that turns it off.
        layer: &'static str,
    },
}

/// Counters over the endpoint's life.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct TeleopCounters {
    /// Cycles stepped.
    pub cycles: u64,
    /// Commands the controller rejected (workspace, limits): never passed to the actuators.
    pub commands_rejected_by_controller: u64,
    /// Link errors while receiving or publishing.
    pub link_errors: u64,
    /// Times the watchdog, a spindle stall or a silent driver put the arm into its safe
    /// state.
    pub safe_stops: u64,
    /// Silence when the watchdog tripped (largest over all trips), ms.
    pub safe_stop_entry_silence_ms: f64,
    /// Of those, the safe stops the arm's spindle stall started (the master's
    /// acknowledgement is refused while the spindle stays stalled).
    pub spindle_stall_stops: u64,
    /// Of those, the safe stops a driver that stopped answering started: its reading's time
    /// did not move on for [`DRIVER_STALE_CYCLES`] cycles (the master's acknowledgement is
    /// refused until the readings are fresh again).
    pub driver_stale_stops: u64,
    /// Times a master was paired again after a safe stop (each on the master's
    /// acknowledgement, `CMD_FLAG_ACK_SAFE_STOP`).
    pub repairs: u64,
    /// Commands received in the safe stop without the master's acknowledgement (they
    /// keep the link alive but neither re-engage the arm nor count as energy).
    pub unacknowledged_in_safe_stop: u64,
    /// New energy ledgers started (re-engagement after a safe stop, a restarted master).
    pub new_pairings: u64,
    /// Feedback messages published.
    pub feedback_published: u64,
    /// The safety monitor's trips by reason (each also a safe stop).
    pub safety_trips: SafetyTrips,
    /// Active cycles that used the told round trip (the fallback) because none was measured
    /// yet (no echo) or measuring is off (`contact.measure_round_trip = false`).
    pub round_trip_fallback_cycles: u64,
    /// Echoes refused by the round-trip estimator (of a feedback this slave cannot have
    /// sent: a sequence number it has not reached, a send time after now).
    pub round_trip_echoes_refused: u64,
}

/// What one cycle did (plain data, no allocation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TeleopCycle {
    /// The controller's output.
    pub out: ControllerOutput,
    /// The passivity port's step.
    pub port: AdmittanceStep,
    /// The slave position the link asks for (master's command), mm.
    pub desired_mm: [f64; 3],
    /// The position commanded to the controller (desired + drift), mm and rad.
    pub commanded_pose: [f64; 4],
    /// The port's drift (commanded − desired), mm.
    pub drift_mm: [f64; 3],
    /// The mode acted on.
    pub mode: Mode,
    /// The endpoint's state after this cycle.
    pub state: SlaveState,
    /// Fault flags sent with this cycle's feedback.
    pub fault_flags: u16,
    /// A valid command arrived this cycle.
    pub fresh: bool,
    /// The watchdog tripped this cycle.
    pub tripped: bool,
    /// The master was paired again this cycle (after a safe stop).
    pub repaired: bool,
    /// Cumulative energies of the slave's port, J.
    pub energy_in_j: f64,
    /// See `energy_in_j`.
    pub energy_out_j: f64,
    /// See `energy_in_j`.
    pub dissipated_j: f64,
    /// Sequence number of the newest accepted command (0: none).
    pub command_seq: u64,
    /// The round trip the hand-over uses this cycle, ms: the measured one, or the told
    /// fallback (`contact.round_trip_ms`, 0: none) when `round_trip_measured` is false.
    pub round_trip_ms: f64,
    /// Whether `round_trip_ms` is the slave's own measurement (false: the fallback).
    pub round_trip_measured: bool,
    /// The arm's reading this cycle (encoders and force/torque sensor), as the driver gave it.
    pub reading: crate::arm::ArmReading,
}

/// The slave's teleoperation endpoint over the arm `A`.
pub struct SlaveTeleop<A: ArmDriver> {
    p: TeleopParams,
    gate: Gate<Command>,
    session_id: u64,
    watchdog: Watchdog,
    port: AdmittancePort,
    ctrl: SlaveController,
    arm: A,
    state: SlaveState,
    faults: u16,
    latest: Option<Command>,
    desired: [f64; 3],
    desired_theta: f64,
    anchored: bool,
    last_out: Option<ControllerOutput>,
    /// Last cycle's commanded displacement and the force measured at its start, booked
    /// by the port once the force at its end is measured.
    pending_work: Option<([f64; 3], [f64; 3])>,
    held: Option<HeldContact>,
    /// The surface of the last held contact (start point, outward normal): position mode
    /// approaches it again no faster than the controller's approach speed.
    known_surface: Option<([f64; 3], [f64; 3])>,
    seq: u64,
    counters: TeleopCounters,
    /// The slave's own round trip, from the commands' echo.
    rtt: RoundTripEstimator,
    /// The safety monitor.
    monitor: SafetyMonitor,
    /// The trip that put the arm into its safe stop (cleared on re-arm).
    tripped_by: Option<TripReason>,
    /// The monitor kept last cycle's command from the arm: the controller starts again from
    /// the arm's pose.
    withheld: bool,
}

impl<A: ArmDriver> SlaveTeleop<A> {
    /// An endpoint driving `arm` with `ctrl`; `period_ns` is the loop period (the watchdog
    /// trips at the first cycle whose silence reaches `watchdog_ms`).
    pub fn new(
        p: TeleopParams,
        ctrl: SlaveController,
        arm: A,
        period_ns: u64,
    ) -> Result<Self, TeleopError> {
        let check = |field, value: f64, min: f64, max: f64, allowed| {
            if value.is_finite() && value >= min && value <= max {
                Ok(())
            } else {
                Err(TeleopError::OutOfRange {
                    field,
                    value,
                    allowed,
                })
            }
        };
        check("watchdog_ms", p.watchdog_ms, 1.0, 1e5, "1 to 100000 ms")?;
        check(
            "restart_silence_ms",
            p.restart_silence_ms,
            1.0,
            1e6,
            "1 to 1000000 ms",
        )?;
        check("speed_margin", p.speed_margin, 0.1, 1.0, "0.1 to 1")?;
        check(
            "passivity.max_correction_mm_per_s",
            p.passivity.max_correction_mm_per_s,
            0.0,
            1e4,
            "0 to 10000 mm/s",
        )?;
        check(
            "passivity.drift_gain_per_s",
            p.passivity.drift_gain_per_s,
            0.0,
            100.0,
            "0 to 100 1/s",
        )?;
        check(
            "passivity.drift_energy_share",
            p.passivity.drift_energy_share,
            0.0,
            1.0,
            "0 to 1",
        )?;
        check_safety(&p, ctrl.params())?;
        let watchdog_ns = ((p.watchdog_ms * 1e6) as u64).saturating_sub(period_ns);
        let ctrl_ws = &ctrl.workspace().clone();
        let ctrl_force_limit_n = ctrl.params().force_limit_n;
        let cp = ctrl.params();
        let limits = CommandLimits {
            workspace: *ctrl.workspace(),
            max_speed_mm_per_s: cp.max_speed_mm_per_s,
            force_limit_n: cp.force_limit_n,
        };
        let energy =
            EnergyBound::from_limits(cp.force_limit_n, cp.max_speed_mm_per_s, ENERGY_POWER_MARGIN);
        Ok(SlaveTeleop {
            gate: Gate::new(p.arm_id, (p.restart_silence_ms * 1e6) as u64)
                .with_limits(limits)
                .with_energy_bound(energy),
            session_id: h4_shared::wire::new_session_id(),
            watchdog: Watchdog::new(watchdog_ns),
            port: AdmittancePort::from_params(&p.passivity),
            ctrl,
            arm,
            state: SlaveState::Idle,
            faults: 0,
            latest: None,
            desired: [0.0; 3],
            desired_theta: 0.0,
            anchored: false,
            last_out: None,
            pending_work: None,
            held: None,
            known_surface: None,
            seq: 0,
            counters: TeleopCounters::default(),
            rtt: RoundTripEstimator::new(),
            monitor: SafetyMonitor::new(SafetyLimits::new(
                p.safety.ratings,
                *ctrl_ws,
                ctrl_force_limit_n,
            )),
            tripped_by: None,
            withheld: false,
            p,
        })
    }

    /// The arm.
    pub fn arm(&self) -> &A {
        &self.arm
    }

    /// The arm, mutable (a simulated arm is advanced by its owner).
    pub fn arm_mut(&mut self) -> &mut A {
        &mut self.arm
    }

    /// The controller.
    pub fn controller(&self) -> &SlaveController {
        &self.ctrl
    }

    /// The passivity port.
    pub fn port(&self) -> &AdmittancePort {
        &self.port
    }

    /// Counters.
    pub fn counters(&self) -> &TeleopCounters {
        &self.counters
    }

    /// The slave's measurement of its round trip.
    pub fn round_trip(&self) -> &RoundTripEstimator {
        &self.rtt
    }

    /// The round trip the hand-over uses, ms, and whether it is measured: the slave's own
    /// (the estimator's median) once an echo has arrived and measuring is on, else the told
    /// `contact.round_trip_ms` (0: none).
    pub fn round_trip_in_use_ms(&self) -> (f64, bool) {
        match self.rtt.round_trip_ms() {
            Some(ms) if self.p.contact.measure_round_trip => (ms, true),
            _ => (self.p.contact.round_trip_ms, false),
        }
    }

    /// What the receive gate accepted and rejected.
    pub fn gate_counters(&self) -> &GateCounters {
        &self.gate.counters
    }

    /// The receive gate (its paired session, pairing energies, last rejection).
    pub fn gate(&self) -> &Gate<Command> {
        &self.gate
    }

    /// This slave's session id (sent in every feedback).
    pub fn session_id(&self) -> u64 {
        self.session_id
    }

    /// The state.
    pub fn state(&self) -> SlaveState {
        self.state
    }

    /// Time since the last valid command at `now_ns` (None before the first).
    pub fn silence_ns(&self, now_ns: u64) -> Option<u64> {
        self.watchdog.silence_ns(now_ns)
    }

    /// One cycle at `now_ns` of `dt_s` seconds on `link`: receive, watchdog, the command
    /// to follow, the passivity port, the controller and the arm, the port's booking, the
    /// feedback.
    pub fn step<L: Link<Feedback, Command>>(
        &mut self,
        link: &mut L,
        now_ns: u64,
        dt_s: f64,
    ) -> TeleopCycle {
        let reading = self.arm.read();
        let silent = self.monitor.observe_time(&reading);
        if silent && self.state != SlaveState::SafeStop {
            // The arm stopped answering: what the controller would act on is old.
            self.ctrl.safe_stop_at_once();
            self.state = SlaveState::SafeStop;
            self.counters.safe_stops += 1;
            self.counters.driver_stale_stops += 1;
            self.counters.safety_trips.count(TripReason::DriverSilent);
            self.tripped_by = Some(TripReason::DriverSilent);
            self.faults |= FAULT_SAFETY_TRIP;
        }
        let stalled =
            silent || self.ctrl.params().spindle_stall_safe_stop && self.arm.spindle_stalled();
        if stalled && !silent && self.state == SlaveState::Active {
            // The spindle stopped under load: feeding on would wedge the tool into the part.
            self.ctrl.safe_stop_at_once();
            self.state = SlaveState::SafeStop;
            self.counters.safe_stops += 1;
            self.counters.spindle_stall_stops += 1;
        }
        if stalled && !silent && self.state == SlaveState::SafeStop {
            // Still stalled once the stop holds: lift further until the spindle runs.
            self.ctrl.lift_stalled_tool();
        }
        // A sensor fault the monitor saw last cycle refuses the acknowledgement as a stall
        // does.
        let sensor_fault = self.p.safety.monitor && self.monitor.persistent_fault().is_some();
        let (fresh, acked) = self.receive(link, now_ns, stalled || sensor_fault);
        let (repaired, tripped) = self.watch(fresh, acked, now_ns);
        let intent = self.follow(dt_s);
        let port = self.shape_command(&intent, dt_s);
        let input = ControllerInput {
            actuators_mm: reading.actuators_mm,
            wrench: reading.wrench,
            command: port.command,
        };
        self.ctrl.observe_turntable(self.arm.turntable_rad());
        if self.withheld {
            self.ctrl.resync_to_arm();
        }
        let out = self.ctrl.step(&input, dt_s);
        self.flag_faults(&out);
        // The safety monitor, between the controller and the arm: a trip keeps this
        // cycle's command from the arm (it holds the last one) and starts the safe stop.
        let force = [
            out.wrench_measured[0],
            out.wrench_measured[1],
            out.wrench_measured[2],
        ];
        let trip = if self.p.safety.monitor {
            self.monitor.check_sample(
                &reading,
                self.arm.wrench_is_new_sample(),
                silent,
                force,
                dt_s,
            )
        } else {
            None
        };
        if self.monitor.persistent_fault().is_some() && self.p.safety.monitor {
            self.faults |= FAULT_SENSOR;
        } else {
            self.faults &= !FAULT_SENSOR;
        }
        // The command is kept from the arm in the trip's cycle and while a sensor fault lasts
        // (what the controller acts on is not to be trusted); otherwise the safe stop's own
        // commands (backing away, retract, hold) reach it.
        let hold_command = match trip {
            Some(TripReason::DriverSilent) => false,
            Some(reason) => {
                let entering = self.tripped_by.is_none() || self.state != SlaveState::SafeStop;
                self.safety_trip(reason);
                entering || reason.persistent()
            }
            None => false,
        };
        self.withheld = hold_command;
        if !hold_command {
            self.arm.command(&out.actuators_cmd_mm);
        }
        if let Some(a) = self.ctrl.turntable_command_rad(dt_s) {
            self.arm.command_turntable(a);
        }
        self.book(&out, &intent, &port, dt_s);
        self.last_out = Some(out);
        let command_seq = self.publish(link, &out, now_ns);
        self.counters.cycles += 1;
        let (round_trip_ms, round_trip_measured) = self.round_trip_in_use_ms();
        if !round_trip_measured && self.state == SlaveState::Active {
            self.counters.round_trip_fallback_cycles += 1;
        }
        self.counters.round_trip_echoes_refused = self.rtt.refused();
        let energy = self.port.energy;
        TeleopCycle {
            out,
            port: port.step,
            desired_mm: self.desired,
            commanded_pose: port.command.pose,
            drift_mm: port.drift_mm,
            mode: intent.mode,
            state: self.state,
            fault_flags: self.faults,
            fresh,
            tripped,
            repaired,
            energy_in_j: energy.in_j,
            energy_out_j: energy.out_j,
            dissipated_j: energy.dissipated_j,
            command_seq,
            round_trip_ms,
            round_trip_measured,
            reading,
        }
    }

    /// A trip of the safety monitor: the safe stop at once (force set-point zero, back away
    /// along the sensed force, retract, hold), counted by reason. In a safe stop already
    /// (a watchdog's, holding the contact force), the stop turns to backing away at once.
    /// Counted once per entry into the safe stop.
    fn safety_trip(&mut self, reason: TripReason) {
        self.ctrl.safety_trip();
        if self.state != SlaveState::SafeStop || self.tripped_by.is_none() {
            self.counters.safety_trips.count(reason);
            if self.state != SlaveState::SafeStop {
                self.counters.safe_stops += 1;
            }
            self.tripped_by = Some(reason);
        }
        self.state = SlaveState::SafeStop;
        self.faults |= FAULT_SAFETY_TRIP;
    }

    /// The monitor's trip that put the arm into its safe stop, until the master re-arms it.
    pub fn tripped_by(&self) -> Option<TripReason> {
        self.tripped_by
    }

    /// Drains the link through the receive gate; returns whether a valid command arrived
    /// and whether the master acknowledged a safe stop (then the port has started a new
    /// ledger before taking the acknowledging command's energy). In the safe stop, commands
    /// without the acknowledgement (and every command while the spindle is stalled) are not
    /// followed and their energies (the old ledger's) are not taken. A restarted master (the gate re-paired) also starts a new ledger.
    fn receive<L: Link<Feedback, Command>>(
        &mut self,
        link: &mut L,
        now_ns: u64,
        spindle_stalled: bool,
    ) -> (bool, bool) {
        let port = &mut self.port;
        let latest = &mut self.latest;
        let rtt = &mut self.rtt;
        let own_seq = self.seq;
        let safe_stopped = self.state == SlaveState::SafeStop;
        let mut acked = false;
        let mut ignored = 0;
        let restarts = self.gate.counters.repaired;
        let d = self
            .gate
            .drain(link, now_ns, MAX_RECEIVED_PER_CYCLE, |c: &Command| {
                // Every accepted command's echo is a round trip, followed or not.
                rtt.observe(c.echo_seq, c.echo_send_time_ns, own_seq, now_ns);
                if safe_stopped && !acked {
                    if c.flags & CMD_FLAG_ACK_SAFE_STOP == 0 || spindle_stalled {
                        ignored += 1;
                        return;
                    }
                    acked = true;
                    port.new_pairing();
                }
                port.receive_remote_in(c.energy_in_j);
                *latest = Some(*c);
            });
        self.counters.unacknowledged_in_safe_stop += ignored;
        if acked {
            self.counters.new_pairings += 1;
        }
        if self.gate.counters.repaired > restarts && !acked {
            self.new_pairing();
        }
        if d.link_error {
            self.counters.link_errors += 1;
        }
        (d.accepted > 0, acked)
    }

    /// A new pairing: the port starts a new energy ledger (taking the newest command's
    /// energy as the new pairing's first), and the desired pose re-anchors on the next
    /// command (no jump). Called on a restarted master; a session id in the wire header
    /// can call it on a new session too.
    pub fn new_pairing(&mut self) {
        self.port.new_pairing();
        if let Some(c) = &self.latest {
            self.port.receive_remote_in(c.energy_in_j);
        }
        self.anchored = false;
        self.counters.new_pairings += 1;
    }

    /// The watchdog: a fresh command feeds it (and, with the master's acknowledgement,
    /// re-pairs after a safe stop); silence while active trips it into the safe stop.
    /// Returns (re-paired, tripped) this cycle.
    fn watch(&mut self, fresh: bool, acked: bool, now_ns: u64) -> (bool, bool) {
        let mut repaired = false;
        if fresh && (acked || self.state != SlaveState::SafeStop) {
            self.watchdog.feed(now_ns);
            if self.state == SlaveState::SafeStop {
                self.ctrl.clear_safe_stop();
                self.tripped_by = None;
                self.faults &= !FAULT_SAFETY_TRIP;
                self.counters.repairs += 1;
                repaired = true;
                // Re-pair with no jump: re-anchor on the next command.
                self.anchored = false;
            }
            self.state = SlaveState::Active;
            self.faults &= !FAULT_COMMAND_TIMEOUT;
        }
        let mut tripped = false;
        if self.state == SlaveState::Active && self.watchdog.tripped(now_ns) {
            self.ctrl.safe_stop();
            self.state = SlaveState::SafeStop;
            self.faults |= FAULT_COMMAND_TIMEOUT;
            self.counters.safe_stops += 1;
            let silence_ms = self.watchdog.silence_ns(now_ns).unwrap_or(0) as f64 / 1e6;
            self.counters.safe_stop_entry_silence_ms =
                self.counters.safe_stop_entry_silence_ms.max(silence_ms);
            tripped = true;
        }
        (repaired, tripped)
    }

    /// What the master asks for this cycle (Hold when not active), and the desired
    /// position it moves (anchored on the first command of a motion, so there is no jump).
    fn follow(&mut self, dt_s: f64) -> Intent {
        let active = self.state == SlaveState::Active;
        let (mode, clutch, setpoint_n, velocity) = match (&self.latest, active) {
            (Some(c), true) => (
                c.mode().unwrap_or(Mode::Hold),
                c.clutch(),
                c.force_setpoint_n,
                c.velocity,
            ),
            _ => (Mode::Hold, false, 0.0, [0.0; 4]),
        };
        let mut desired_velocity = [0.0; 3];
        if let Some(c) = &self.latest
            && active
            && !clutch
            && mode != Mode::Hold
        {
            if !self.anchored {
                // First command, or the first after a safe stop or a hold: the link's
                // pose becomes the desired one with no velocity; the port closes the gap
                // from where the arm is commanded gradually (no jump).
                self.desired = [c.pose[0], c.pose[1], c.pose[2]];
                self.anchored = true;
            }
            for (i, v) in desired_velocity.iter_mut().enumerate() {
                *v = (c.pose[i] - self.desired[i]) / dt_s;
                self.desired[i] = c.pose[i];
            }
            self.desired_theta = c.pose[3];
        } else if mode == Mode::Hold || !active {
            // While holding the arm stays where it is; re-anchor on the next motion.
            self.anchored = false;
        }
        Intent {
            mode,
            clutch,
            setpoint_n,
            velocity,
            desired_velocity,
        }
    }

    /// The passivity port's step (position mode: observer, and controller when enabled)
    /// and the controller command it gives, its speed limited.
    fn shape_command(&mut self, intent: &Intent, dt_s: f64) -> PortCommand {
        let mode = intent.mode;
        let force = self.last_out.map_or([0.0; 3], |o| {
            [
                o.wrench_measured[0],
                o.wrench_measured[1],
                o.wrench_measured[2],
            ]
        });
        let control = self.p.passivity.enabled && mode == Mode::Position && !intent.clutch;
        let max_v = self.ctrl.params().max_speed_mm_per_s * self.p.speed_margin;
        let held = self.last_out.map_or(self.desired, |o| {
            [
                o.commanded_pose[0],
                o.commanded_pose[1],
                o.commanded_pose[2],
            ]
        });
        let v_d = intent.desired_velocity;
        // The safe stop holds the contact's force: the hand-over is kept as it is (not
        // stepped: nothing moves, nothing is booked), so a re-pairing within the hold
        // continues from the same virtual spring (no force jump, the tool stays on the
        // surface).
        let riding_through =
            self.state == SlaveState::SafeStop && self.ctrl.safe_stop_holds_contact();
        if riding_through {
        } else if mode != Mode::Position || intent.clutch {
            self.held = None;
        } else {
            self.update_held(force, held);
        }
        if let Some(mut h) = self.held
            && !riding_through
        {
            return self.handover(&mut h, intent, max_v, control, dt_s);
        }
        let ps = if mode == Mode::Position {
            let ps = self
                .port
                .step_position(held, self.desired, v_d, force, max_v, dt_s, control);
            self.slow_near_known_surface(ps, held, dt_s)
        } else {
            self.port.clear_drift();
            AdmittanceStep {
                velocity_mm_per_s: [intent.velocity[0], intent.velocity[1], intent.velocity[2]],
                target_mm: self.desired,
                admittance_mm_per_n_s: 0.0,
                observed_j: self.port.observed_j(),
            }
        };
        let drift_mm = self.port.drift_mm;
        let pose = [
            ps.target_mm[0],
            ps.target_mm[1],
            ps.target_mm[2],
            self.desired_theta,
        ];
        let mut vel = ps.velocity_mm_per_s;
        let speed = norm3(&vel);
        if speed > max_v {
            for v in vel.iter_mut() {
                *v *= max_v / speed;
            }
        }
        PortCommand {
            step: ps,
            control,
            drift_mm,
            virtual_move_mm: None,
            command: SlaveCommand {
                mode,
                pose,
                velocity: [vel[0], vel[1], vel[2], 0.0],
                force_setpoint_n: intent
                    .setpoint_n
                    .clamp(0.0, self.ctrl.params().force_limit_n),
                clutch: intent.clutch,
            },
        }
    }

    /// Position mode near a surface held before (after a release, a safe stop, a
    /// re-pairing): the motion into it, within `SURFACE_MARGIN_MM` of it or beyond, is
    /// limited to the controller's approach speed, so a return to a known stiff wall
    /// touches it as gently as the force loop's own approach; the gap becomes drift.
    fn slow_near_known_surface(
        &mut self,
        mut ps: AdmittanceStep,
        held: [f64; 3],
        dt_s: f64,
    ) -> AdmittanceStep {
        let Some((point, n)) = self.known_surface else {
            return ps;
        };
        let h = HeldContact {
            point_mm: point,
            normal: n,
            virtual_mm: point,
        };
        let v = ps.velocity_mm_per_s;
        let v_in = -(v[0] * n[0] + v[1] * n[1] + v[2] * n[2]);
        let approach = self.ctrl.params().approach_speed_mm_per_s;
        if depth_mm(&h, &ps.target_mm) > -SURFACE_MARGIN_MM && v_in > approach {
            for i in 0..3 {
                ps.velocity_mm_per_s[i] += (v_in - approach) * n[i];
                ps.target_mm[i] = held[i] + ps.velocity_mm_per_s[i] * dt_s;
            }
            let mut drift = [0.0; 3];
            for (i, d) in drift.iter_mut().enumerate() {
                *d = ps.target_mm[i] - self.desired[i];
            }
            self.port.set_drift(drift);
        }
        ps
    }

    /// Starts the contact hand-over on a touch (the measured force above the controller's
    /// contact threshold, in position mode) and ends it once the command lies
    /// `release_mm` out of the surface.
    fn update_held(&mut self, force: [f64; 3], commanded: [f64; 3]) {
        let c = self.p.contact;
        if !c.enabled {
            self.held = None;
            return;
        }
        match self.held {
            None => {
                let f = norm3(&force);
                if f > self.ctrl.params().contact_threshold_n {
                    let normal = [force[0] / f, force[1] / f, force[2] / f];
                    self.held = Some(HeldContact {
                        point_mm: commanded,
                        normal,
                        virtual_mm: commanded,
                    });
                    self.known_surface = Some((commanded, normal));
                }
            }
            Some(h) => {
                let out = depth_mm(&h, &self.desired);
                if out < -c.release_mm {
                    self.held = None;
                }
            }
        }
    }

    /// One cycle of the contact hand-over: the passivity port moves the virtual commanded
    /// position (its energy bound holds the depth when the observer is empty), and the
    /// force loop is asked for the virtual spring's force at its depth.
    fn handover(
        &mut self,
        h: &mut HeldContact,
        intent: &Intent,
        max_v: f64,
        control: bool,
        dt_s: f64,
    ) -> PortCommand {
        let c = self.p.contact;
        let k = c.stiffness_at_n_per_mm(self.round_trip_in_use_ms().0);
        let v_d = intent.desired_velocity;
        // The port drives the virtual spring. Out of contact (the force loop approaching, a
        // bounce) the measured force is about zero: the port bounds and books the motion
        // against the spring's force, so a virtual position moved into the surface is paid
        // for before the force loop reaches it. In contact the measured force is what the
        // master renders, and the motion is booked against it (at the same instants), as
        // outside the hand-over; the bound takes the larger of the two.
        let n = h.normal;
        let measured = self.last_out.map_or([0.0; 3], |o| {
            [
                o.wrench_measured[0],
                o.wrench_measured[1],
                o.wrench_measured[2],
            ]
        });
        let touching = norm3(&measured) >= self.ctrl.params().contact_threshold_n;
        let spring = |depth: f64| {
            let f = handover_setpoint_n(&c, k, depth);
            [f * n[0], f * n[1], f * n[2]]
        };
        let depth = depth_mm(h, &h.virtual_mm);
        let f_start = spring(depth);
        // The bound must cover the spring's force wherever this step can end: its force at
        // the deepest point one step at the speed limit reaches, and never less than the
        // hold force (inside the release band the spring's force ramps up from zero: a
        // bound of zero there would let each step in go unpaid).
        let f_spring = spring(depth.max(0.0) + max_v * dt_s);
        let f_bound = if norm3(&measured) > norm3(&f_spring) {
            measured
        } else {
            f_spring
        };
        let ps = self.port.step_position(
            h.virtual_mm,
            self.desired,
            v_d,
            f_bound,
            max_v,
            dt_s,
            control,
        );
        let moved = [
            ps.target_mm[0] - h.virtual_mm[0],
            ps.target_mm[1] - h.virtual_mm[1],
            ps.target_mm[2] - h.virtual_mm[2],
        ];
        h.virtual_mm = ps.target_mm;
        self.held = Some(*h);
        let f_end = spring(depth_mm(h, &h.virtual_mm));
        let limit = self.ctrl.params().force_limit_n * c.force_share;
        let sp = handover_setpoint_n(&c, k, depth_mm(h, &h.virtual_mm));
        // Along the surface: the command's velocity without its normal part.
        let n = h.normal;
        let vn = v_d[0] * n[0] + v_d[1] * n[1] + v_d[2] * n[2];
        let mut vt = [0.0; 3];
        for i in 0..3 {
            vt[i] = v_d[i] - vn * n[i];
        }
        let speed = norm3(&vt);
        if speed > max_v {
            for v in vt.iter_mut() {
                *v *= max_v / speed;
            }
        }
        PortCommand {
            step: ps,
            control,
            drift_mm: self.port.drift_mm,
            virtual_move_mm: Some((moved, (!touching).then_some((f_start, f_end)))),
            command: SlaveCommand {
                mode: Mode::ForceGuided,
                pose: [
                    h.virtual_mm[0],
                    h.virtual_mm[1],
                    h.virtual_mm[2],
                    self.desired_theta,
                ],
                velocity: [vt[0], vt[1], vt[2], 0.0],
                force_setpoint_n: sp.clamp(0.0, limit),
                clutch: false,
            },
        }
    }

    /// The fault flags of the controller's output: a rejected command, the force limit.
    fn flag_faults(&mut self, out: &ControllerOutput) {
        if out.rejection.is_some() {
            self.counters.commands_rejected_by_controller += 1;
            self.faults |= FAULT_COMMAND_REJECTED;
        } else {
            self.faults &= !FAULT_COMMAND_REJECTED;
        }
        if out.status == Status::ForceLimited {
            self.faults |= FAULT_FORCE_LIMIT;
        } else {
            self.faults &= !FAULT_FORCE_LIMIT;
        }
    }

    /// The port books the motion actually commanded (the controller's rate limits and
    /// holds included) against the force the arm measured at the same instants: the
    /// displacement commanded last cycle (executed over it) against the forces measured
    /// at its start and at its end (this cycle's reading). Only position mode closes a
    /// loop through the link: in force-guided mode the contact force is the slave's own
    /// force loop's, and nothing measured is rendered.
    fn book(&mut self, out: &ControllerOutput, intent: &Intent, port: &PortCommand, dt_s: f64) {
        let f_now = [
            out.wrench_measured[0],
            out.wrench_measured[1],
            out.wrench_measured[2],
        ];
        if let Some((f_start, moved)) = self.pending_work.take() {
            self.port.commit_work(f_start, f_now, moved);
        }
        if intent.mode == Mode::Position {
            match port.virtual_move_mm {
                // In the contact hand-over the link's port is the virtual commanded position;
                // out of contact its force is the virtual spring's, known now.
                Some((moved, Some((f_start, f_end)))) => {
                    self.port.commit_work(f_start, f_end, moved)
                }
                // In contact: the measured forces at both ends of the move.
                Some((moved, None)) => self.pending_work = Some((f_now, moved)),
                None => {
                    let moved = self.last_out.map_or([0.0; 3], |o| {
                        [
                            out.commanded_pose[0] - o.commanded_pose[0],
                            out.commanded_pose[1] - o.commanded_pose[1],
                            out.commanded_pose[2] - o.commanded_pose[2],
                        ]
                    });
                    self.pending_work = Some((f_now, moved));
                }
            }
            if port.control {
                self.port.hand_back(dt_s);
            }
        }
    }

    /// Publishes this cycle's feedback (with the port's energies); returns the sequence
    /// number of the newest accepted command it echoes (0: none).
    fn publish<L: Link<Feedback, Command>>(
        &mut self,
        link: &mut L,
        out: &ControllerOutput,
        now_ns: u64,
    ) -> u64 {
        self.seq += 1;
        let (echo_seq, echo_t) = self.latest.map_or((0, 0), |c| (c.seq, c.send_time_ns));
        let surface = self.surface_estimate(out);
        let fb = Feedback {
            seq: self.seq,
            send_time_ns: now_ns,
            echo_seq,
            echo_send_time_ns: echo_t,
            pose: out.measured_pose,
            wrench_measured: out.wrench_measured,
            wrench_desired: out.wrench_desired,
            energy_in_j: self.port.available_to_remote_j(),
            energy_out_j: self.port.energy.out_j,
            protocol_version: PROTOCOL_VERSION,
            arm_id: self.p.arm_id,
            state: self.state as u8,
            contact_state: surface.state as u8,
            fault_flags: self.faults,
            session_id: self.session_id,
            rejected_reasons: self.gate.take_reasons(),
            rejected_count: u32::try_from(self.gate.counters.rejected()).unwrap_or(u32::MAX),
            contact_point_mm: surface.point_mm,
            contact_normal: surface.normal,
            contact_stiffness_n_per_mm: surface.stiffness_n_per_mm,
        };
        if fb.validate().is_ok() {
            match link.publish(&fb) {
                Ok(()) => self.counters.feedback_published += 1,
                Err(_) => self.counters.link_errors += 1,
            }
        }
        echo_seq
    }
}

/// The slave's surface estimate, as the feedback carries it (protocol 3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceEstimate {
    /// Free, contact or unknown.
    pub state: ContactState,
    /// The contact point, mm, slave frame.
    pub point_mm: [f64; 3],
    /// The outward unit normal (zero: none known).
    pub normal: [f64; 3],
    /// The environment's stiffness the force controller estimates, N/mm (0: none).
    pub stiffness_n_per_mm: f64,
}

impl<A: ArmDriver> SlaveTeleop<A> {
    /// The surface estimate from what the slave already estimates: in contact (a contact the
    /// hand-over holds, or the measured force above the controller's contact threshold) the
    /// tool's measured position, the controller's contact normal (the hand-over's when the
    /// controller has none) and its online stiffness estimate (`env_stiffness_n_per_mm`, the
    /// recursive least squares of `controller::estimator`); in free space the last surface
    /// touched (all zero before the first touch) with the stiffness estimate as it was left;
    /// unknown while not active (idle, safe stop). Any figure that would not pass the
    /// receiver's checks (`Feedback::validate`) is sent as unknown.
    fn surface_estimate(&self, out: &ControllerOutput) -> SurfaceEstimate {
        let unknown = SurfaceEstimate {
            state: ContactState::Unknown,
            point_mm: [0.0; 3],
            normal: [0.0; 3],
            stiffness_n_per_mm: 0.0,
        };
        if self.state != SlaveState::Active {
            return unknown;
        }
        let force = [
            out.wrench_measured[0],
            out.wrench_measured[1],
            out.wrench_measured[2],
        ];
        let touching =
            self.held.is_some() || norm3(&force) > self.ctrl.params().contact_threshold_n;
        let unit = |n: [f64; 3]| {
            let l = norm3(&n);
            (l.is_finite() && l > 1e-9).then(|| [n[0] / l, n[1] / l, n[2] / l])
        };
        let k = out.env_stiffness_n_per_mm;
        let k = if k.is_finite() && (0.0..=SURFACE_STIFFNESS_MAX_N_PER_MM).contains(&k) {
            k
        } else {
            0.0
        };
        let est = if touching {
            let normal = unit(out.contact_normal)
                .or_else(|| self.held.and_then(|h| unit(h.normal)))
                .or_else(|| unit(force));
            let Some(normal) = normal else {
                return unknown;
            };
            let m = out.measured_pose;
            SurfaceEstimate {
                state: ContactState::Contact,
                point_mm: [m[0], m[1], m[2]],
                normal,
                stiffness_n_per_mm: k,
            }
        } else {
            let (point_mm, normal) = self
                .known_surface
                .and_then(|(p, n)| unit(n).map(|n| (p, n)))
                .unwrap_or(([0.0; 3], [0.0; 3]));
            SurfaceEstimate {
                state: ContactState::Free,
                point_mm,
                normal,
                stiffness_n_per_mm: if normal == [0.0; 3] { 0.0 } else { k },
            }
        };
        let in_range = est
            .point_mm
            .iter()
            .all(|x| x.is_finite() && x.abs() <= SURFACE_POINT_LIMIT_MM);
        if in_range { est } else { unknown }
    }
}

/// What the master asks for this cycle.
struct Intent {
    /// The mode acted on (Hold when not active).
    mode: Mode,
    /// The operator's clutch.
    clutch: bool,
    /// The force set-point, N.
    setpoint_n: f64,
    /// The commanded velocity `[vx, vy, vz, ω]`, mm/s and rad/s.
    velocity: [f64; 4],
    /// The velocity of the desired position this cycle, mm/s.
    desired_velocity: [f64; 3],
}

/// The virtual spring's force before and after a move of the hand-over's virtual position, N.
type SpringForces = ([f64; 3], [f64; 3]);

/// The passivity port's step and the controller command it gives.
struct PortCommand {
    /// The port's step.
    step: AdmittanceStep,
    /// The port's controller acts (passivity on, position mode, no clutch).
    control: bool,
    /// The port's drift (commanded − desired), mm.
    drift_mm: [f64; 3],
    /// In the contact hand-over: the virtual commanded position's move this cycle, mm, and,
    /// out of contact, the virtual spring's force before and after it, N (booked against
    /// the move; in contact the measured forces are).
    virtual_move_mm: Option<([f64; 3], Option<SpringForces>)>,
    /// The controller's command.
    command: SlaveCommand,
}

/// How close to a surface held before position mode slows to the approach speed, mm.
const SURFACE_MARGIN_MM: f64 = 1.0;

/// The hand-over's virtual spring: the force set-point at `depth_mm` of the virtual
/// position beyond the contact's start point (released over `release_mm` outside it), N.
fn handover_setpoint_n(c: &ContactHandover, stiffness_n_per_mm: f64, depth_mm: f64) -> f64 {
    if depth_mm >= 0.0 {
        c.hold_min_n + stiffness_n_per_mm * depth_mm
    } else {
        c.hold_min_n * (1.0 + depth_mm / c.release_mm.max(1e-6)).max(0.0)
    }
}

/// How far `x` lies beyond the contact's start point, along its inward normal, mm.
fn depth_mm(h: &HeldContact, x: &[f64; 3]) -> f64 {
    let n = h.normal;
    (h.point_mm[0] - x[0]) * n[0] + (h.point_mm[1] - x[1]) * n[1] + (h.point_mm[2] - x[2]) * n[2]
}

/// Most commands taken from the link in one cycle (more than any queue holds).
/// The energy plausibility bound on the master's energy fields: this many times the power
/// the slave can exchange at its force and speed limits (the master's handle may move faster
/// than the slave follows; docs/wire.md).
const ENERGY_POWER_MARGIN: f64 = 4.0;

const MAX_RECEIVED_PER_CYCLE: usize = 4096;

/// Cycles in a row without a fresh reading (the reading's time not moving on) after which
/// the driver counts as silent and the slave goes to its safe stop (the safety monitor's).
pub use crate::safety::DRIVER_STALE_CYCLES;

/// The safety layers a configuration asks for: no limit above the arm's rating (whatever
/// the override), and without `--unsafe-test-override` no gain beyond the arm's stable
/// range and no safety layer (passivity, the spindle-stall stop, the monitor) off.
fn check_safety(
    p: &TeleopParams,
    cp: &crate::controller::ControllerParams,
) -> Result<(), TeleopError> {
    let r = &p.safety.ratings;
    for (field, value, rating) in [
        ("force_limit_n", cp.force_limit_n, r.force_limit_n),
        (
            "max_speed_mm_per_s",
            cp.max_speed_mm_per_s,
            r.max_speed_mm_per_s,
        ),
    ] {
        if value.is_nan() || value > rating {
            return Err(TeleopError::AboveRating {
                field,
                value,
                rating,
            });
        }
    }
    if p.safety.unsafe_test_override {
        return Ok(());
    }
    for (field, value, max, rating) in [
        ("kp", cp.kp, r.kp_max, "kp_max"),
        ("ki_per_s", cp.ki_per_s, r.ki_max_per_s, "ki_max_per_s"),
    ] {
        if value.is_nan() || value > max {
            return Err(TeleopError::UnstableGain {
                field,
                value,
                max,
                rating,
            });
        }
    }
    let off = [
        (!p.passivity.enabled, "passivity.enabled = false"),
        (
            !cp.spindle_stall_safe_stop,
            "controller.spindle_stall_safe_stop = false",
        ),
        (!p.safety.monitor, "the safety monitor off"),
    ];
    for (is_off, layer) in off {
        if is_off {
            return Err(TeleopError::SafetyLayerOff { layer });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hand-over spring softens over a told round trip to K·T = 0.5 N·s/mm, never
    /// stiffens, and stays as set when not told; the set-point follows the spring in effect.
    #[test]
    fn a_told_round_trip_softens_the_hand_over_spring() {
        let mut c = ContactHandover::default();
        assert_eq!(c.effective_stiffness_n_per_mm(), 5.0);
        for (rtt_ms, k) in [(10.0, 5.0), (100.0, 5.0), (500.0, 1.0), (2000.0, 0.25)] {
            c.round_trip_ms = rtt_ms;
            assert!(
                (c.effective_stiffness_n_per_mm() - k).abs() < 1e-12,
                "{rtt_ms} ms"
            );
        }
        let k = c.effective_stiffness_n_per_mm();
        assert!((handover_setpoint_n(&c, k, 4.0) - (c.hold_min_n + 1.0)).abs() < 1e-12);
        assert!(c.validate_at("").is_ok());
        c.round_trip_ms = -1.0;
        assert!(c.validate_at("contact.").is_err());
        c.round_trip_ms = f64::NAN;
        assert!(c.validate_at("contact.").is_err());
    }
}
