//! The experiment's loop on the simulated clock: each 1 ms cycle the arm is read, the
//! scheduled command (set-point steps after the first contact, tracking after the start
//! delay) goes through the controller to the arm, the arm advances, and the simulation's
//! truth is kept for the summary (and recorded).

use std::time::Instant;

use h4_shared::config::Validate;
use h4_shared::kinematics::Pose;
use h4_shared::wire::Mode;
use h4_telemetry::recording::Recorder;
use nalgebra::Vector3;

use super::ExperimentError;
use super::config::ExperimentConfig;
use super::metrics::{self, Summary};
use super::record::Channels;
use crate::plant::SimArm;
use h4_slave::arm::ArmDriver;
use h4_slave::controller::{ControllerInput, ControllerOutput, SlaveCommand, Status};

/// The control period, ns.
const CYCLE_NS: u64 = 1_000_000;

/// The simulation's truth after a cycle.
pub(super) struct Truth {
    /// The platform's true pose, mm and rad.
    pub(super) pose: Pose,
    /// The true penetration into the surface, mm.
    pub(super) penetration_mm: f64,
    /// The surface's outward normal nearest the tool.
    pub(super) normal: Vector3<f64>,
    /// The true contact force along that normal, N.
    pub(super) fn_true_n: f64,
    /// The true contact force's magnitude, N.
    force_n: f64,
}

impl Truth {
    fn of(arm: &SimArm) -> Self {
        let pose = arm.true_pose();
        let tip = Vector3::new(pose[0], pose[1], pose[2]);
        let (penetration_mm, normal) = arm.surface().penetration(&tip);
        let w = arm.true_contact_wrench();
        let f3 = Vector3::new(w[0], w[1], w[2]);
        Truth {
            pose,
            penetration_mm,
            normal,
            fn_true_n: f3.dot(&normal),
            force_n: f3.norm(),
        }
    }
}

/// What a run keeps for its summary.
pub(super) struct Trace {
    /// The true normal force of every cycle, N.
    pub(super) fn_true_n: Vec<f64>,
    /// The first cycle with a true contact force.
    pub(super) first_true_contact: Option<usize>,
    /// The first cycle the controller reported contact (the set-point steps count from
    /// it), ms.
    pub(super) ctrl_contact_ms: Option<u64>,
    /// The first cycle of the tracking motion.
    pub(super) track_start: Option<usize>,
    /// Cycles without contact after tracking started, ms.
    pub(super) contact_lost_ms: u64,
    /// Path length of the tool while tracking, mm.
    pub(super) tracked_mm: f64,
    /// Largest contact force magnitude, N.
    pub(super) max_force_n: f64,
    /// Cycles whose command the controller rejected.
    pub(super) rejected_cycles: u64,
    /// The controller's latest environment-stiffness estimate, N/mm.
    pub(super) env_estimate_n_per_mm: f64,
    /// The controller's state at the last cycle.
    pub(super) last_status: Status,
    /// The distance from the last commanded pose to the approach target, mm.
    pub(super) target_distance_mm: f64,
    /// The true pose of the previous cycle.
    prev_pose: Pose,
}

impl Trace {
    fn new(cycles: u64, start: Pose) -> Self {
        Trace {
            fn_true_n: Vec::with_capacity(cycles as usize),
            first_true_contact: None,
            ctrl_contact_ms: None,
            track_start: None,
            contact_lost_ms: 0,
            tracked_mm: 0.0,
            max_force_n: 0.0,
            rejected_cycles: 0,
            env_estimate_n_per_mm: f64::NAN,
            last_status: Status::Taring,
            target_distance_mm: f64::NAN,
            prev_pose: start,
        }
    }

    /// The set-point and velocity of cycle `k` (`velocity` is the tracking velocity).
    fn command(
        &mut self,
        k: u64,
        cfg: &ExperimentConfig,
        velocity: &Vector3<f64>,
    ) -> (f64, [f64; 4]) {
        let mut setpoint = cfg.force.setpoint_n;
        let mut v = [0.0; 4];
        if let Some(tc) = self.ctrl_contact_ms {
            let since = (k - tc) as f64 * 1e-3;
            for st in &cfg.force.steps {
                if since >= st.time_s {
                    setpoint = st.setpoint_n;
                }
            }
            if since >= cfg.track.start_delay_s {
                v = [velocity[0], velocity[1], velocity[2], 0.0];
                if self.track_start.is_none() {
                    self.track_start = Some(k as usize);
                }
            }
        }
        (setpoint, v)
    }

