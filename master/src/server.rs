//! `h4-master run`: the master as a real process. A 1 kHz loop on absolute deadlines steps
//! the master's endpoint ([`MasterTeleop`] over any [`HapticDevice`]: receive gate,
//! coupling with its passivity port and feedback-loss fade) on the process's
//! monotonic clock, and publishes one command per cycle on the link.
//!
//! When feedback stops the coupling fades the rendered force to zero; when it returns the
//! force fades back in (no jump). The loop allocates nothing, blocks on nothing and logs
//! nothing per cycle: statistics are fixed-size histograms, the status line is formatted a
//! few times a second on a terminal only, and the recording goes through a bounded queue to
//! a writer thread.

use h4_shared::vec3::norm3;
use std::time::Duration;

use h4_shared::wire::{Command, Feedback, SlaveState};
use h4_telemetry::process::stop_requested;
use h4_telemetry::progress::{Progress, ProgressConfig, Unit};
use h4_telemetry::rt::{LoopReport, RtLoop};
use h4_telemetry::sink::Sink;
use h4_transport::Link;
use h4_transport::gate::GateCounters;
use serde::{Deserialize, Serialize};

use crate::device::HapticDevice;
use crate::teleop::{MasterTeleop, MasterTeleopError};

/// How the master loop runs.
#[derive(Clone, Debug)]
pub struct MasterRunOptions {
    /// Arm id: service names, key expressions and every message carry it.
    pub arm_id: u16,
    /// Loop period, ns (1 kHz = 1 000 000).
    pub period_ns: u64,
    /// How long before each deadline the loop stops sleeping and spins, ns.
    pub spin_ns: u64,
    /// Real-time settings (SCHED_FIFO, locked memory; `--realtime`): default off.
    pub realtime: h4_telemetry::rt::RealtimePlan,
    /// Progress on stderr (waiting for the slave, then the loop): default off.
    pub progress: h4_telemetry::progress::ProgressConfig,
    /// Stop by itself after this long, s (None: until SIGINT/SIGTERM).
    pub duration_s: Option<f64>,
    /// Wait this long for the slave's first feedback before starting the operator's script,
    /// s (0: start at once).
    pub wait_for_slave_s: f64,
    /// After publishing its command, wait (blocking on the link, until shortly before the
    /// next deadline) for the slave's feedback that echoes it and take it when it arrives
    /// (default on): with a phase-locked slave the coupling then has the answer to its last
    /// command in every cycle, and the round trip is measured when the answer arrives.
    pub await_feedback: bool,
}

impl Default for MasterRunOptions {
    fn default() -> Self {
        MasterRunOptions {
            arm_id: 0,
            period_ns: 1_000_000,
            spin_ns: 200_000,
            realtime: h4_telemetry::rt::RealtimePlan::off(),
            progress: h4_telemetry::progress::ProgressConfig::off(),
            duration_s: None,
            wait_for_slave_s: 10.0,
            await_feedback: true,
        }
    }
}

