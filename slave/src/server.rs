//! `h4-slave run`: the slave as a real process. A 1 kHz loop on absolute deadlines reads
//! the link, passes every command through the receive gate, runs the controller on the
//! (simulated) arm and publishes feedback. No valid command for the watchdog period (20 ms)
//! puts the arm in its safe state (force set-point ramped to zero, retract along the contact
//! normal, hold); a valid command after that re-pairs with no jump.
//!
//! The loop allocates nothing, blocks on nothing and logs nothing per cycle: statistics are
//! fixed-size, the status line is formatted only a few times a second on a terminal, and the
//! recording is handed to a writer thread through a bounded queue (full queue = counted drop).

use std::path::PathBuf;
use std::time::Duration;

use h4_shared::clock::{Clock, MonotonicClock};
use h4_shared::process::{StatusLine, Watchdog, stop_requested};
use h4_shared::recording::BackgroundRecorder;
use h4_shared::rt::{Histogram, Pacer, lock_memory, set_fifo_priority};
use h4_shared::wire::{
    Command, FAULT_COMMAND_REJECTED, FAULT_COMMAND_TIMEOUT, FAULT_FORCE_LIMIT, Feedback, Mode,
    SlaveState,
};
use h4_transport::Link;
use h4_transport::gate::{Gate, GateCounters};
use serde::{Deserialize, Serialize};

use crate::controller::{ControllerInput, SlaveCommand, SlaveController, Status};
use crate::experiment::ExperimentConfig;
use crate::plant::{ArmDriver, SimArm, SimError};

/// How the loop runs.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Arm id: service names, key expressions and every message carry it.
    pub arm_id: u16,
    /// Loop period, ns (1 kHz = 1 000 000).
    pub period_ns: u64,
    /// How long before each deadline the loop stops sleeping and spins, ns.
    pub spin_ns: u64,
    /// No valid command for this long → safe state, ms.
    pub watchdog_ms: f64,
    /// Run under SCHED_FIFO at this priority (None: normal scheduling).
    pub fifo_priority: Option<i32>,
    /// Lock all memory (mlockall).
    pub lock_memory: bool,
    /// Stop by itself after this long, s (None: until SIGINT/SIGTERM).
    pub duration_s: Option<f64>,
    /// Write an MCAP recording here.
    pub record: Option<PathBuf>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            arm_id: 0,
            period_ns: 1_000_000,
            spin_ns: 200_000,
            watchdog_ms: 20.0,
            fifo_priority: None,
            lock_memory: false,
            duration_s: None,
            record: None,
        }
    }
}

/// What a slave run reports when it stops.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct SlaveRunSummary {
    /// Loop cycles run.
    pub cycles: u64,
    /// Deadlines missed (the loop woke more than a whole period late).
    pub deadline_misses: u64,
    /// Lateness of the loop's wake-up, µs.
    pub lateness_p50_us: f64,
    /// p99 lateness, µs.
    pub lateness_p99_us: f64,
    /// p99.9 lateness, µs.
    pub lateness_p999_us: f64,
    /// Largest lateness, µs.
    pub lateness_max_us: f64,
    /// What the receive gate accepted and rejected.
    pub gate: GateCounters,
    /// Commands the controller rejected (workspace, limits): never passed to the actuators.
    pub commands_rejected_by_controller: u64,
    /// Link errors while receiving or publishing.
    pub link_errors: u64,
    /// Times the watchdog put the arm into its safe state.
    pub safe_stops: u64,
    /// Silence when the watchdog tripped (the largest over all trips), ms on the slave's clock.
    pub safe_stop_entry_silence_ms: f64,
    /// The loop's lateness in the cycle the watchdog tripped (largest), ms: the part of the
    /// entry silence that is the host not running the loop.
    pub safe_stop_entry_lateness_ms: f64,
    /// Times a master was paired after a safe stop.
    pub repairs: u64,
    /// Largest true contact force of the simulated arm, N.
    pub max_force_n: f64,
    /// The controller's force limit, N.
    pub force_limit_n: f64,
    /// Largest measured (sensor) force, N.
    pub max_measured_force_n: f64,
    /// Cycles in contact force control.
    pub contact_cycles: u64,
    /// Mean |F_n − F_d| over contact cycles, N.
    pub force_error_mean_n: f64,
    /// State when the run ended.
    pub final_state: String,
    /// Recording samples dropped because the writer fell behind.
    pub recording_dropped: u64,
    /// Seconds run, by the slave's clock.
    pub run_time_s: f64,
}

