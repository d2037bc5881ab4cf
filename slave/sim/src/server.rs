//! `h4-slave run --arm sim`: the product's real-time server ([`h4_slave::server::run`])
//! over the simulated arm of a world file, with the simulated arm's diagnostics: the true
//! contact force (`force_true_n` of `/slave/cycle`, the summary's `max_force_n`) and, when
//! the arm cuts, the cut (`/slave/cut`, the summary's cutting fields, the part's files).
//! Nothing here reaches the controller: the server reads the arm through
//! [`h4_slave::arm::ArmDriver`] only.

use std::path::PathBuf;

use h4_shared::wire::{Command, Feedback};
use h4_slave::controller::SlaveController;
use h4_slave::server::{Diagnostics, RunOptions, ServerError, SlaveRunSummary};
use h4_slave::teleop::{SlaveTeleop, TeleopCycle, TeleopError};
use h4_telemetry::recording::{EncodedChannel, PolledChannels};
use h4_telemetry::sink::{Outputs, OutputsError};
use h4_transport::Link;
use h4_transport::ros2::telemetry::{LatestCell, Ros2Recording, SlaveSample, TelemetrySample};
use serde::{Deserialize, Serialize};

use crate::cut::{CutCycle, CutTeleop};
use crate::experiment::ExperimentConfig;
use crate::plant::SimArm;
use crate::plant::SimError;
use crate::plant::cutting::judge::{CutEvaluator, CutSummary};

/// Where a run's outputs go.
#[derive(Clone, Debug, Default)]
pub struct RunOutputs {
    /// Write an MCAP recording here (`--record`).
    pub record: Option<PathBuf>,
    /// Serve the live view here (`--foxglove-ws HOST:PORT`).
    pub foxglove_ws: Option<String>,
    /// When the arm cuts: write the machined part here at the end (`height.png`,
    /// `part.stl`, `deviation.png` with a `cut_target`; `--out DIR`).
    pub out_dir: Option<PathBuf>,
    /// With `--ros2`: the cell the ROS 2 publishing thread reads (each cycle is written
    /// into it, `h4_slave::ros2::Ros2Tee`).
    pub ros2: Option<std::sync::Arc<LatestCell<SlaveSample>>>,
    /// With `--record-ros2`: the CRTK topics the recording also holds, sampled from `ros2`
    /// (which must then be set).
    pub ros2_record: Option<Ros2Recording>,
}

impl RunOutputs {
    /// The recording's ROS 2 channels (`--record-ros2`), if any.
    pub fn ros2_polled(&self) -> Result<Option<PolledChannels>, OutputsError> {
        ros2_polled(self.ros2_record.as_ref(), self.ros2.as_ref())
    }
}

/// The ROS 2 channels `--record-ros2` adds to a recording: `record`'s topics of `T`'s side
/// (CDR messages, `ros2msg` schemas), sampled from `cell` by the recording thread at
/// `record.rate_hz` (the 1 kHz loop only writes the cell, as for `--ros2`). None without
/// `record` or `cell`.
pub fn ros2_polled<T: TelemetrySample>(
    record: Option<&Ros2Recording>,
    cell: Option<&std::sync::Arc<LatestCell<T>>>,
) -> Result<Option<PolledChannels>, OutputsError> {
    let (Some(record), Some(cell)) = (record, cell) else {
        return Ok(None);
    };
    let topics = record
        .topics::<T>()
        .map_err(|e| OutputsError::Recording(format!("--record-ros2: {e}")))?;
    let channels = topics
        .into_iter()
        .map(|t| EncodedChannel {
            topic: t.topic,
            schema_name: t.type_name.to_owned(),
            schema_encoding: "ros2msg".to_owned(),
            schema_data: t.definition,
            message_encoding: "cdr".to_owned(),
        })
        .collect();
    let mut poller = record.poller(std::sync::Arc::clone(cell));
    Ok(Some(PolledChannels {
        channels,
        period: std::time::Duration::from_secs_f64(1.0 / record.rate_hz.clamp(1.0, 1000.0)),
        poll: Box::new(move |write| {
            poller.poll(write);
        }),
    }))
}