/// What a master run reports when it stops.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct MasterRunSummary {
    /// Cycles, deadline misses, lateness, CPU and run time (from the end of the wait for the
    /// slave) of the loop (fields flattened into this summary).
    #[serde(flatten)]
    pub run: LoopReport,
    /// Round trips measured, count: every feedback message the gate accepted that echoes a
    /// command, its age at reception (now − the echoed send time, master clock; includes
    /// the phase of both loops). The definition of `crate::teleop::RoundTrip`, the same as
    /// the simulation's `rtt_mean_ms`.
    pub round_trip_samples: u64,
    /// Round trip p50, µs.
    pub round_trip_p50_us: f64,
    /// Round trip p99, µs.
    pub round_trip_p99_us: f64,
    /// Round trip p99.9, µs.
    pub round_trip_p999_us: f64,
    /// Largest round trip, µs.
    pub round_trip_max_us: f64,
    /// Cycles whose command the slave's feedback echoed before the master's next cycle (the
    /// slave answered within the master's period: `MasterRunOptions::await_feedback` with a
    /// phase-locked slave).
    #[serde(default)]
    pub feedback_in_period_cycles: u64,
    /// Feedback messages received from the link (before the gate).
    pub feedback_received: u64,
    /// Feedback messages rejected for any reason but `stale` (duplicates and reordered
    /// messages): undecodable, wrong version, wrong arm, reserved bits, length mismatch,
    /// wild sequence number, wrong session, implausible energy. They never reach the coupling.
    pub feedback_invalid: u64,
    /// The master's receive gate: feedback accepted, rejected by reason, pairings with a
    /// slave session (docs/processes.md).
    pub gate: GateCounters,
    /// Link errors while receiving or publishing.
    pub link_errors: u64,
    /// Cycles the haptic device had stopped answering (no fresh reading for 2 cycles:
    /// `h4_master::teleop::DEVICE_STALE_CYCLES`); the rendered force fades out through them.
    #[serde(default)]
    pub device_stale_cycles: u64,
    /// A ROS 2 device (`--device crtk`): samples refused on its topics, by reason
    /// (truncated CDR, wrong type on the key or payload, NaN/infinite values, a second
    /// publisher, a bad attachment; docs/ros2.md). All zero for other devices.
    #[serde(default)]
    pub ros2_rejected: h4_transport::ros2::subscriber::Ros2Rejected,
    /// A ROS 2 device: poses, velocities and button messages accepted, times it fell
    /// silent (no fresh pose within `--device-timeout-ms`), poses clamped into the mapped
    /// workspace. None for other devices.
    #[serde(default)]
    pub ros2_device: Option<h4_transport::ros2::device::DeviceReport>,
    /// Largest force rendered to the operator, N.
    pub max_rendered_force_n: f64,
    /// Largest change of the rendered force from one cycle to the next, N.
    pub max_rendered_force_step_n: f64,
    /// [`Self::max_rendered_force_step_n`] between cycles that ran on time, one period apart,
    /// N: a cycle after a missed deadline (the host stalled the loop) renders after the handle
    /// moved for several periods under the held force, whose step is the stall's, not the
    /// coupling's.
    pub max_rendered_force_step_outside_stalls_n: f64,
    /// Rendered force in the last cycle, N.
    pub final_rendered_force_n: f64,
    /// Times the feedback stopped and the rendered force started fading out.
    pub feedback_losses: u64,
    /// Times feedback returned after a loss and the force faded back in.
    pub feedback_restored: u64,
    /// Times the rendered force reached zero fade after a loss.
    pub faded_out: u64,
    /// Largest force of the slave's (the link force, scaled) rendered while faded out
    /// completely (should be 0), N. (A slave replaced within the feedback timeout: the old
    /// one's last force fading out over `coupling.fade_ms` beside the link is not counted.)
    pub max_force_while_faded_out_n: f64,
    /// Largest force rendered while faded out completely, N: only the local brake's damping
    /// (`coupling.brake_on_loss`), against the handle's motion.
    pub max_brake_force_while_faded_out_n: f64,
    /// Fade factor of the rendered force in the last cycle (1 = full, 0 = faded out).
    pub final_fade: f64,
    /// Cycles in which the slave reported its safe state.
    pub slave_safe_state_cycles: u64,
    /// Cycles in contact (slave's measured force above 1 N, feedback fresh).
    pub contact_cycles: u64,
    /// Force transparency over contact cycles: Σ|F_rendered / scale.force − F_slave| over
    /// Σ|F_slave|, %.
    pub force_transparency_err_pct: f64,
    /// Largest force the slave measured, as reported in its feedback, N.
    pub max_slave_force_n: f64,
    /// Lowest value of the master's passivity observer, J (below zero: the link generated
    /// energy at this port).
    #[serde(default)]
    pub energy_min_j: f64,
    /// Recording samples dropped because the writer fell behind.
    pub recording_dropped: u64,
    /// Time spent waiting for the slave's first feedback, s.
    pub waited_for_slave_s: f64,
    /// Feedback messages the slave sent that never arrived (gaps in its sequence numbers).
    #[serde(default)]
    pub feedback_lost: u64,
    /// `feedback_lost` as % of what the slave sent.
    #[serde(default)]
    pub feedback_loss_pct: f64,
    /// Cycles with the link down (no feedback for longer than the fade: nothing rendered).
    #[serde(default)]
    pub link_down_cycles: u64,
    /// The link's state in the last cycle: `waiting`, `up`, `fading` or `down`.
    #[serde(default)]
    pub link_state: crate::link_stats::LinkState,
    /// What the loop got of `--realtime`: SCHED_FIFO priority, locked memory, refusals.
    pub realtime: h4_telemetry::rt::RealtimeStatus,
}

/// Why the master could not run.
#[derive(Debug, thiserror::Error)]
pub enum MasterRunError {
    /// The device could not be built (the simulated one: the session file's operator
    /// script or master arm).
    #[error("{0}")]
    Device(String),
    /// The master's endpoint could not be built.
    #[error("{0}")]
    Master(#[from] MasterTeleopError),
    /// No feedback from a slave within the wait.
    #[error(
        "no feedback from a slave within {0} s: is `h4-slave run` running with the same transport, arm id and prefix/endpoints?"
    )]
    NoSlave(f64),
    /// The recording could not be written, or the live view could not start.
    #[error("{0}")]
    Outputs(String),
    /// `--realtime enforce` and a setting was not permitted.
    #[error("--realtime enforce: {0}")]
    Realtime(#[from] h4_telemetry::rt::RtError),
}