/// Why the slave could not run.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    /// The simulated arm could not be built.
    #[error("simulated arm: {0}")]
    Sim(#[from] SimError),
    /// The configuration is unusable.
    #[error("configuration: {0}")]
    Config(#[from] h4_shared::config::ConfigError),
    /// The recording could not be written.
    #[error("recording: {0}")]
    Recording(String),
}

/// One cycle as recorded.
#[derive(Clone, Copy, Debug, Serialize)]
struct CycleRecord {
    time_ns: u64,
    state: u8,
    status: u8,
    lateness_us: f64,
    force_measured_n: f64,
    force_desired_n: f64,
    force_true_n: f64,
    measured_pose: [f64; 4],
    commanded_pose: [f64; 4],
    contact_normal: [f64; 3],
    command_seq: u64,
}

const CYCLE_SCHEMA: &str = r#"{"type":"object","properties":{
"time_ns":{"type":"integer"},"state":{"type":"integer"},"status":{"type":"integer"},
"lateness_us":{"type":"number"},"force_measured_n":{"type":"number"},
"force_desired_n":{"type":"number"},"force_true_n":{"type":"number"},
"measured_pose":{"type":"array","items":{"type":"number"}},
"commanded_pose":{"type":"array","items":{"type":"number"}},
"contact_normal":{"type":"array","items":{"type":"number"}},
"command_seq":{"type":"integer"}}}"#;

/// Applies the real-time options, printing a clear message for each one refused.
pub fn apply_realtime(fifo_priority: Option<i32>, lock: bool) {
    if lock && let Err(e) = lock_memory() {
        eprintln!("warning: {e}");
    }
    if let Some(p) = fifo_priority
        && let Err(e) = set_fifo_priority(p)
    {
        eprintln!("warning: {e}");
    }
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1e3
}

fn slave_command(cmd: &Command) -> SlaveCommand {
    SlaveCommand {
        mode: cmd.mode().unwrap_or(Mode::Hold),
        pose: cmd.pose,
        velocity: cmd.velocity,
        force_setpoint_n: cmd.force_setpoint_n,
        clutch: cmd.clutch(),
    }
}

