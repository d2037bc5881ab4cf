//! [`Session`]: the master's and the slave's endpoints, an impaired in-process link in each
//! direction and both simulated arms, stepped in lockstep on the simulated clock.

use std::path::Path;
use std::time::Instant;

use h4_shared::clock::{Clock, SimClock};
use h4_shared::config::Validate;
use h4_shared::kinematics::Pose;
use h4_shared::rng::Rng;
use h4_shared::vec3::norm3;
use h4_shared::wire::{Command, Feedback, Mode};
use h4_slave::controller::Status;
use h4_slave::teleop::{SlaveTeleop, TeleopCycle, TeleopParams};
use h4_slave_sim::cut::CutTeleop;
use h4_slave_sim::plant::SimArm;
use h4_telemetry::recording::{Recorder, RecordingError};
use h4_transport::impair::Impaired;
use h4_transport::inproc::{self, InprocEnd};
use h4_transport::playout::Playout;

use super::SimMasterCycle;
use super::cutting::{CutEvaluator, CutSummary, RevolutionMean};
use super::detector::{Evaluator, RunFacts, Sample};
use super::record::Channels;
use super::timing::SlaveInbox;
use super::{CYCLE_NS, DT_S, HostConfig, SessionConfig, SessionError, StallSide, Summary};
use crate::hand::SimHandDevice;
use h4_master::device::HapticDevice;
use h4_master::teleop::MasterTeleop;

type MasterEnd = Impaired<InprocEnd<Command, Feedback>, SimClock, Command, Feedback>;
/// The slave's end: its feedback impaired on the way out, its commands through its playout
/// buffer on the way in, taken when `slave.timing` says.
type SlaveEnd = SlaveInbox<
    Playout<
        Impaired<InprocEnd<Feedback, Command>, SimClock, Feedback, Command>,
        SimClock,
        Feedback,
        Command,
    >,
>;

/// A session ready to run: both sides and the link.
pub struct Session {
    cfg: SessionConfig,
    clock: SimClock,
    /// The master's endpoint.
    pub master: MasterTeleop<SimHandDevice>,
    /// The slave side.
    pub slave: SlaveTeleop<SimArm>,
    master_end: MasterEnd,
    slave_end: SlaveEnd,
    stalls: HostStalls,
    /// The last cycle of each side (what a stalled loop's devices still hold).
    last: Option<(SimMasterCycle, TeleopCycle)>,
}

/// The schedule of `[host]`'s stalls on the simulated clock.
struct HostStalls {
    cfg: HostConfig,
    rng: Rng,
    next_start_ns: u64,
    until_ns: u64,
}

impl HostStalls {
    fn new(cfg: HostConfig, seed: u64) -> Self {
        let mut s = HostStalls {
            cfg,
            rng: Rng::fork(seed, cfg.seed ^ 0x5741_4c4c),
            next_start_ns: 0,
            until_ns: 0,
        };
        s.next_start_ns = s.interval_ns();
        s
    }

    fn interval_ns(&mut self) -> u64 {
        (self.cfg.stall_every_ms * self.rng.uniform_in(0.5, 1.5) * 1e6) as u64
    }

    /// Whether the master's and the slave's loops are frozen at `now_ns`.
    fn frozen(&mut self, now_ns: u64) -> (bool, bool) {
        if self.cfg.stall_ms <= 0.0 {
            return (false, false);
        }
        if now_ns >= self.next_start_ns {
            self.until_ns = self.next_start_ns + (self.cfg.stall_ms * 1e6) as u64;
            self.next_start_ns += self
                .interval_ns()
                .max(self.until_ns - self.next_start_ns + 1);
        }
        let on = now_ns < self.until_ns;
        match self.cfg.stalls {
            StallSide::Both => (on, on),
            StallSide::Master => (on, false),
            StallSide::Slave => (false, on),
        }
    }
}