/// One master cycle as recorded (topic `/master/cycle`, schema `h4.MasterProcessCycle`).
#[derive(Clone, Copy, Debug, Serialize, schemars::JsonSchema)]
pub struct CycleRecord {
    /// The loop's clock, ns since the loop started.
    pub time_ns: u64,
    /// How late the loop woke for this cycle, µs.
    pub lateness_us: f64,
    /// Handle pose [x, y, z, theta], mm, rad.
    pub pose: [f64; 4],
    /// The operator's hand on the handle [Fx, Fy, Fz, My], N, N·mm, when the device knows
    /// it (the simulated operator; null for a real device: [`HapticDevice::hand_wrench`]).
    pub hand_wrench: Option<[f64; 4]>,
    /// Wrench applied by the device [Fx, Fy, Fz, My], N, N·mm.
    pub rendered_wrench: [f64; 4],
    /// Fade factor of the rendered force (1 full, 0 faded out).
    pub fade: f64,
    /// The slave's target sent this cycle [x, y, z, theta], mm, rad.
    pub slave_target: [f64; 4],
    /// The slave's measured force in the newest valid feedback, N.
    pub slave_force_n: [f64; 3],
    /// The slave's state in the newest valid feedback (`SlaveState` code).
    pub slave_state: u8,
    /// The newest round trip (`teleop::RoundTrip`: now − the send time of the command the
    /// newest echoing feedback echoed), µs; null (so not a required field) until a feedback
    /// message has echoed a command.
    pub round_trip_us: Option<f64>,
    /// The master port's passivity observer, J.
    pub energy_observed_j: f64,
    /// Feedback messages the slave sent that the master did not accept, so far (lost on the
    /// link or rejected by the gate; from the slave's sequence numbers, `link_stats`).
    pub feedback_lost: u64,
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1e3
}