/// Runs the slave until stopped (SIGINT/SIGTERM or the duration), on `link`.
pub fn run<L: Link<Feedback, Command>>(
    cfg: &ExperimentConfig,
    opts: &RunOptions,
    link: &mut L,
) -> Result<SlaveRunSummary, ServerError> {
    use h4_shared::config::Validate;
    cfg.validate()?;
    let ws = cfg.arm.workspace();
    let assumed = cfg.arm.stiffness().map_err(SimError::from)?;
    let p = cfg.surface.contact_point_mm;
    let start = h4_shared::Pose::new(p[0], p[1], p[2] + cfg.approach.gap_mm, 0.0);
    let mut arm = SimArm::new(
        ws.params,
        cfg.arm.actuator_stiffness_n_per_mm,
        cfg.plant,
        cfg.sensor,
        cfg.surface(),
        start,
        cfg.seed,
    )?;
    let mut ctrl = SlaveController::new(ws, assumed, cfg.controller);
    let mut recorder = BackgroundRecorder::<CycleRecord>::start(
        opts.record.as_deref(),
        "/slave/cycle",
        "h4.SlaveCycle",
        CYCLE_SCHEMA,
    )
    .map_err(|e| ServerError::Recording(e.to_string()))?;

    apply_realtime(opts.fifo_priority, opts.lock_memory);
    let clock = MonotonicClock::new();
    let period_ns = opts.period_ns.max(1);
    let dt_s = period_ns as f64 * 1e-9;
    let mut pacer = Pacer::new(
        Duration::from_nanos(period_ns),
        Duration::from_nanos(opts.spin_ns),
    );
    let mut gate = Gate::<Command>::new(opts.arm_id, 100_000_000);
    // Tripped at the first cycle whose silence reaches the watchdog period.
    let watchdog_ns = ((opts.watchdog_ms * 1e6) as u64).saturating_sub(period_ns);
    let mut watchdog = Watchdog::new(watchdog_ns);
    let mut status_line = StatusLine::new(4.0);
    let mut text = String::with_capacity(256);
    let end_ns = opts.duration_s.map(|s| (s * 1e9) as u64);

    let mut s = SlaveRunSummary {
        force_limit_n: cfg.controller.force_limit_n,
        ..SlaveRunSummary::default()
    };
    let mut state = SlaveState::Idle;
    let mut current = SlaveCommand::default();
    let mut last_cmd: Option<Command> = None;
    let mut seq = 0u64;
    let mut error_sum = 0.0;
    let mut faults = 0u16;
    loop {
        let tick = pacer.wait();
        let now = clock.now_ns();
        if stop_requested() || end_ns.is_some_and(|e| now >= e) {
            break;
        }
        let mut fresh = false;
        loop {
            match link.try_recv() {
                Ok(Some(msg)) => {
                    if let Ok(cmd) = gate.accept(&msg, now) {
                        last_cmd = Some(cmd);
                        fresh = true;
                    }
                }
                Ok(None) => break,
                Err(_) => {
                    s.link_errors += 1;
                    break;
                }
            }
        }
        if fresh {
            watchdog.feed(now);
            if state == SlaveState::SafeStop {
                ctrl.clear_safe_stop();
                s.repairs += 1;
            }
            state = SlaveState::Active;
            faults &= !FAULT_COMMAND_TIMEOUT;
            if let Some(cmd) = &last_cmd {
                current = slave_command(cmd);
            }
        }
        if state == SlaveState::Active && watchdog.tripped(now) {
            ctrl.safe_stop();
            state = SlaveState::SafeStop;
            faults |= FAULT_COMMAND_TIMEOUT;
            s.safe_stops += 1;
            let silence_ms = watchdog.silence_ns(now).unwrap_or(0) as f64 / 1e6;
            s.safe_stop_entry_silence_ms = s.safe_stop_entry_silence_ms.max(silence_ms);
            s.safe_stop_entry_lateness_ms = s
                .safe_stop_entry_lateness_ms
                .max(tick.lateness_ns as f64 / 1e6);
        }
        let reading = arm.read();
        let command = if state == SlaveState::Active {
            current
        } else {
            SlaveCommand {
                mode: Mode::Hold,
                ..current
            }
        };
        let out = ctrl.step(
            &ControllerInput {
                actuators_mm: reading.actuators_mm,
                wrench: reading.wrench,
                command,
            },
            dt_s,
        );
        if out.rejection.is_some() {
            s.commands_rejected_by_controller += 1;
            faults |= FAULT_COMMAND_REJECTED;
        } else {
            faults &= !FAULT_COMMAND_REJECTED;
        }
        if out.status == Status::ForceLimited {
            faults |= FAULT_FORCE_LIMIT;
        } else {
            faults &= !FAULT_FORCE_LIMIT;
        }
        arm.command(&out.actuators_cmd_mm);
        // The simulated arm keeps real time, skipped deadlines included.
        arm.advance(period_ns * (1 + tick.missed));

        let true_force_n = arm.true_contact_wrench().fixed_rows::<3>(0).norm();
        s.max_force_n = s.max_force_n.max(true_force_n);
        s.max_measured_force_n = s.max_measured_force_n.max(out.normal_force_n.abs());
        if out.status == Status::Contact {
            s.contact_cycles += 1;
            error_sum += (out.normal_force_n - out.setpoint_n).abs();
        }
        seq += 1;
        let fb = Feedback {
            seq,
            send_time_ns: now,
            echo_seq: last_cmd.map_or(0, |c| c.seq),
            echo_send_time_ns: last_cmd.map_or(0, |c| c.send_time_ns),
            pose: out.measured_pose,
            wrench_measured: out.wrench_measured,
            wrench_desired: out.wrench_desired,
            energy_in_j: 0.0,
            energy_out_j: 0.0,
            arm_id: opts.arm_id,
            state: state as u8,
            fault_flags: faults,
            ..Feedback::default()
        };
        if link.publish(&fb).is_err() {
            s.link_errors += 1;
        }
        recorder.push(
            now,
            CycleRecord {
                time_ns: now,
                state: state as u8,
                status: out.status.code(),
                lateness_us: us(tick.lateness_ns),
                force_measured_n: out.normal_force_n,
                force_desired_n: out.setpoint_n,
                force_true_n: true_force_n,
                measured_pose: out.measured_pose,
                commanded_pose: out.commanded_pose,
                contact_normal: out.contact_normal,
                command_seq: last_cmd.map_or(0, |c| c.seq),
            },
        );
        s.cycles += 1;
        if status_line.due(now) {
            use std::fmt::Write;
            text.clear();
            let _ = write!(
                text,
                "slave arm {} | {:>6} cycles | late p99 {:>6.1} us | misses {} | {:?} {:?} | F {:>6.2} N (set {:>5.1}) | rejected {}",
                opts.arm_id,
                s.cycles,
                us(pacer.lateness.quantile(0.99)),
                pacer.misses,
                state,
                out.status,
                out.normal_force_n,
                out.setpoint_n,
                gate.counters.rejected(),
            );
            status_line.show(&text);
        }
    }
    status_line.finish();
    s.deadline_misses = pacer.misses;
    fill_lateness(&mut s, &pacer.lateness);
    s.gate = gate.counters;
    s.force_error_mean_n = if s.contact_cycles > 0 {
        error_sum / s.contact_cycles as f64
    } else {
        0.0
    };
    s.final_state = format!("{state:?}");
    s.run_time_s = clock.now_ns() as f64 / 1e9;
    s.recording_dropped = recorder.dropped();
    recorder.finish().map_err(ServerError::Recording)?;
    Ok(s)
}