/// What a run on the simulated arm reports: the product's summary, and the cut's fields
/// when the arm cuts.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct SimRunSummary {
    /// The product server's summary (fields flattened).
    #[serde(flatten)]
    pub slave: SlaveRunSummary,
    /// With a `cutting` section: the cut and the part (`removed_volume_mm3`,
    /// `surface_error_p99_mm` and `gouge_max_mm` against the world's `cut_target` and
    /// fixture floor, `cutting_force_dev_p99_pct`, `removal_rate_mm3_per_s`, …; the fields
    /// of the simulation's summary, `docs/cutting.md`).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub cutting: Option<CutSummary>,
    /// With `--inject-fault`: what the fault did and how the slave answered.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault_injection: Option<FaultReport>,
}

/// What an injected fault (`h4-slave run --inject-fault`) showed: the summary's
/// `fault_injection`. Cycles are counted on the arm's clock (1 ms each at 1 kHz; a cycle the
/// loop missed counts too).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct FaultReport {
    /// The fault (`sensor-freeze`, `sensor-saturate`, `driver-silent`).
    pub kind: String,
    /// When it began, s on the arm's clock.
    pub start_s: f64,
    /// How long it lasted, s.
    pub duration_s: f64,
    /// The slave's state in the cycle before the fault (`active`: it was following the
    /// master when the fault struck).
    pub state_before: String,
    /// Cycles from the fault's first cycle to the first cycle the slave was safe-stopped
    /// (0: in that cycle; absent: never).
    pub safe_stop_after_cycles: Option<u64>,
    /// The safety monitor's trips from the fault's start to its end, by reason.
    pub trips_during: h4_slave::safety::SafetyTrips,
    /// Cycles of the fault in which the slave was not safe-stopped (following the master on
    /// a faulty arm).
    pub cycles_active_during: u64,
    /// The largest true contact force from the fault's start to the run's end, N.
    pub max_true_force_n: f64,
    /// Cycles from the fault's end to the first re-pairing after it (absent: never).
    pub repaired_after_cycles: Option<u64>,
}

/// Follows an injected fault through the run ([`FaultReport`]).
struct FaultWatch {
    report: FaultReport,
    start_ns: u64,
    end_ns: u64,
    period_ns: u64,
    last_state: h4_shared::wire::SlaveState,
    trips_at_start: Option<h4_slave::safety::SafetyTrips>,
    trips_at_end: Option<h4_slave::safety::SafetyTrips>,
    prev_trips: h4_slave::safety::SafetyTrips,
}

impl FaultWatch {
    fn new(plan: crate::fault::FaultPlan, period_ns: u64) -> Self {
        let ns = |s: f64| (s * 1e9).round() as u64;
        FaultWatch {
            report: FaultReport {
                kind: plan.kind.name().to_string(),
                start_s: plan.start_s,
                duration_s: plan.duration_s,
                ..FaultReport::default()
            },
            start_ns: ns(plan.start_s),
            end_ns: ns(plan.start_s + plan.duration_s),
            period_ns,
            last_state: h4_shared::wire::SlaveState::Idle,
            trips_at_start: None,
            trips_at_end: None,
            prev_trips: h4_slave::safety::SafetyTrips::default(),
        }
    }

    /// One cycle whose reading was taken at `t_ns` (arm clock).
    fn observe(&mut self, t_ns: u64, teleop: &SlaveTeleop<SimArm>, cycle: &TeleopCycle) {
        use h4_shared::wire::SlaveState;
        let trips = teleop.counters().safety_trips;
        if t_ns >= self.start_ns && self.trips_at_start.is_none() {
            self.report.state_before = format!("{:?}", self.last_state).to_lowercase();
            // The trips counted before this cycle's step.
            self.trips_at_start = Some(self.prev_trips);
        }
        if t_ns >= self.start_ns {
            let f = teleop.arm().true_contact_wrench().fixed_rows::<3>(0).norm();
            self.report.max_true_force_n = if f.is_nan() || self.report.max_true_force_n.is_nan() {
                f64::NAN
            } else {
                self.report.max_true_force_n.max(f)
            };
            let safe = cycle.state == SlaveState::SafeStop || cycle.state == SlaveState::Fault;
            if t_ns < self.end_ns {
                if safe {
                    self.report
                        .safe_stop_after_cycles
                        .get_or_insert((t_ns - self.start_ns) / self.period_ns);
                } else {
                    self.report.cycles_active_during += 1;
                }
            } else {
                self.trips_at_end.get_or_insert(trips);
                if cycle.repaired {
                    self.report
                        .repaired_after_cycles
                        .get_or_insert((t_ns - self.end_ns) / self.period_ns);
                }
            }
        }
        self.last_state = cycle.state;
        self.prev_trips = trips;
    }

