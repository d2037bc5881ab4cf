//! `h4-slave run`: the slave as a real process. A 1 kHz loop reads the link, passes every
//! command through the receive gate, runs the controller on the (simulated) arm and
//! publishes feedback. The loop is phase-locked to the master: each cycle runs when the
//! master's command arrives (the link wakes it), so the feedback leaves within the master's
//! period; without a command for 1.5 periods it runs on its own absolute deadlines
//! ([`h4_telemetry::rt::Pacer::wait_or_wake`]). No valid command for the watchdog period (20 ms)
//! puts the arm in its safe state (force set-point ramped to zero, retract along the contact
//! normal, hold); a valid command after that re-pairs with no jump.
//!
//! The loop allocates nothing, blocks on nothing and logs nothing per cycle: statistics are
//! fixed-size, the status line is formatted only a few times a second on a terminal, and the
//! recording is handed to a writer thread through a bounded queue (full queue = counted drop).

use h4_shared::vec3::norm3;

use h4_shared::passivity::PassivityParams;
use h4_shared::wire::{Command, Feedback, SlaveState};
use h4_telemetry::rt::{LoopReport, RtLoop};
use h4_telemetry::sink::Sink;
use h4_transport::Link;
use h4_transport::gate::GateCounters;
use serde::{Deserialize, Serialize};

use crate::arm::ArmDriver;
use crate::controller::Status;
use crate::round_trip::RoundTripEstimator;
use crate::teleop::{SlaveTeleop, TeleopCounters, TeleopCycle, TeleopError};

/// What a driver can tell beyond its sensors, for the recording and the summary only:
/// nothing here reaches the controller. The simulated arm knows the true contact force and
/// the cut (`h4_slave_sim::server::SimDiagnostics`); a real arm knows neither
/// ([`NoDiagnostics`]: the measured force stands in for the true one). Called from the
/// 1 kHz loop: allocates nothing, blocks on nothing.
pub trait Diagnostics<A: ArmDriver> {
    /// The second recorded topic's sample (`()` without one).
    type Sample: Copy + Send + 'static;
    /// The true contact force's magnitude now, N (None: not known).
    fn true_force_n(&self, teleop: &SlaveTeleop<A>) -> Option<f64>;
    /// This cycle's sample of the second topic (None: no sample this cycle).
    fn sample(&self, teleop: &SlaveTeleop<A>) -> Option<Self::Sample>;
    /// Every cycle of the run (not the shutdown's), after the endpoint's step.
    fn observe(&mut self, _teleop: &SlaveTeleop<A>, _cycle: &TeleopCycle) {}
}

/// A driver with nothing to tell beyond its sensors (a real arm).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoDiagnostics;

impl<A: ArmDriver> Diagnostics<A> for NoDiagnostics {
    type Sample = ();
    fn true_force_n(&self, _: &SlaveTeleop<A>) -> Option<f64> {
        None
    }
    fn sample(&self, _: &SlaveTeleop<A>) -> Option<()> {
        None
    }
}

/// How the loop runs.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Arm id: service names, key expressions and every message carry it.
    pub arm_id: u16,
    /// Loop period, ns (1 kHz = 1 000 000).
    pub period_ns: u64,
    /// How long before each deadline the loop stops sleeping and spins, ns.
    pub spin_ns: u64,
    /// Phase-locked (default): each cycle runs when the master's command arrives (the link
    /// wakes the loop: [`Link::wait_message`]), so the feedback leaves within the master's
    /// period; without a command within `1.5 ×` its period the loop runs on its own clock
    /// (the watchdog and safe stop as ever). Off, or on a link that cannot wake the loop (an
    /// impaired or playout link): the loop runs on its own clock only.
    pub phase_lock: bool,
    /// No valid command for this long → safe state, ms.
    pub watchdog_ms: f64,
    /// After this much silence a command whose sequence number went backwards is taken as a
    /// restarted master, ms.
    pub restart_silence_ms: f64,
    /// The slave's passivity port.
    pub passivity: PassivityParams,
    /// The contact hand-over (a session's `[slave.contact]`).
    pub contact: crate::teleop::ContactHandover,
    /// Real-time settings (SCHED_FIFO, locked memory; `--realtime`): default off.
    pub realtime: h4_telemetry::rt::RealtimePlan,
    /// Progress on stderr: default off.
    pub progress: h4_telemetry::progress::ProgressConfig,
    /// Stop by itself after this long, s (None: until SIGINT/SIGTERM).
    pub duration_s: Option<f64>,
    /// After a stop request, keep cycling (commands ignored) for at most this long until the
    /// arm is in its safe state with the force released, s.
    pub shutdown_limit_s: f64,
    /// The arm's ratings, the safety monitor and `--unsafe-test-override`.
    pub safety: crate::teleop::SafetyParams,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            arm_id: 0,
            period_ns: 1_000_000,
            spin_ns: 200_000,
            phase_lock: true,
            watchdog_ms: 20.0,
            restart_silence_ms: 100.0,
            passivity: PassivityParams::default(),
            contact: crate::teleop::ContactHandover::default(),
            realtime: h4_telemetry::rt::RealtimePlan::off(),
            progress: h4_telemetry::progress::ProgressConfig::off(),
            duration_s: None,
            shutdown_limit_s: 2.0,
            safety: crate::teleop::SafetyParams::default(),
        }
    }
}