    /// Books the controller's output of cycle `k` (`target`: the approach's target).
    fn controller(&mut self, k: u64, out: &ControllerOutput, target: &[f64; 4]) {
        self.last_status = out.status;
        let c = out.commanded_pose;
        self.target_distance_mm =
            Vector3::new(target[0] - c[0], target[1] - c[1], target[2] - c[2]).norm();
        if out.rejection.is_some() {
            self.rejected_cycles += 1;
        }
        if self.ctrl_contact_ms.is_none() && out.status == Status::Contact {
            self.ctrl_contact_ms = Some(k);
        }
        self.env_estimate_n_per_mm = out.env_stiffness_n_per_mm;
    }

    /// Books the truth after cycle `k`.
    fn truth(&mut self, k: u64, truth: &Truth) {
        self.max_force_n = self.max_force_n.max(truth.force_n);
        if self.first_true_contact.is_none() && truth.fn_true_n > 0.0 {
            self.first_true_contact = Some(k as usize);
        }
        let (pose, prev) = (truth.pose, self.prev_pose);
        if self.track_start.is_some() {
            if truth.fn_true_n <= 0.0 {
                self.contact_lost_ms += 1;
            }
            self.tracked_mm +=
                Vector3::new(pose[0] - prev[0], pose[1] - prev[1], pose[2] - prev[2]).norm();
        }
        self.prev_pose = pose;
        self.fn_true_n.push(truth.fn_true_n);
    }
}

/// Runs one experiment; with a recorder, every cycle is recorded on `/slave/force`,
/// `/slave/pose` and `/slave/contact`, stamped with the simulated time.
pub fn run(
    cfg: &ExperimentConfig,
    recorder: Option<&mut Recorder>,
) -> Result<Summary, ExperimentError> {
    run_with(cfg, recorder, &mut |_| true)
}

/// [`run`], calling `on_cycle(cycles run)` after every cycle (progress); when it returns
/// false the experiment stops there (interrupted) and the summary covers the cycles run.
pub fn run_with(
    cfg: &ExperimentConfig,
    mut recorder: Option<&mut Recorder>,
    on_cycle: &mut dyn FnMut(u64) -> bool,
) -> Result<Summary, ExperimentError> {
    cfg.validate()?;
    let p = cfg.surface.contact_point_mm;
    let start = Pose::new(p[0], p[1], p[2] + cfg.approach.gap_mm, 0.0);
    let target = [
        p[0],
        p[1],
        p[2] - cfg.approach.target_depth_mm,
        cfg.approach.theta_rad,
    ];
    let (mut arm, mut ctrl) = cfg.world().build(start, cfg.seed)?;
    let channels = match recorder.as_deref_mut() {
        Some(r) => Some(Channels::add(r)?),
        None => None,
    };

    let cycles = (cfg.duration_s * 1000.0).round() as u64;
    let velocity = Vector3::from(cfg.track.direction).normalize() * cfg.track.speed_mm_per_s;
    let mut trace = Trace::new(cycles, arm.true_pose());
    let wall = Instant::now();
    for k in 0..cycles {
        let reading = arm.read();
        let (setpoint, v) = trace.command(k, cfg, &velocity);
        let input = ControllerInput {
            actuators_mm: reading.actuators_mm,
            wrench: reading.wrench,
            command: SlaveCommand {
                mode: Mode::ForceGuided,
                pose: target,
                velocity: v,
                force_setpoint_n: setpoint,
                clutch: false,
            },
        };
        let out = ctrl.step(&input, 1e-3);
        trace.controller(k, &out, &target);
        arm.command(&out.actuators_cmd_mm);
        arm.advance(CYCLE_NS);
        let truth = Truth::of(&arm);
        trace.truth(k, &truth);
        if let (Some(r), Some(ch)) = (recorder.as_deref_mut(), channels.as_ref()) {
            ch.write(r, arm.time_ns(), &out, &truth, setpoint)?;
        }
        if !on_cycle(k + 1) {
            break;
        }
    }
    let wall_time_s = wall.elapsed().as_secs_f64();
    let env_true = arm.surface().material.stiffness_n_per_mm;
    let mut summary = metrics::summarise(cfg, &trace, env_true, wall_time_s);
    summary.verdict = metrics::judge(cfg, &trace, &summary);
    Ok(summary)
}