impl Session {
    /// Builds a session from a validated configuration.
    pub fn new(cfg: &SessionConfig) -> Result<Self, SessionError> {
        cfg.validate()?;
        let script = cfg.operator.script()?;
        let clock = SimClock::new();
        let (m_end, s_end) = inproc::pair(1024);
        let mut rng = Rng::fork(cfg.seed, cfg.link.seed);
        let mut down = cfg.link;
        down.seed = rng.next_u64();
        let mut up = cfg.link;
        up.seed = rng.next_u64();
        let master_end = Impaired::new(m_end, clock.clone(), down, CYCLE_NS)?;
        let slave_end = SlaveInbox::new(
            Playout::new(
                Impaired::new(s_end, clock.clone(), up, CYCLE_NS)?,
                clock.clone(),
                cfg.slave.playout,
            ),
            cfg.slave.timing,
        );

        let (arm, ctrl) = cfg
            .slave_world()
            .build(Pose::from(cfg.environment.slave_start_pose()), cfg.seed)?;
        let slave = SlaveTeleop::new(
            TeleopParams {
                arm_id: 0,
                watchdog_ms: cfg.slave.command_timeout_ms,
                restart_silence_ms: 1000.0,
                passivity: cfg.passivity,
                speed_margin: 0.9,
                contact: cfg.slave.contact,
                safety: h4_slave::teleop::SafetyParams {
                    ratings: cfg.slave.arm.ratings,
                    monitor: cfg.slave.safety_monitor,
                    unsafe_test_override: cfg.unsafe_test_override,
                },
            },
            ctrl,
            arm,
            CYCLE_NS,
        )?;
        let master = MasterTeleop::new(
            &cfg.master_teleop(0),
            SimHandDevice::new(cfg.master, cfg.operator.hand, script)
                .map_err(SessionError::Master)?,
        );
        Ok(Session {
            cfg: cfg.clone(),
            clock,
            master,
            slave,
            master_end,
            slave_end,
            stalls: HostStalls::new(cfg.host, cfg.seed),
            last: None,
        })
    }

    /// One lockstep cycle: master step, slave step, physics of both arms, clock + 1 ms (the
    /// slave takes the master's command of this period or, `slave.timing = "own-clock"`, of
    /// the previous one: [`SlaveInbox`]). A loop frozen by a host stall (`[host]`) does not
    /// step: its device holds what it was last given, and the cycle returns that loop's last
    /// cycle.
    pub fn cycle(&mut self) -> Result<(SimMasterCycle, TeleopCycle), SessionError> {
        self.step_cycle()?;
        self.last
            .ok_or(SessionError::Link(h4_transport::LinkError::Closed))
    }

    /// [`Session::cycle`] without handing the cycle out: both sides' cycles are written in
    /// place into `self.last` (no copies of the two cycles' structs per cycle; the run loop
    /// reads them there).
    fn step_cycle(&mut self) -> Result<(), SessionError> {
        let now = self.clock.now_ns();
        let (master_frozen, slave_frozen) = self.stalls.frozen(now);
        match &mut self.last {
            Some((m, s)) => {
                if master_frozen {
                    // The hand is physics: it goes on while the loop is frozen.
                    m.hand = self.master.device_mut().hand_step(now, DT_S);
                } else {
                    m.cycle = self.master.step(&mut self.master_end, now, DT_S);
                    m.hand = self.master.device().hand();
                }
                if !slave_frozen {
                    *s = self.slave.step(&mut self.slave_end, now, DT_S);
                }
            }
            None => {
                let cycle = self.master.step(&mut self.master_end, now, DT_S);
                let m = SimMasterCycle {
                    cycle,
                    hand: self.master.device().hand(),
                };
                let s = self.slave.step(&mut self.slave_end, now, DT_S);
                self.last = Some((m, s));
            }
        }
        // An own-clock slave's poll for the next period: what has arrived by now, before the
        // master's next command (here, not at the next cycle's start, so that the poll
        // releases no message of the link's delay earlier than the slave's own step would).
        self.slave_end.poll()?;
        self.master.device_mut().advance(CYCLE_NS);
        self.slave.arm_mut().advance(CYCLE_NS);
        self.clock.advance_ns(CYCLE_NS);
        Ok(())
    }