impl RunOptions {
    /// The endpoint's parameters these options give (arm id, watchdog, restart silence,
    /// passivity, contact hand-over; the rest the endpoint's defaults).
    pub fn teleop_params(&self) -> crate::teleop::TeleopParams {
        crate::teleop::TeleopParams {
            arm_id: self.arm_id,
            watchdog_ms: self.watchdog_ms,
            restart_silence_ms: self.restart_silence_ms,
            passivity: self.passivity,
            contact: self.contact,
            safety: self.safety,
            ..crate::teleop::TeleopParams::default()
        }
    }
}

/// How many safe-stop start times a slave run's summary keeps.
pub const SAFE_STOP_TIMES_MAX: usize = 64;

/// What a slave run reports when it stops.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct SlaveRunSummary {
    /// Cycles, deadline misses, lateness, CPU and run time of the loop (fields flattened
    /// into this summary).
    #[serde(flatten)]
    pub run: LoopReport,
    /// What the receive gate accepted and rejected.
    pub gate: GateCounters,
    /// Commands the controller rejected (workspace, limits): never passed to the actuators.
    pub commands_rejected_by_controller: u64,
    /// Link errors while receiving or publishing.
    pub link_errors: u64,
    /// Times the watchdog (or a spindle stall) put the arm into its safe state.
    pub safe_stops: u64,
    /// Of those, the safe stops a spindle stall started (a cutting arm).
    pub spindle_stall_stops: u64,
    /// Of those, the safe stops a driver that stopped answering started (no fresh reading
    /// for 2 cycles: `h4_slave::teleop::DRIVER_STALE_CYCLES`).
    pub driver_stale_stops: u64,
    /// A ROS 2 arm (`--arm crtk`): samples refused on its topics, by reason (truncated CDR,
    /// wrong type on the key or payload, NaN/infinite values, a second publisher, a bad
    /// attachment; docs/ros2.md). All zero for other drivers.
    #[serde(default)]
    pub ros2_rejected: h4_transport::ros2::subscriber::Ros2Rejected,
    /// A ROS 2 arm: poses and wrenches accepted, times it went stale (no fresh pose or
    /// wrench within `--arm-timeout-ms`), poses it could not map, set-points not sent,
    /// commands sent. None for other drivers.
    #[serde(default)]
    pub ros2_arm: Option<h4_transport::ros2::arm::ArmReport>,
    /// Silence when the watchdog tripped, ms on the slave's clock (of the trip where the
    /// silence most exceeded the loop's own lateness).
    pub safe_stop_entry_silence_ms: f64,
    /// The loop's lateness in that cycle, ms: the part of the entry silence that is the host
    /// not running the slave's loop.
    pub safe_stop_entry_lateness_ms: f64,
    /// When the safe stops started (the first [`SAFE_STOP_TIMES_MAX`]), ns on the host's
    /// `CLOCK_MONOTONIC`: the clock of both processes' `deadline_miss_spans_ns`, so a trip can
    /// be matched against a stall of either loop.
    pub safe_stop_times_ns: Vec<u64>,
    /// Times a master was paired after a safe stop.
    pub repairs: u64,
    /// The safety monitor's trips by reason (each also one of `safe_stops`).
    pub safety_trips: crate::safety::SafetyTrips,
    /// The run had `--unsafe-test-override` (a safety layer may have been off).
    pub unsafe_test_override: bool,
    /// The safety monitor ran (off only with `--unsafe-test-override`).
    pub safety_monitor: bool,
    /// Largest true contact force, N: the driver's diagnostics' (the simulated arm's true
    /// force), or the measured force's magnitude when the driver has none (a real arm).
    pub max_force_n: f64,
    /// Lowest value of the slave's passivity observer, J (below zero: the link generated
    /// energy at this port).
    #[serde(default)]
    pub energy_min_j: f64,
    /// The controller's force limit, N.
    pub force_limit_n: f64,
    /// Largest measured (sensor) force magnitude, N.
    pub max_measured_force_n: f64,
    /// Cycles in contact force control (force-guided mode).
    pub contact_cycles: u64,
    /// Mean |F_n − F_d| over contact cycles, N.
    pub force_error_mean_n: f64,
    /// State when the run ended.
    pub final_state: String,
    /// Recording samples dropped because the writer fell behind.
    pub recording_dropped: u64,
    /// The stop: the loop kept running with commands ignored until the arm was in its safe
    /// state with the force released (or the time limit); what it reached.
    pub shutdown: ShutdownReport,
    /// What the loop got of `--realtime`: SCHED_FIFO priority, locked memory, refusals.
    pub realtime: h4_telemetry::rt::RealtimeStatus,
    /// The round trip the slave measured from the commands' echo of its feedback (protocol 3,
    /// docs/wire.md "The command's echo"), over the run: median, ms (null: no echo taken).
    pub rtt_measured_p50_ms: Option<f64>,
    /// Its 99th percentile, ms (null: no echo taken).
    pub rtt_measured_p99_ms: Option<f64>,
    /// Its p95 − p50, ms (null: no echo taken).
    pub rtt_jitter_ms: Option<f64>,
    /// Echoes taken as round-trip samples (one per command that brought a new echo).
    pub round_trip_samples: u64,
    /// Active cycles that used the told round trip (`contact.round_trip_ms`) because none was
    /// measured yet or measuring is off.
    pub round_trip_fallback_cycles: u64,
    /// Echoes refused: of a feedback this slave cannot have sent (an `echo_seq` above its
    /// own, a send time after its clock's now). The command itself is judged as usual.
    pub round_trip_echoes_refused: u64,
}