/// Runs the master until stopped (SIGINT/SIGTERM or the duration), on `link`: a real-time
/// shell (pacer, clock, statistics, status line, signals) around the master's endpoint
/// `side` over any [`HapticDevice`]. Every cycle's record goes to `sink` (the recording and
/// the live view: `h4_telemetry::sink::Outputs` from the command line). Calls
/// `at_loop_end` as soon as the loop has stopped (before the summary and the recording are
/// finished): `loopback` stops the slave there, before its watchdog would notice the
/// silence.
pub fn run_then<D, S, L>(
    side: &mut MasterTeleop<D>,
    mut sink: S,
    opts: &MasterRunOptions,
    mut link: L,
    at_loop_end: impl FnOnce(),
) -> Result<MasterRunSummary, MasterRunError>
where
    D: HapticDevice,
    S: Sink<CycleRecord>,
    L: Link<Command, Feedback>,
{
    let mut realtime = opts.realtime.prepare()?;
    let mut s = MasterRunSummary {
        waited_for_slave_s: wait_for_slave(side, &mut link, opts)?,
        ..MasterRunSummary::default()
    };
    let period_ns = opts.period_ns.max(1);
    let dt_s = period_ns as f64 * 1e-9;
    let progress = loop_progress(&opts.progress, opts.duration_s, period_ns);
    opts.realtime.enter(&mut realtime)?;
    s.realtime = realtime;
    let mut rt =
        RtLoop::new(period_ns, opts.spin_ns, opts.duration_s).with_progress(progress.handle());
    let mut stats = RenderStats::new(side.coupling().params().scale.force);
    let mut link_stats = crate::link_stats::LossMeter::new();
    rt.run(|cx| {
        let now = cx.now_ns;
        side.stalled(now, period_ns, cx.tick.missed);
        let m = side.step(&mut link, now, dt_s);
        side.device_mut().advance(period_ns);
        s.energy_min_j = s.energy_min_j.min(m.step.observed_j);
        let fade = m.step.fade;
        let force = stats.rendered(
            &mut s,
            &m.rendered_wrench,
            &m.step.link_force_n,
            fade,
            cx.tick.missed,
        );
        let (slave_force, slave_state) = stats.slave(&mut s, side.latest_feedback());
        link_stats.cycle(side.latest_feedback(), side.gate_counters().accepted, fade);
        stats.transparency(&m.rendered_wrench, &slave_force, fade, &mut s);
        let record = CycleRecord {
            time_ns: now,
            lateness_us: us(cx.tick.lateness_ns),
            pose: m.handle.pose,
            hand_wrench: side.device().hand_wrench(),
            rendered_wrench: m.rendered_wrench,
            fade,
            slave_target: m.step.slave_target,
            slave_force_n: slave_force,
            slave_state,
            round_trip_us: Some(m.round_trip_us).filter(|r| r.is_finite()),
            energy_observed_j: m.step.observed_j,
            feedback_lost: {
                let (sent, arrived) = link_stats.totals();
                sent.saturating_sub(arrived)
            },
        };
        sink.record(cx.unix_ns, record, None);
        sink.show(cx.unix_ns, record, None);
        if let Some(line) = &mut cx.status {
            use std::fmt::Write;
            let _ = write!(
                line.text,
                "master arm {} | {:>6} cycles | late p99 {:>6.1} us | misses {} | link {} rtt {:>7.1} ms (p99 {:>7.1}) loss {:>4.1} % | F {:>6.2} N | fade {:.2} | slave {}",
                opts.arm_id,
                cx.cycles,
                line.lateness_p99_us,
                line.misses,
                link_stats.state().word(),
                us(side.round_trip().last_ns()) / 1e3,
                us(side.round_trip().histogram().quantile(0.99)) / 1e3,
                link_stats.window_loss_pct(),
                force,
                fade,
                state_name(slave_state),
            );
        }
        s.final_rendered_force_n = force;
        s.final_fade = fade;
        if opts.await_feedback {
            side.await_feedback(&mut link, cx.idle_until, || cx.clock_ns());
        }
        Ok::<(), MasterRunError>(())
    })?;
    at_loop_end();
    progress.finish();
    let r = side.round_trip().histogram();
    s.round_trip_samples = r.count();
    s.round_trip_p50_us = us(r.quantile(0.5));
    s.round_trip_p99_us = us(r.quantile(0.99));
    s.round_trip_p999_us = us(r.quantile(0.999));
    s.round_trip_max_us = us(r.max());
    let gate = side.gate_counters();
    s.feedback_received =
        side.counters().feedback_received + side.gate().link_decode_rejects().total();
    s.feedback_invalid = gate.rejected() - gate.stale;
    s.gate = *gate;
    s.link_errors = side.counters().link_errors;
    s.device_stale_cycles = side.counters().device_stale_cycles;
    s.feedback_in_period_cycles = side.counters().feedback_in_period_cycles;
    s.force_transparency_err_pct = stats.transparency_err_pct();
    let (sent, arrived) = link_stats.totals();
    s.feedback_lost = sent.saturating_sub(arrived);
    s.feedback_loss_pct = link_stats.loss_pct();
    s.link_down_cycles = link_stats.down_cycles();
    s.link_state = link_stats.state();
    s.run = rt.report();
    s.recording_dropped = sink.dropped();
    sink.finish().map_err(MasterRunError::Outputs)?;
    Ok(s)
}