fn fill_lateness(s: &mut SlaveRunSummary, h: &Histogram) {
    s.lateness_p50_us = us(h.quantile(0.5));
    s.lateness_p99_us = us(h.quantile(0.99));
    s.lateness_p999_us = us(h.quantile(0.999));
    s.lateness_max_us = us(h.max());
}

/// Command-line options shared by `h4-slave run`, `h4-master run` and `h4-master loopback`:
/// which transport, which arm, and the Zenoh endpoints.
#[cfg(feature = "server")]
pub mod cli {
    use std::path::PathBuf;

    use clap::{Args, ValueEnum};
    use h4_shared::wire::{Command, Feedback, WireMessage};
    use h4_transport::Link;
    use h4_transport::iceoryx2::{self as iox, Iceoryx2Options};
    use h4_transport::zenoh::{ZenohConfig, ZenohLink, ZenohMode};

    /// The transport between the two processes.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
    pub enum TransportKind {
        /// iceoryx2 shared memory (same host).
        Iceoryx2,
        /// Eclipse Zenoh (same host or between hosts).
        Zenoh,
    }

    /// Transport options.
    #[derive(Clone, Debug, Args)]
    pub struct TransportArgs {
        /// Transport to the other side.
        #[arg(long, value_enum, default_value_t = TransportKind::Iceoryx2)]
        pub transport: TransportKind,
        /// Arm id: selects the iceoryx2 services / Zenoh key expressions `h4/<arm-id>/…`.
        #[arg(long, default_value_t = 0)]
        pub arm_id: u16,
        /// iceoryx2 service name prefix.
        #[arg(long, default_value = "h4")]
        pub iceoryx2_prefix: String,
        /// Zenoh mode: peer or client.
        #[arg(long, value_parser = ["peer", "client"], default_value = "peer")]
        pub zenoh_mode: String,
        /// Zenoh endpoint to listen on (repeatable), e.g. tcp/127.0.0.1:7447. Loopback only
        /// unless you name another address.
        #[arg(long = "zenoh-listen", value_name = "ENDPOINT")]
        pub zenoh_listen: Vec<String>,
        /// Zenoh endpoint to connect to (repeatable), e.g. tcp/127.0.0.1:7447.
        #[arg(long = "zenoh-connect", value_name = "ENDPOINT")]
        pub zenoh_connect: Vec<String>,
        /// Zenoh json5 configuration file (TLS, user/password, access control); the options
        /// above are applied over it.
        #[arg(long = "zenoh-config", value_name = "FILE")]
        pub zenoh_config: Option<PathBuf>,
    }

    impl TransportArgs {
        /// The arguments that reproduce these options on another command line.
        pub fn to_args(&self) -> Vec<String> {
            let mut v = vec![
                "--transport".to_string(),
                match self.transport {
                    TransportKind::Iceoryx2 => "iceoryx2",
                    TransportKind::Zenoh => "zenoh",
                }
                .to_string(),
                "--arm-id".to_string(),
                self.arm_id.to_string(),
                "--iceoryx2-prefix".to_string(),
                self.iceoryx2_prefix.clone(),
                "--zenoh-mode".to_string(),
                self.zenoh_mode.clone(),
            ];
            for e in &self.zenoh_listen {
                v.extend(["--zenoh-listen".to_string(), e.clone()]);
            }
            for e in &self.zenoh_connect {
                v.extend(["--zenoh-connect".to_string(), e.clone()]);
            }
            if let Some(f) = &self.zenoh_config {
                v.extend(["--zenoh-config".to_string(), f.display().to_string()]);
            }
            v
        }