impl SlaveRunSummary {
    /// Books the endpoint's counters and its receive gate's.
    fn book_endpoint(&mut self, k: &TeleopCounters, gate: &GateCounters) {
        self.commands_rejected_by_controller = k.commands_rejected_by_controller;
        self.link_errors = k.link_errors;
        self.safe_stops = k.safe_stops;
        self.spindle_stall_stops = k.spindle_stall_stops;
        self.driver_stale_stops = k.driver_stale_stops;
        self.repairs = k.repairs;
        self.safety_trips = k.safety_trips;
        self.gate = *gate;
    }

    /// Books the round trip the slave measured (protocol 3's echo) and its counters.
    fn book_round_trip(&mut self, rtt: &RoundTripEstimator, k: &TeleopCounters) {
        let (p50, p99, jitter) = rtt.summary_ms();
        let some = |v: f64| v.is_finite().then_some(v);
        self.rtt_measured_p50_ms = some(p50);
        self.rtt_measured_p99_ms = some(p99);
        self.rtt_jitter_ms = some(jitter);
        self.round_trip_samples = rtt.samples();
        self.round_trip_fallback_cycles = k.round_trip_fallback_cycles;
        self.round_trip_echoes_refused = k.round_trip_echoes_refused;
    }
}

/// How the slave left: after a stop request (signal, parent gone, duration) the loop ignores
/// commands, its watchdog trips, and the arm goes to its safe state (set-point ramped to zero,
/// retract, hold) before the process exits.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct ShutdownReport {
    /// Cycles run after the stop request.
    pub cycles: u64,
    /// The endpoint's state at exit (`SafeStop`, or `Idle` if no master ever commanded).
    pub final_state: String,
    /// True contact force at exit, N (the measured force without diagnostics).
    pub final_force_n: f64,
    /// The arm reached its safe state (not `Active`) with the true force below
    /// [`SHUTDOWN_RELEASED_N`] within the limit.
    pub safe: bool,
}