    /// What the detector takes from one cycle: the master's cycle `m`, the slave's `s`, the
    /// true contact force at the slave `true_force_slave_n` (N).
    fn sample(&self, m: &SimMasterCycle, s: &TeleopCycle, true_force_slave_n: &[f64; 3]) -> Sample {
        let force_scale = self.cfg.scale.force;
        let intent = m.hand.intent;
        let meas = s.out.measured_pose;
        Sample {
            true_force_n: norm3(true_force_slave_n),
            master_force_n: norm3(&m.rendered_wrench),
            master_force_vec_n: [
                m.rendered_wrench[0],
                m.rendered_wrench[1],
                m.rendered_wrench[2],
            ],
            true_force_vec_n: *true_force_slave_n,
            transparency_abs_n: {
                let mut d = [0.0; 3];
                for (i, di) in d.iter_mut().enumerate() {
                    *di = m.rendered_wrench[i] / force_scale - s.out.wrench_measured[i];
                }
                norm3(&d)
            },
            slave_force_n: norm3(&s.out.wrench_measured),
            steady: intent.steady && !intent.clutch && !m.handle.clutch,
            observed_min_j: m.step.observed_j.min(s.port.observed_j),
            drift_mm: {
                // The master–slave mismatch: the slave's own drift plus the offset the
                // master's contact model put into the target.
                let o = self.master.coupling().model_offset_mm();
                norm3(&[
                    s.drift_mm[0] + o[0],
                    s.drift_mm[1] + o[1],
                    s.drift_mm[2] + o[2],
                ])
            },
            tracking_err_mm: norm3(&[
                meas[0] - s.desired_mm[0],
                meas[1] - s.desired_mm[1],
                meas[2] - s.desired_mm[2],
            ]),
            free_motion: s.mode == Mode::Position,
            rejected: s.out.status == Status::Rejected,
            finite: m.handle.pose.iter().all(|v| v.is_finite())
                && meas.iter().all(|v| v.is_finite()),
            push_n: norm3(&intent.push_n),
            applied_push_n: {
                let p = norm3(&intent.push_n);
                if p > 0.0 {
                    (0..3)
                        .map(|i| m.hand.wrench[i] * intent.push_n[i])
                        .sum::<f64>()
                        / p
                } else {
                    0.0
                }
            },
            intent_steady: intent.steady,
            tip_z_mm: self
                .slave
                .arm()
                .cut()
                .map(|_| self.slave.arm().true_pose()[2]),
        }
    }

    /// Writes one cycle of both sides and the link's events since the last one, at `t_ns`.
    fn record(
        &mut self,
        r: &mut Recorder,
        ch: &Channels,
        t_ns: u64,
        (m, s): (&SimMasterCycle, &TeleopCycle),
        true_force_slave_n: [f64; 3],
    ) -> Result<(), RecordingError> {
        let me = self.master.coupling().port.energy;
        ch.write_cycle(r, t_ns, (m, me), (s, &self.slave), true_force_slave_n)?;
        ch.write_cut(r, t_ns, &self.slave)?;
        ch.write_link_events(r, "command", |f| self.master_end.drain_events(f))?;
        ch.write_link_events(r, "feedback", |f| {
            self.slave_end.inner_mut().inner_mut().drain_events(f)
        })
    }

    /// Runs the whole session; with a recorder every cycle of both sides and every link
    /// event is recorded.
    pub fn run(self, recorder: Option<&mut Recorder>) -> Result<Summary, SessionError> {
        self.run_to(recorder, None)
    }

    /// The cutting fields of the summary, and the part's files into `out_dir`.
    fn finish_cut(
        &self,
        ev: CutEvaluator,
        out_dir: Option<&Path>,
    ) -> Result<Option<CutSummary>, SessionError> {
        Ok(self.slave.finish_cut(
            ev,
            self.cfg.cut_target.as_ref(),
            self.cfg.fixtures.depth_floor.map(|f| f.z_mm),
            out_dir,
        )?)
    }

    /// [`Session::run`], and in a cutting session the part's files into `out_dir`
    /// (`height.png`, `part.stl`, `deviation.png`).
    pub fn run_to(
        self,
        recorder: Option<&mut Recorder>,
        out_dir: Option<&Path>,
    ) -> Result<Summary, SessionError> {
        self.run_with(recorder, out_dir, &mut |_| true)
    }