        fn zenoh(&self) -> ZenohConfig {
            ZenohConfig {
                mode: if self.zenoh_mode == "client" {
                    ZenohMode::Client
                } else {
                    ZenohMode::Peer
                },
                listen: self.zenoh_listen.clone(),
                connect: self.zenoh_connect.clone(),
                config_file: self.zenoh_config.as_ref().map(|p| p.display().to_string()),
                ..ZenohConfig::default()
            }
        }

        fn open<Out, In>(
            &self,
            iox_open: impl FnOnce(&Iceoryx2Options) -> Result<Box<dyn Link<Out, In>>, String>,
        ) -> Result<Box<dyn Link<Out, In>>, String>
        where
            Out: WireMessage,
            In: WireMessage,
        {
            match self.transport {
                TransportKind::Iceoryx2 => {
                    match iox::remove_stale_nodes() {
                        Ok(0) => {}
                        Ok(n) => {
                            eprintln!("iceoryx2: removed the resources of {n} dead process(es)")
                        }
                        Err(e) => eprintln!("warning: {e}"),
                    }
                    let opts = Iceoryx2Options {
                        prefix: self.iceoryx2_prefix.clone(),
                        ..Iceoryx2Options::new(self.arm_id)
                    };
                    iox_open(&opts)
                }
                TransportKind::Zenoh => ZenohLink::<Out, In>::open(self.arm_id, &self.zenoh())
                    .map(|l| Box::new(l) as Box<dyn Link<Out, In>>)
                    .map_err(|e| e.to_string()),
            }
        }

        /// Opens the slave's end.
        pub fn open_slave(&self) -> Result<Box<dyn Link<Feedback, Command>>, String> {
            self.open(|o| {
                iox::slave(o)
                    .map(|l| Box::new(l) as Box<dyn Link<Feedback, Command>>)
                    .map_err(|e| e.to_string())
            })
        }

        /// Opens the master's end.
        pub fn open_master(&self) -> Result<Box<dyn Link<Command, Feedback>>, String> {
            self.open(|o| {
                iox::master(o)
                    .map(|l| Box::new(l) as Box<dyn Link<Command, Feedback>>)
                    .map_err(|e| e.to_string())
            })
        }
    }

    /// `h4-slave run`.
    #[derive(Clone, Debug, Args)]
    pub struct RunArgs {
        /// The simulated world (arm, surface, sensor, plant, controller): an experiment file,
        /// e.g. config/experiments/fig6b.toml (its force and track sections are not used: the
        /// master commands the motion).
        #[arg(long, default_value = "config/slave/sim-resin.toml")]
        pub config: PathBuf,
        /// Override any field of the config file (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        pub set: Vec<String>,
        /// Transport.
        #[command(flatten)]
        pub transport: TransportArgs,
        /// Stop by itself after this many seconds (default: until SIGINT/SIGTERM).
        #[arg(long)]
        pub duration_s: Option<f64>,
        /// Write the summary as JSON here (it is also printed on stdout).
        #[arg(long)]
        pub summary: Option<PathBuf>,
        /// Write an MCAP recording here.
        #[arg(long)]
        pub record: Option<PathBuf>,
        /// No valid command for this long puts the arm in its safe state, ms.
        #[arg(long, default_value_t = 20.0)]
        pub watchdog_ms: f64,
        /// Run the loop under SCHED_FIFO at this priority (1–99).
        #[arg(long)]
        pub fifo_priority: Option<i32>,
        /// Lock all memory (mlockall).
        #[arg(long)]
        pub lock_memory: bool,
    }

    impl RunArgs {
        /// Runs the slave process.
        pub fn run(self) -> Result<(), String> {
            h4_shared::process::install_stop_handlers()
                .map_err(|e| format!("signal handlers: {e}"))?;
            let cfg: crate::experiment::ExperimentConfig =
                h4_shared::config::load(&self.config, &self.set).map_err(|e| e.to_string())?;
            let mut link = self.transport.open_slave()?;
            let opts = super::RunOptions {
                arm_id: self.transport.arm_id,
                watchdog_ms: self.watchdog_ms,
                fifo_priority: self.fifo_priority,
                lock_memory: self.lock_memory,
                duration_s: self.duration_s,
                record: self.record.clone(),
                ..super::RunOptions::default()
            };
            let summary = super::run(&cfg, &opts, &mut link).map_err(|e| e.to_string())?;
            let json = serde_json::to_string_pretty(&summary).map_err(|e| e.to_string())?;
            println!("{json}");
            if let Some(path) = &self.summary {
                std::fs::write(path, format!("{json}\n"))
                    .map_err(|e| format!("{}: {e}", path.display()))?;
            }
            Ok(())
        }
    }
}