/// The force below which the shutdown counts the arm as released, N.
pub const SHUTDOWN_RELEASED_N: f64 = 0.5;
/// How long the arm holds in its safe state before the process exits, cycles.
const SHUTDOWN_HOLD_CYCLES: u64 = 50;

/// A link that still publishes but ignores (drains and drops) every received message: the
/// slave's view of the world after a stop request.
struct Deaf<'a, L>(&'a mut L);

impl<L: Link<Feedback, Command>> Link<Feedback, Command> for Deaf<'_, L> {
    fn publish(&mut self, msg: &Feedback) -> Result<(), h4_transport::LinkError> {
        self.0.publish(msg)
    }
    fn try_recv(&mut self) -> Result<Option<Command>, h4_transport::LinkError> {
        while self.0.try_recv()?.is_some() {}
        Ok(None)
    }
}

/// Why the slave could not run.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    /// The configuration is unusable.
    #[error("configuration: {0}")]
    Config(#[from] h4_shared::config::ConfigError),
    /// The recording could not be written.
    #[error("recording: {0}")]
    Recording(String),
    /// The teleoperation endpoint's settings are unusable.
    #[error("{0}")]
    Teleop(#[from] TeleopError),
    /// `--realtime enforce` and a setting was not permitted.
    #[error("--realtime enforce: {0}")]
    Realtime(#[from] h4_telemetry::rt::RtError),
}

/// One cycle of the slave process as recorded (topic `/slave/cycle`, schema
/// `h4.SlaveProcessCycle`; the session simulation records another shape on the same topic,
/// `h4.SlaveCycle`).
#[derive(Clone, Copy, Debug, Serialize, schemars::JsonSchema)]
pub struct CycleRecord {
    /// The loop's clock, ns since the process's loop started.
    pub time_ns: u64,
    /// The endpoint's state (`SlaveState` code: 0 idle, 1 active, 2 safe stop).
    pub state: u8,
    /// The controller's status code.
    pub status: u8,
    /// How late the loop woke for this cycle, µs.
    pub lateness_us: f64,
    /// Measured force along the contact normal, N.
    pub force_measured_n: f64,
    /// Force set-point along the contact normal, N.
    pub force_desired_n: f64,
    /// True contact force magnitude, N (the driver's diagnostics: the simulated arm's true
    /// force; the measured force's magnitude without diagnostics).
    pub force_true_n: f64,
    /// Measured pose of the tool [x, y, z, theta], mm, rad.
    pub measured_pose: [f64; 4],
    /// Commanded pose of the tool [x, y, z, theta], mm, rad.
    pub commanded_pose: [f64; 4],
    /// Estimated contact normal (unit vector).
    pub contact_normal: [f64; 3],
    /// Sequence number of the command acted on.
    pub command_seq: u64,
    /// The slave port's passivity observer, J.
    pub energy_observed_j: f64,
    /// The arm's reading this cycle: actuator positions from the encoders, mm (what a
    /// replay driver plays back).
    pub actuators_mm: [f64; 4],
    /// The arm's reading this cycle: the sensor's wrench `[Fx_n, Fy_n, Fz_n, My_n_mm]`, base
    /// frame, as the driver reported it (bias not removed).
    pub wrench_sensor: [f64; 4],
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1e3
}

/// Runs the slave until stopped (SIGINT/SIGTERM or the duration), on `link`: a real-time
/// shell (pacer, clock, statistics, status line, signals) around the slave's teleoperation
/// endpoint [`SlaveTeleop`], the same per-cycle code the lockstep session simulation steps,
/// over any [`ArmDriver`]. Every cycle's record goes to `sink` (the recording and the live
/// view: `h4_telemetry::sink::Outputs` from the command line); what the driver knows beyond
/// its sensors comes from `diag`, for the record and the summary only.
pub fn run<A, D, S, L>(
    teleop: &mut SlaveTeleop<A>,
    diag: &mut D,
    mut sink: S,
    opts: &RunOptions,
    link: &mut L,
) -> Result<SlaveRunSummary, ServerError>
where
    A: ArmDriver,
    D: Diagnostics<A>,
    S: Sink<CycleRecord, D::Sample>,
    L: Link<Feedback, Command>,
{
    opts.passivity.validate_at("passivity.")?;
    opts.contact.validate_at("contact.")?;
    let period_ns = opts.period_ns.max(1);
    let dt_s = period_ns as f64 * 1e-9;

    let mut realtime = opts.realtime.prepare()?;
    let per_step_s = period_ns as f64 * 1e-9;
    let progress = h4_telemetry::progress::Progress::start(
        &opts.progress,
        h4_telemetry::progress::Unit::Seconds {
            per_step_s,
            what: "",
        },
        opts.duration_s.map(|d| (d / per_step_s).round() as u64),
    );
    opts.realtime.enter(&mut realtime)?;
    let mut rt =
        RtLoop::new(period_ns, opts.spin_ns, opts.duration_s).with_progress(progress.handle());
    let mut s = SlaveRunSummary {
        force_limit_n: teleop.controller().params().force_limit_n,
        unsafe_test_override: opts.safety.unsafe_test_override,
        safety_monitor: opts.safety.monitor,
        // Allocated whole before the loop: recording a trip allocates nothing.
        safe_stop_times_ns: Vec::with_capacity(SAFE_STOP_TIMES_MAX),
        realtime,
        ..SlaveRunSummary::default()
    };
    let mut error_sum = 0.0;
    let mut worst_excess_ms = f64::NEG_INFINITY;
    let mut state = SlaveState::Idle;
    let mut body = |cx: &mut h4_telemetry::rt::CycleCtx<'_>, link: &mut L| {
        let now = cx.now_ns;
        // A simulated arm keeps real time: through deadlines the loop missed (a stalled
        // host) its servos held the last command written, before this cycle reads it.
        teleop.arm_mut().advance(period_ns * cx.tick.missed);
        let c = teleop.step(link, now, dt_s);
        s.energy_min_j = s.energy_min_j.min(c.port.observed_j);
        state = c.state;
        if c.tripped {
            let silence_ms = teleop.silence_ns(now).unwrap_or(0) as f64 / 1e6;
            let lateness_ms = cx.tick.lateness_ns as f64 / 1e6;
            s.book_trip(silence_ms, lateness_ms, &mut worst_excess_ms);
        }
        teleop.arm_mut().advance(period_ns);

        let out = &c.out;
        let measured_n = norm3(&out.wrench_measured);
        let true_force_n = diag.true_force_n(teleop).unwrap_or(measured_n);
        s.max_force_n = s.max_force_n.max(true_force_n);
        s.max_measured_force_n = s.max_measured_force_n.max(measured_n);
        if out.status == Status::Contact {
            s.contact_cycles += 1;
            error_sum += (out.normal_force_n - out.setpoint_n).abs();
        }
        let record = CycleRecord::of(&c, cx, true_force_n);
        let sample = diag.sample(teleop);
        sink.record(cx.unix_ns, record, sample);
        sink.show(cx.unix_ns, record, sample);
        diag.observe(teleop, &c);
        if let Some(line) = &mut cx.status {
            use std::fmt::Write;
            let _ = write!(
                line.text,
                "slave arm {} | {:>6} cycles | late p99 {:>6.1} us | misses {} | {:?} {:?} | F {:>6.2} N | rejected {}",
                opts.arm_id,
                teleop.counters().cycles,
                line.lateness_p99_us,
                line.misses,
                c.state,
                out.status,
                measured_n,
                teleop.gate_counters().rejected(),
            );
        }
        Ok::<(), std::convert::Infallible>(())
    };
    let Ok(()) = if opts.phase_lock && link.can_wake() {
        // A failed wait is a cycle on the loop's own clock; the step's receive counts the
        // link's error.
        rt.run_phase_locked(
            link,
            |l, until| l.wait_message(until).unwrap_or(false),
            body,
        )
    } else {
        rt.run(|cx| body(cx, link))
    };
    let k = *teleop.counters();
    s.book_round_trip(teleop.round_trip(), &k);
    s.shutdown = shut_down(teleop, diag, link, &mut rt, &mut sink, opts);
    progress.finish();
    s.book_endpoint(&k, teleop.gate_counters());
    s.force_error_mean_n = if s.contact_cycles > 0 {
        error_sum / s.contact_cycles as f64
    } else {
        0.0
    };
    s.final_state = format!("{state:?}");
    s.run = rt.report();
    s.recording_dropped = sink.dropped();
    sink.finish().map_err(ServerError::Recording)?;
    Ok(s)
}

impl SlaveRunSummary {
    /// Books a watchdog trip now: its time (the first [`SAFE_STOP_TIMES_MAX`]), and its entry
    /// silence and the loop's lateness when the silence exceeds the lateness by more than
    /// every trip's before (`worst_excess_ms`): that trip is the one reported. Allocates
    /// nothing (the times' capacity is allocated before the loop).
    fn book_trip(&mut self, silence_ms: f64, lateness_ms: f64, worst_excess_ms: &mut f64) {
        if self.safe_stop_times_ns.len() < SAFE_STOP_TIMES_MAX {
            self.safe_stop_times_ns
                .push(h4_telemetry::rt::monotonic_ns());
        }
        if silence_ms - lateness_ms > *worst_excess_ms {
            *worst_excess_ms = silence_ms - lateness_ms;
            self.safe_stop_entry_silence_ms = silence_ms;
            self.safe_stop_entry_lateness_ms = lateness_ms;
        }
    }
}

/// After the stop request: commands ignored, the watchdog trips, the safe stop ramps the
/// force to zero and retracts; returns when the arm holds released (or at the limit).
fn shut_down<A, D, S, L>(
    teleop: &mut SlaveTeleop<A>,
    diag: &D,
    link: &mut L,
    rt: &mut RtLoop,
    sink: &mut S,
    opts: &RunOptions,
) -> ShutdownReport
where
    A: ArmDriver,
    D: Diagnostics<A>,
    S: Sink<CycleRecord, D::Sample>,
    L: Link<Feedback, Command>,
{
    let period_ns = opts.period_ns.max(1);
    let mut deaf = Deaf(link);
    let mut r = ShutdownReport::default();
    let mut held = 0;
    rt.run_after_stop(opts.shutdown_limit_s, |cx| {
        teleop.arm_mut().advance(period_ns * cx.tick.missed);
        let c = teleop.step(&mut deaf, cx.now_ns, period_ns as f64 * 1e-9);
        teleop.arm_mut().advance(period_ns);
        let force_n = diag
            .true_force_n(teleop)
            .unwrap_or_else(|| norm3(&c.out.wrench_measured));
        sink.record(
            cx.unix_ns,
            CycleRecord::of(&c, cx, force_n),
            diag.sample(teleop),
        );
        r.cycles += 1;
        r.final_force_n = force_n;
        r.safe = c.state != SlaveState::Active && force_n < SHUTDOWN_RELEASED_N;
        held = if r.safe { held + 1 } else { 0 };
        // Idle: never commanded, nothing to bring back.
        !(c.state == SlaveState::Idle && r.safe || held >= SHUTDOWN_HOLD_CYCLES)
    });
    r.final_state = format!("{:?}", teleop.state());
    r
}

impl CycleRecord {
    fn of(c: &TeleopCycle, cx: &h4_telemetry::rt::CycleCtx<'_>, force_true_n: f64) -> Self {
        let out = &c.out;
        CycleRecord {
            time_ns: cx.now_ns,
            state: c.state as u8,
            status: out.status.code(),
            lateness_us: us(cx.tick.lateness_ns),
            force_measured_n: out.normal_force_n,
            force_desired_n: out.setpoint_n,
            force_true_n,
            measured_pose: out.measured_pose,
            commanded_pose: out.commanded_pose,
            contact_normal: out.contact_normal,
            command_seq: c.command_seq,
            energy_observed_j: c.port.observed_j,
            actuators_mm: c.reading.actuators_mm,
            wrench_sensor: c.reading.wrench,
        }
    }
}