    fn finish(mut self, trips_now: h4_slave::safety::SafetyTrips) -> FaultReport {
        if let Some(a) = self.trips_at_start {
            let b = self.trips_at_end.unwrap_or(trips_now);
            self.report.trips_during = b.since(&a);
        }
        self.report
    }
}

impl std::ops::Deref for SimRunSummary {
    type Target = SlaveRunSummary;
    fn deref(&self) -> &SlaveRunSummary {
        &self.slave
    }
}

impl std::ops::DerefMut for SimRunSummary {
    fn deref_mut(&mut self) -> &mut SlaveRunSummary {
        &mut self.slave
    }
}

/// Why the slave could not run on the simulated arm.
#[derive(Debug, thiserror::Error)]
pub enum SimServerError {
    /// The simulated arm could not be built.
    #[error("simulated arm: {0}")]
    Sim(#[from] SimError),
    /// The configuration is unusable.
    #[error("configuration: {0}")]
    Config(#[from] h4_shared::config::ConfigError),
    /// The teleoperation endpoint's settings are unusable.
    #[error("{0}")]
    Teleop(#[from] TeleopError),
    /// The server could not run.
    #[error("{0}")]
    Server(#[from] ServerError),
    /// The recording or the live view could not start.
    #[error("{0}")]
    Outputs(#[from] OutputsError),
    /// The part's files could not be written.
    #[error("--out: {0}")]
    Part(String),
}

/// The most steady-feed samples a cutting run keeps for `cutting_force_dev_p99_pct` (one a
/// cycle: the first 10 minutes of steady feed; 4.8 MB allocated before the loop).
const MAX_STEADY_FEED_SAMPLES: usize = 600_000;

/// The simulated arm's diagnostics: its true contact force, and the cut (its record and
/// its evidence for the judge).
pub struct SimDiagnostics {
    cut_ev: Option<CutEvaluator>,
    fault: Option<FaultWatch>,
    period_ns: u64,
}

impl SimDiagnostics {
    /// For `teleop`, over a run of `duration_s` (None: open-ended) at `period_ns`: the cut's
    /// evidence is allocated here, before the loop.
    pub fn new(teleop: &SlaveTeleop<SimArm>, duration_s: Option<f64>, period_ns: u64) -> Self {
        let dt_s = period_ns.max(1) as f64 * 1e-9;
        let cut_ev = teleop.arm().cut().map(|c| {
            let cycles = duration_s.map_or(MAX_STEADY_FEED_SAMPLES, |d| {
                ((d / dt_s).ceil() as usize).min(MAX_STEADY_FEED_SAMPLES)
            });
            CutEvaluator::new(cycles, c.tool().spindle_rpm)
        });
        let fault = teleop
            .arm()
            .fault()
            .map(|(plan, _)| FaultWatch::new(plan, period_ns.max(1)));
        SimDiagnostics {
            cut_ev,
            fault,
            period_ns: period_ns.max(1),
        }
    }
}

impl Diagnostics<SimArm> for SimDiagnostics {
    type Sample = CutCycle;
    fn true_force_n(&self, teleop: &SlaveTeleop<SimArm>) -> Option<f64> {
        Some(teleop.arm().true_contact_wrench().fixed_rows::<3>(0).norm())
    }
    fn sample(&self, teleop: &SlaveTeleop<SimArm>) -> Option<CutCycle> {
        teleop.cut_cycle()
    }
    fn observe(&mut self, teleop: &SlaveTeleop<SimArm>, cycle: &TeleopCycle) {
        if let (Some(ev), Some(sample)) = (self.cut_ev.as_mut(), teleop.cut_sample(cycle)) {
            ev.push(&sample);
        }
        if let Some(w) = self.fault.as_mut() {
            // Observed after the arm advanced: the cycle's reading was a period earlier.
            let t_ns = teleop.arm().time_ns().saturating_sub(self.period_ns);
            w.observe(t_ns, teleop, cycle);
        }
    }
}

/// Runs the slave on the simulated arm of `cfg` until stopped (SIGINT/SIGTERM or the
/// duration), on `link`.
pub fn run<L: Link<Feedback, Command>>(
    cfg: &ExperimentConfig,
    opts: &RunOptions,
    outputs: &RunOutputs,
    link: &mut L,
) -> Result<SimRunSummary, SimServerError> {
    run_with_fault(cfg, opts, outputs, None, link)
}

/// [`run`], with `fault` injected into the simulated arm (`h4-slave run --inject-fault`; a
/// saturated sensor reads the arm's `ratings.sensor_range_n`): the summary's
/// `fault_injection` says what it did.
pub fn run_with_fault<L: Link<Feedback, Command>>(
    cfg: &ExperimentConfig,
    opts: &RunOptions,
    outputs: &RunOutputs,
    fault: Option<crate::fault::FaultPlan>,
    link: &mut L,
) -> Result<SimRunSummary, SimServerError> {
    use h4_shared::config::Validate;
    cfg.validate()?;
    opts.passivity.validate_at("passivity.")?;
    opts.contact.validate_at("contact.")?;
    let period_ns = opts.period_ns.max(1);
    let mut teleop = build_teleop(cfg, opts, period_ns)?;
    if let Some(plan) = fault {
        teleop
            .arm_mut()
            .inject_fault(plan, cfg.arm.ratings.sensor_range_n);
    }
    // `/slave/cut` beside the cycles when the arm cuts.
    let sink = Outputs::start_polled(
        outputs.record.as_deref(),
        outputs.foxglove_ws.as_deref(),
        "h4-slave",
        ("/slave/cycle", "h4.SlaveProcessCycle"),
        teleop.cut_cycle().map(|_| ("/slave/cut", "h4.CutCycle")),
        1e9 / period_ns as f64,
        outputs.ros2_polled()?,
    )?;
    let sink = h4_slave::ros2::Ros2Tee::new(sink, outputs.ros2.clone());
    let mut diag = SimDiagnostics::new(&teleop, opts.duration_s, period_ns);
    let slave = h4_slave::server::run(&mut teleop, &mut diag, sink, opts, link)?;
    let fault_injection = diag
        .fault
        .take()
        .map(|w| w.finish(teleop.counters().safety_trips));
    let mut s = SimRunSummary {
        slave,
        cutting: None,
        fault_injection,
    };
    if let Some(ev) = diag.cut_ev {
        s.cutting = teleop
            .finish_cut(
                ev,
                cfg.cut_target.as_ref(),
                cfg.fixtures.depth_floor.map(|f| f.z_mm),
                outputs.out_dir.as_deref(),
            )
            .map_err(|e| SimServerError::Part(e.to_string()))?;
    }
    Ok(s)
}

/// The simulated arm of `cfg` and its controller; the arm starts `approach.gap_mm` above
/// the surface's contact point.
pub fn sim_parts(cfg: &ExperimentConfig) -> Result<(SimArm, SlaveController), SimError> {
    let p = cfg.surface.contact_point_mm;
    let start = h4_shared::Pose::new(p[0], p[1], p[2] + cfg.approach.gap_mm, 0.0);
    cfg.world().build(start, cfg.seed)
}

/// The slave's endpoint over the simulated arm of `cfg` ([`sim_parts`]).
pub fn build_teleop(
    cfg: &ExperimentConfig,
    opts: &RunOptions,
    period_ns: u64,
) -> Result<SlaveTeleop<SimArm>, SimServerError> {
    let (arm, ctrl) = sim_parts(cfg)?;
    Ok(SlaveTeleop::new(
        opts.teleop_params(),
        ctrl,
        arm,
        period_ns,
    )?)
}