/// Waits for the slave's first valid feedback (at most `opts.wait_for_slave_s`; 0: not at
/// all, or until a stop request); returns how long it waited, s. The feedback goes through
/// the endpoint's gate (at time 0, before the loop's clock starts).
fn wait_for_slave<D: HapticDevice, L: Link<Command, Feedback>>(
    side: &mut MasterTeleop<D>,
    link: &mut L,
    opts: &MasterRunOptions,
) -> Result<f64, MasterRunError> {
    let wait = std::time::Instant::now();
    if opts.wait_for_slave_s > 0.0 {
        // Said at once and every second (at most) while it lasts: how long, of how long.
        let mut cfg = opts.progress.clone();
        cfg.label = format!("{}: waiting for a slave (arm {})", cfg.label, opts.arm_id);
        cfg.plain_interval_s = cfg.plain_interval_s.min(1.0);
        let progress = Progress::start(
            &cfg,
            Unit::Seconds {
                per_step_s: 1e-3,
                what: "",
            },
            Some((opts.wait_for_slave_s * 1e3).round() as u64),
        );
        let handle = progress.handle();
        loop {
            if stop_requested() || side.poll_peer(link, 0) {
                break;
            }
            let waited_s = wait.elapsed().as_secs_f64();
            handle.set((waited_s * 1e3) as u64);
            if waited_s > opts.wait_for_slave_s {
                return Err(MasterRunError::NoSlave(opts.wait_for_slave_s));
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    Ok(wait.elapsed().as_secs_f64())
}

/// The loop's progress: seconds run (of `--duration-s`, if any), with the status text.
fn loop_progress(cfg: &ProgressConfig, duration_s: Option<f64>, period_ns: u64) -> Progress {
    let per_step_s = period_ns as f64 * 1e-9;
    Progress::start(
        cfg,
        Unit::Seconds {
            per_step_s,
            what: "",
        },
        duration_s.map(|d| (d / per_step_s).round() as u64),
    )
}

/// The master loop's running statistics of the rendered force, the feedback-loss fade and
/// the force transparency (booked into the summary cycle by cycle).
struct RenderStats {
    force_scale: f64,
    prev_fade: f64,
    fading_out: bool,
    prev_force_n: f64,
    transparency_abs_n: f64,
    transparency_ref_n: f64,
}

impl RenderStats {
    fn new(force_scale: f64) -> Self {
        RenderStats {
            force_scale,
            prev_fade: 0.0,
            fading_out: false,
            prev_force_n: 0.0,
            transparency_abs_n: 0.0,
            transparency_ref_n: 0.0,
        }
    }

    /// Books the rendered wrench, the slave's part of it (`link_force_n`) and the fade of one
    /// cycle that came `missed` deadlines late; returns the rendered force, N.
    fn rendered(
        &mut self,
        s: &mut MasterRunSummary,
        rendered: &[f64; 4],
        link_force_n: &[f64; 3],
        fade: f64,
        missed: u64,
    ) -> f64 {
        let force = norm3(rendered);
        let step_n = (force - self.prev_force_n).abs();
        s.max_rendered_force_n = s.max_rendered_force_n.max(force);
        s.max_rendered_force_step_n = s.max_rendered_force_step_n.max(step_n);
        if missed == 0 {
            s.max_rendered_force_step_outside_stalls_n =
                s.max_rendered_force_step_outside_stalls_n.max(step_n);
        }
        self.prev_force_n = force;
        if fade < self.prev_fade && !self.fading_out {
            self.fading_out = true;
            s.feedback_losses += 1;
        } else if fade > self.prev_fade && self.fading_out {
            self.fading_out = false;
            s.feedback_restored += 1;
        } else if fade >= 1.0 {
            self.fading_out = false;
        }
        if fade <= 0.0 && s.feedback_losses > 0 {
            if self.prev_fade > 0.0 {
                s.faded_out += 1;
            }
            s.max_force_while_faded_out_n = s.max_force_while_faded_out_n.max(norm3(link_force_n));
            s.max_brake_force_while_faded_out_n = s.max_brake_force_while_faded_out_n.max(force);
        }
        self.prev_fade = fade;
        force
    }

    /// Books the newest valid feedback; returns the slave's measured force, N, and state code.
    fn slave(&mut self, s: &mut MasterRunSummary, latest: Option<&Feedback>) -> ([f64; 3], u8) {
        let mut slave_force = [0.0; 3];
        let mut slave_state = SlaveState::Idle as u8;
        if let Some(fb) = latest {
            slave_force = [
                fb.wrench_measured[0],
                fb.wrench_measured[1],
                fb.wrench_measured[2],
            ];
            slave_state = fb.state;
            if fb.state == SlaveState::SafeStop as u8 {
                s.slave_safe_state_cycles += 1;
            }
        }
        s.max_slave_force_n = s.max_slave_force_n.max(norm3(&slave_force));
        (slave_force, slave_state)
    }

    /// Books one cycle's force transparency: in contact (slave force above 1 N) with full
    /// fade, |F_rendered / scale.force − F_slave| against |F_slave|.
    fn transparency(
        &mut self,
        rendered: &[f64; 4],
        slave_force: &[f64; 3],
        fade: f64,
        s: &mut MasterRunSummary,
    ) {
        let fs = norm3(slave_force);
        if fs > 1.0 && fade >= 1.0 {
            s.contact_cycles += 1;
            let mut d = [0.0; 3];
            for (i, di) in d.iter_mut().enumerate() {
                *di = rendered[i] / self.force_scale - slave_force[i];
            }
            self.transparency_abs_n += norm3(&d);
            self.transparency_ref_n += fs;
        }
    }

    /// Σ|F_rendered / scale.force − F_slave| over Σ|F_slave|, %, or 0 without contact.
    fn transparency_err_pct(&self) -> f64 {
        if self.transparency_ref_n > 0.0 {
            100.0 * self.transparency_abs_n / self.transparency_ref_n
        } else {
            0.0
        }
    }
}

/// A slave state code as a word.
pub fn state_name(code: u8) -> &'static str {
    match code {
        c if c == SlaveState::Idle as u8 => "idle",
        c if c == SlaveState::Active as u8 => "active",
        c if c == SlaveState::SafeStop as u8 => "safe-stop",
        _ => "?",
    }
}