    /// [`Session::run_to`], calling `on_cycle(cycles run)` after every cycle (progress);
    /// when it returns false the session stops there (interrupted) and the summary covers
    /// the cycles run.
    pub fn run_with(
        mut self,
        mut recorder: Option<&mut Recorder>,
        out_dir: Option<&Path>,
        on_cycle: &mut dyn FnMut(u64) -> bool,
    ) -> Result<Summary, SessionError> {
        let channels = match recorder.as_deref_mut() {
            Some(r) => Some(Channels::add(r, self.slave.arm().cut().is_some())?),
            None => None,
        };
        let planned = (self.cfg.duration_s * 1000.0).round() as u64;
        let mut ev = Evaluator::new(self.cfg.detector, planned as usize);
        let mut cut_ev = self
            .slave
            .arm()
            .cut()
            .map(|c| CutEvaluator::new(planned as usize, c.tool().spindle_rpm));
        let mut rev_mean = self
            .slave
            .arm()
            .cut()
            .map(|c| RevolutionMean::new(c.tool().spindle_rpm));
        let wall = Instant::now();
        let mut cycles = 0;
        while cycles < planned {
            let t_ns = self.clock.now_ns();
            self.step_cycle()?;
            let Some((m, s)) = self.last.as_ref() else {
                break;
            };
            let true_wrench_slave = self.slave.arm().true_contact_wrench();
            // Cutting: the true force averaged over a spindle revolution (the instant's sample
            // aliases the tooth-passing pulses into the detector's 1 kHz record).
            let true_force_slave_n = match (self.slave.arm().cut(), rev_mean.as_mut()) {
                (Some(c), Some(r)) => r.push(c.report().mean_force_n),
                _ => [
                    true_wrench_slave[0],
                    true_wrench_slave[1],
                    true_wrench_slave[2],
                ],
            };
            ev.push(self.sample(m, s, &true_force_slave_n));
            if let (Some(ce), Some(cs)) = (cut_ev.as_mut(), self.slave.cut_sample(s)) {
                ce.push(&cs);
            }
            if let (Some(r), Some(ch), Some((m, s))) =
                (recorder.as_deref_mut(), channels.as_ref(), self.last)
            {
                self.record(r, ch, t_ns + CYCLE_NS, (&m, &s), true_force_slave_n)?;
            }
            cycles += 1;
            if !on_cycle(cycles) {
                break;
            }
        }
        let wall_time_s = wall.elapsed().as_secs_f64();
        let dissipated =
            self.master.coupling().port.energy.dissipated_j + self.slave.port().energy.dissipated_j;
        let lost =
            self.master_end.counters.dropped() + self.slave_end.inner().inner().counters.dropped();
        let rejected =
            self.master.gate_counters().rejected() + self.slave.gate_counters().rejected();
        let rtt = self.master.round_trip().mean_ms();
        let facts = RunFacts {
            force_scale: self.cfg.scale.force,
            slave_safe_stops: self.slave.counters().safe_stops,
            master_saw_safe_stops: self.master.coupling().safe_stops_seen,
            repairs: self.slave.counters().repairs,
            safety_trips: self.slave.counters().safety_trips,
            unsafe_test_override: self.cfg.unsafe_test_override,
        };
        let mut summary = ev.finish(
            self.cfg.name.clone(),
            dissipated,
            lost,
            rejected,
            rtt,
            cycles,
            wall_time_s,
            &facts,
        );
        summary.slave_gate = *self.slave.gate_counters();
        summary.master_gate = *self.master.gate_counters();
        (
            summary.rtt_measured_p50_ms,
            summary.rtt_measured_p99_ms,
            summary.rtt_jitter_ms,
        ) = self.slave.round_trip().summary_ms();
        summary.rtt_fallback_cycles = self.slave.counters().round_trip_fallback_cycles;
        if let Some(ce) = cut_ev {
            summary.cutting = self.finish_cut(ce, out_dir)?;
        }
        Ok(summary)
    }
}

/// Runs a session from its configuration; a cutting session writes its part's files into
/// `out_dir`.
pub fn run_with_outputs(
    cfg: &SessionConfig,
    recorder: Option<&mut Recorder>,
    out_dir: Option<&Path>,
) -> Result<Summary, SessionError> {
    Session::new(cfg)?.run_to(recorder, out_dir)
}

/// Runs a session from its configuration.
pub fn run(cfg: &SessionConfig, recorder: Option<&mut Recorder>) -> Result<Summary, SessionError> {
    Session::new(cfg)?.run(recorder)
}
