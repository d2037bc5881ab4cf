//! A whole teleoperation session on the simulated clock: the operator's hand, the master arm
//! and its coupling, an impaired in-process link in each direction, the slave's passivity
//! port, the slave controller and the simulated H-4 arm, stepped in lockstep at 1 kHz. The
//! two sides share nothing but the link. A summary judges the run (with the stability
//! detector), and an MCAP recording can hold every cycle of both sides and the link's events.
//!
//! Every field of a session file is documented in `docs/sessions.md`.

use h4_shared::vec3::norm3;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;

use h4_shared::clock::{Clock, SimClock};
use h4_shared::config::{ArmConfig, ConfigError, Section, Validate, check_range};
use h4_shared::kinematics::Pose;
use h4_shared::passivity::PassivityParams;
use h4_shared::recording::{ChannelId, Recorder, RecordingError};
use h4_shared::rng::Rng;
use h4_shared::wire::{Command, Feedback, Mode};
use h4_slave::controller::{ControllerParams, SlaveController, Status};
use h4_slave::plant::{
    Material, MaterialPreset, PlantConfig, SensorConfig, SimArm, SimError, Surface, SurfaceShape,
};
use h4_slave::teleop::{SlaveTeleop, TeleopCycle, TeleopError, TeleopParams};
use h4_transport::Link;
use h4_transport::gate::{Gate, GateCounters};
use h4_transport::impair::{Impaired, ImpairmentConfig, LinkEvent};
use h4_transport::inproc::{self, InprocEnd};
use serde::{Deserialize, Serialize};

use crate::coupling::{CouplingMode, CouplingParams, MasterCoupling, MasterStep, ModelParams};
use crate::device::{HapticDevice, MasterArmConfig, SimMasterArm};
use crate::operator::{HandConfig, IntentError, IntentSegment, Operator, Script};

const CYCLE_NS: u64 = 1_000_000;
const DT_S: f64 = 1e-3;

/// The surface the slave touches.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvironmentConfig {
    /// `resin` (200 N/mm), `steel` (2000 N/mm) or `aluminium` (1000 N/mm).
    pub material: MaterialPreset,
    /// Overrides the material's contact stiffness, N/mm (0 = the material's).
    pub stiffness_n_per_mm: f64,
    /// Overrides the material's contact damping ratio (negative = the material's).
    pub damping_ratio: f64,
    /// Overrides the material's friction coefficient (negative = the material's).
    pub friction_coefficient: f64,
    /// A point of the (plane) surface, slave frame, mm.
    pub contact_point_mm: [f64; 3],
    /// Tilt of the surface normal about y, degrees.
    pub tilt_deg: f64,
    /// The slave starts this far above the contact point, mm.
    pub gap_mm: f64,
}

impl Default for EnvironmentConfig {
    fn default() -> Self {
        EnvironmentConfig {
            material: MaterialPreset::Resin,
            stiffness_n_per_mm: 0.0,
            damping_ratio: -1.0,
            friction_coefficient: -1.0,
            contact_point_mm: [0.0, 0.0, -250.0],
            tilt_deg: 0.0,
            gap_mm: 5.0,
        }
    }
}

impl EnvironmentConfig {
    /// The surface.
    pub fn surface(&self) -> Surface {
        let m = self.material.material();
        let material = Material {
            stiffness_n_per_mm: if self.stiffness_n_per_mm > 0.0 {
                self.stiffness_n_per_mm
            } else {
                m.stiffness_n_per_mm
            },
            damping_ratio: if self.damping_ratio >= 0.0 {
                self.damping_ratio
            } else {
                m.damping_ratio
            },
            friction_coefficient: if self.friction_coefficient >= 0.0 {
                self.friction_coefficient
            } else {
                m.friction_coefficient
            },
        };
        let t = self.tilt_deg.to_radians();
        Surface {
            shape: SurfaceShape::Plane {
                point_mm: self.contact_point_mm,
                normal: [t.sin(), 0.0, t.cos()],
            },
            material,
        }
    }
}

/// Passivity control (`passivity.*`): the same settings on both sides.
pub type PassivityConfig = PassivityParams;

/// The coupling.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CouplingConfig {
    /// `position-force` or `force-guided`.
    pub mode: CouplingMode,
    /// Largest force rendered to the operator, N.
    pub force_limit_n: f64,
    /// Feedback silence after which the rendered force fades, ms.
    pub feedback_timeout_ms: f64,
    /// Duration of the fade, ms.
    pub fade_ms: f64,
    /// Force-guided: stiffness of the virtual spring the operator pushes, N/mm.
    pub guide_stiffness_n_per_mm: f64,
    /// Force-guided: largest contact-force set-point, N.
    pub guide_setpoint_max_n: f64,
    /// Force-guided: how far beyond the surface the slave's approach target lies, mm.
    pub guide_approach_depth_mm: f64,
    /// Local damping the master renders against the handle's velocity (position–force),
    /// N·s/mm.
    pub master_damping_n_s_per_mm: f64,
    /// Cut-off of the first-order low-pass on the slave force rendered (position–force), Hz
    /// (0: unfiltered).
    pub force_filter_hz: f64,
    /// Model-mediated rendering (position–force): a local model of the slave's contact.
    pub model: bool,
    /// Largest stiffness the local model renders at the handle, N/mm.
    pub model_stiffness_max_n_per_mm: f64,
    /// Stiffness the model assumes before its first estimate, N/mm at the slave.
    pub model_stiffness_initial_n_per_mm: f64,
    /// Slave force above which feedback counts as contact for the model, N.
    pub model_contact_n: f64,
    /// Forgetting time constant of the model's stiffness estimator, s.
    pub model_estimator_time_constant_s: f64,
    /// Largest speed at which the model's plane pushes the handle out, mm/s at the slave.
    pub model_plane_rate_mm_per_s: f64,
    /// Feedback silence after which the model's force fades out, ms.
    pub model_hold_ms: f64,
}

impl Default for CouplingConfig {
    fn default() -> Self {
        CouplingConfig {
            mode: CouplingMode::PositionForce,
            force_limit_n: 30.0,
            feedback_timeout_ms: 100.0,
            fade_ms: 50.0,
            guide_stiffness_n_per_mm: 1.0,
            guide_setpoint_max_n: 50.0,
            guide_approach_depth_mm: 20.0,
            master_damping_n_s_per_mm: 0.3,
            force_filter_hz: 0.0,
            model: ModelParams::default().enabled,
            model_stiffness_max_n_per_mm: ModelParams::default().stiffness_max_n_per_mm,
            model_stiffness_initial_n_per_mm: ModelParams::default().stiffness_initial_n_per_mm,
            model_contact_n: ModelParams::default().contact_n,
            model_estimator_time_constant_s: ModelParams::default().estimator_time_constant_s,
            model_plane_rate_mm_per_s: ModelParams::default().plane_rate_mm_per_s,
            model_hold_ms: ModelParams::default().hold_ms,
        }
    }
}

/// Motion and force scaling.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScaleConfig {
    /// Slave translation per master translation.
    pub motion: f64,
    /// Master force per slave force.
    pub force: f64,
}

impl Default for ScaleConfig {
    fn default() -> Self {
        ScaleConfig {
            motion: 1.0,
            force: 0.5,
        }
    }
}

/// The operator.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OperatorConfig {
    /// The hand.
    pub hand: HandConfig,
    /// The scripted intent (ignored when `replay_file` is set).
    pub intent: Vec<IntentSegment>,
    /// A recorded master trajectory to replay instead (JSON lines), relative to the
    /// session file.
    pub replay_file: Option<PathBuf>,
}

/// The slave side.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlaveConfig {
    /// The slave arm.
    pub arm: ArmConfig,
    /// The simulated arm.
    pub plant: PlantConfig,
    /// The force sensor.
    pub sensor: SensorConfig,
    /// The slave controller.
    pub controller: ControllerParams,
    /// Command silence after which the slave holds, ms.
    pub command_timeout_ms: f64,
}

impl Default for SlaveConfig {
    fn default() -> Self {
        SlaveConfig {
            arm: ArmConfig::default(),
            plant: PlantConfig::default(),
            sensor: SensorConfig::default(),
            controller: ControllerParams::default(),
            command_timeout_ms: 500.0,
        }
    }
}

/// The stability detector.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Contact force above which the tool counts as in contact, N.
    pub contact_threshold_n: f64,
    /// Time constant of the moving mean the oscillation is measured around, s.
    pub mean_time_constant_s: f64,
    /// Contact time skipped after the start of each contact episode, s.
    pub settle_s: f64,
    /// Contact lost for less than this and regained is one episode (a bounce), s.
    pub contact_gap_s: f64,
    /// An episode shorter than `settle_s` whose force reaches this is an impact, N.
    pub impact_force_n: f64,
    /// Impacts less than this apart are in a row (one bouncing run), s.
    pub bounce_gap_s: f64,
    /// This many impacts in a row or more is sustained bouncing: unstable.
    pub bounce_limit: u64,
    /// Length of the early and late windows of contact, s.
    pub window_s: f64,
    /// Late-contact oscillation (RMS around the moving mean) above which the run is unstable, N.
    pub oscillation_limit_n: f64,
    /// Oscillation growth (late over early) above which the run is unstable.
    pub growth_limit: f64,
    /// Floor of the early oscillation in the growth ratio, N (sensor noise).
    pub oscillation_floor_n: f64,
    /// Observer energy below −this is unstable, J.
    pub energy_tolerance_j: f64,
    /// Contact force above which the run is unstable, N.
    pub force_limit_n: f64,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            contact_threshold_n: 0.5,
            mean_time_constant_s: 0.1,
            settle_s: 0.5,
            contact_gap_s: 0.25,
            impact_force_n: 2.0,
            bounce_gap_s: 2.0,
            bounce_limit: 4,
            window_s: 2.0,
            oscillation_limit_n: 1.5,
            growth_limit: 3.0,
            oscillation_floor_n: 0.5,
            energy_tolerance_j: 0.01,
            force_limit_n: 100.0,
        }
    }
}

/// One session, as read from a TOML file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionConfig {
    /// Free-text name.
    #[serde(default)]
    pub name: String,
    /// Seed of every random draw (sensor noise, link impairment).
    pub seed: u64,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Impairment of each direction of the link (`link.seed` is mixed with `seed`).
    #[serde(default)]
    pub link: ImpairmentConfig,
    /// The surface.
    #[serde(default)]
    pub environment: EnvironmentConfig,
    /// Passivity control.
    #[serde(default)]
    pub passivity: PassivityConfig,
    /// The coupling.
    #[serde(default)]
    pub coupling: CouplingConfig,
    /// Scaling.
    #[serde(default)]
    pub scale: ScaleConfig,
    /// The master arm.
    #[serde(default)]
    pub master: MasterArmConfig,
    /// The operator.
    #[serde(default)]
    pub operator: OperatorConfig,
    /// The slave.
    #[serde(default)]
    pub slave: SlaveConfig,
    /// The stability detector.
    #[serde(default)]
    pub detector: DetectorConfig,
}

impl Validate for SessionConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        check_range("duration_s", self.duration_s, 0.01, 3600.0, "s")?;
        self.link.validate_at("link.")?;
        let e = &self.environment;
        if e.stiffness_n_per_mm != 0.0 {
            check_range(
                "environment.stiffness_n_per_mm",
                e.stiffness_n_per_mm,
                0.1,
                1e5,
                "N/mm (0 = the material's)",
            )?;
        }
        check_range(
            "environment.damping_ratio",
            e.damping_ratio,
            -1.0,
            2.0,
            "(negative = the material's)",
        )?;
        check_range(
            "environment.friction_coefficient",
            e.friction_coefficient,
            -1.0,
            2.0,
            "(negative = the material's)",
        )?;
        for (i, v) in e.contact_point_mm.iter().enumerate() {
            check_range(
                &format!("environment.contact_point_mm[{i}]"),
                *v,
                -1e3,
                1e3,
                "mm",
            )?;
        }
        check_range("environment.tilt_deg", e.tilt_deg, -45.0, 45.0, "deg")?;
        check_range("environment.gap_mm", e.gap_mm, 0.0, 100.0, "mm")?;
        self.passivity.validate_at("passivity.")?;
        let c = &self.coupling;
        check_range("coupling.force_limit_n", c.force_limit_n, 0.0, 200.0, "N")?;
        check_range(
            "coupling.feedback_timeout_ms",
            c.feedback_timeout_ms,
            1.0,
            1e5,
            "ms",
        )?;
        check_range("coupling.fade_ms", c.fade_ms, 1.0, 1e4, "ms")?;
        check_range(
            "coupling.guide_stiffness_n_per_mm",
            c.guide_stiffness_n_per_mm,
            0.01,
            100.0,
            "N/mm",
        )?;
        check_range(
            "coupling.guide_setpoint_max_n",
            c.guide_setpoint_max_n,
            0.0,
            self.slave.controller.force_limit_n,
            "N (up to slave.controller.force_limit_n)",
        )?;
        check_range(
            "coupling.master_damping_n_s_per_mm",
            c.master_damping_n_s_per_mm,
            0.0,
            1.0,
            "N·s/mm",
        )?;
        check_range(
            "coupling.force_filter_hz",
            c.force_filter_hz,
            0.0,
            500.0,
            "Hz",
        )?;
        check_range(
            "coupling.model_stiffness_max_n_per_mm",
            c.model_stiffness_max_n_per_mm,
            0.01,
            1000.0,
            "N/mm",
        )?;
        check_range(
            "coupling.model_stiffness_initial_n_per_mm",
            c.model_stiffness_initial_n_per_mm,
            0.01,
            1e4,
            "N/mm",
        )?;
        check_range(
            "coupling.model_contact_n",
            c.model_contact_n,
            0.01,
            100.0,
            "N",
        )?;
        check_range(
            "coupling.model_estimator_time_constant_s",
            c.model_estimator_time_constant_s,
            0.001,
            100.0,
            "s",
        )?;
        check_range(
            "coupling.model_plane_rate_mm_per_s",
            c.model_plane_rate_mm_per_s,
            0.0,
            1e4,
            "mm/s",
        )?;
        check_range("coupling.model_hold_ms", c.model_hold_ms, 1.0, 1e5, "ms")?;
        check_range(
            "coupling.guide_approach_depth_mm",
            c.guide_approach_depth_mm,
            0.0,
            100.0,
            "mm",
        )?;
        check_range("scale.motion", self.scale.motion, 0.01, 100.0, "")?;
        check_range("scale.force", self.scale.force, 0.01, 100.0, "")?;
        let m = &self.master;
        m.geometry.validate().map_err(|e| ConfigError::OutOfRange {
            field: "master.geometry".into(),
            value: String::new(),
            allowed: e.to_string(),
        })?;
        for (i, v) in m.home_pose.iter().enumerate() {
            check_range(&format!("master.home_pose[{i}]"), *v, -1e3, 1e3, "mm / rad")?;
        }
        check_range(
            "master.carriage_mass_kg",
            m.carriage_mass_kg,
            0.001,
            100.0,
            "kg",
        )?;
        check_range(
            "master.handle_mass_kg",
            m.handle_mass_kg,
            0.001,
            100.0,
            "kg",
        )?;
        check_range(
            "master.handle_inertia_kg_mm2",
            m.handle_inertia_kg_mm2,
            0.1,
            1e6,
            "kg·mm²",
        )?;
        check_range(
            "master.coulomb_friction_n",
            m.coulomb_friction_n,
            0.0,
            100.0,
            "N",
        )?;
        check_range(
            "master.viscous_friction_n_s_per_mm",
            m.viscous_friction_n_s_per_mm,
            0.0,
            10.0,
            "N·s/mm",
        )?;
        check_range(
            "master.friction_velocity_mm_per_s",
            m.friction_velocity_mm_per_s,
            0.01,
            100.0,
            "mm/s",
        )?;
        check_range(
            "master.motor_force_max_n",
            m.motor_force_max_n,
            0.0,
            1e3,
            "N",
        )?;
        check_range("master.substeps", f64::from(m.substeps), 1.0, 1000.0, "")?;
        let h = &self.operator.hand;
        check_range(
            "operator.hand.hand_mass_kg",
            h.hand_mass_kg,
            0.01,
            10.0,
            "kg",
        )?;
        check_range(
            "operator.hand.arm_stiffness_n_per_mm",
            h.arm_stiffness_n_per_mm,
            0.0,
            100.0,
            "N/mm",
        )?;
        check_range(
            "operator.hand.arm_damping_n_s_per_mm",
            h.arm_damping_n_s_per_mm,
            0.0,
            10.0,
            "N·s/mm",
        )?;
        check_range(
            "operator.hand.grip_stiffness_n_per_mm",
            h.grip_stiffness_n_per_mm,
            0.01,
            20.0,
            "N/mm",
        )?;
        check_range(
            "operator.hand.grip_damping_n_s_per_mm",
            h.grip_damping_n_s_per_mm,
            0.0,
            10.0,
            "N·s/mm",
        )?;
        if self.operator.replay_file.is_none() {
            Script::Segments(self.operator.intent.clone())
                .validate()
                .map_err(|e| ConfigError::OutOfRange {
                    field: "operator.intent".into(),
                    value: String::new(),
                    allowed: e.to_string(),
                })?;
        }
        self.slave.arm.validate_at("slave.arm.")?;
        check_range(
            "slave.command_timeout_ms",
            self.slave.command_timeout_ms,
            1.0,
            1e5,
            "ms",
        )?;
        let sc = &self.slave.controller;
        check_range(
            "slave.controller.force_limit_n",
            sc.force_limit_n,
            1.0,
            1000.0,
            "N",
        )?;
        check_range(
            "slave.controller.max_speed_mm_per_s",
            sc.max_speed_mm_per_s,
            1.0,
            1000.0,
            "mm/s",
        )?;
        check_range(
            "slave.plant.servo_rate_hz",
            self.slave.plant.servo_rate_hz,
            1000.0,
            1e5,
            "Hz",
        )?;
        check_range(
            "slave.sensor.sample_rate_hz",
            self.slave.sensor.sample_rate_hz,
            100.0,
            1e5,
            "Hz",
        )?;
        let d = &self.detector;
        check_range(
            "detector.contact_threshold_n",
            d.contact_threshold_n,
            0.01,
            100.0,
            "N",
        )?;
        check_range(
            "detector.mean_time_constant_s",
            d.mean_time_constant_s,
            0.001,
            10.0,
            "s",
        )?;
        check_range("detector.settle_s", d.settle_s, 0.0, 100.0, "s")?;
        check_range("detector.contact_gap_s", d.contact_gap_s, 0.0, 100.0, "s")?;
        check_range("detector.impact_force_n", d.impact_force_n, 0.0, 1e4, "N")?;
        check_range("detector.bounce_gap_s", d.bounce_gap_s, 0.0, 100.0, "s")?;
        check_range(
            "detector.bounce_limit",
            d.bounce_limit as f64,
            2.0,
            1e6,
            "impacts in a row",
        )?;
        check_range("detector.window_s", d.window_s, 0.05, 100.0, "s")?;
        check_range(
            "detector.oscillation_limit_n",
            d.oscillation_limit_n,
            0.0,
            1e3,
            "N",
        )?;
        check_range("detector.growth_limit", d.growth_limit, 0.0, 1e3, "")?;
        check_range(
            "detector.oscillation_floor_n",
            d.oscillation_floor_n,
            0.0,
            100.0,
            "N",
        )?;
        check_range(
            "detector.energy_tolerance_j",
            d.energy_tolerance_j,
            0.0,
            1e3,
            "J",
        )?;
        check_range("detector.force_limit_n", d.force_limit_n, 0.0, 1e4, "N")?;
        Ok(())
    }
}

/// Why a session could not run.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The configuration is not usable.
    #[error("{0}")]
    Config(#[from] ConfigError),
    /// The operator's script or replay file.
    #[error("{0}")]
    Intent(#[from] IntentError),
    /// The simulated slave could not be built.
    #[error("slave simulation: {0}")]
    Sim(#[from] SimError),
    /// The master arm could not be built.
    #[error("master arm: {0}")]
    Master(h4_shared::KinError),
    /// The recording failed.
    #[error("{0}")]
    Recording(#[from] RecordingError),
    /// The slave's endpoint could not be built.
    #[error("{0}")]
    Teleop(#[from] TeleopError),
    /// The link failed.
    #[error("link: {0}")]
    Link(#[from] h4_transport::LinkError),
}

/// Loads a session file with `--set` overrides; a relative `operator.replay_file` is
/// resolved against the session file's directory.
pub fn load(path: &Path, overrides: &[String]) -> Result<SessionConfig, SessionError> {
    let mut cfg: SessionConfig = h4_shared::config::load(path, overrides)?;
    if let Some(rf) = &cfg.operator.replay_file
        && rf.is_relative()
        && let Some(dir) = path.parent()
    {
        cfg.operator.replay_file = Some(dir.join(rf));
    }
    Ok(cfg)
}

/// The result of one session.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// The session's name.
    pub name: String,
    /// The detector's verdict: no growing or sustained oscillation in contact, observers
    /// within tolerance, forces within limits, nothing diverged.
    pub stable: bool,
    /// Why the detector said unstable (empty when stable).
    pub unstable_reasons: Vec<String>,
    /// Lowest energy of the passivity observers (master and slave ports), J.
    pub energy_min_j: f64,
    /// Largest contact force at the slave (simulation truth), N.
    pub max_force_n: f64,
    /// Largest force rendered to the operator, N.
    pub max_master_force_n: f64,
    /// Chatter of the force rendered to the operator: the largest RMS, over any
    /// `CHATTER_WINDOW_MS` (100 ms) window, of the cycle-to-cycle change of the rendered
    /// force vector (|F_k − F_{k−1}|), N per cycle. A smooth push changes it by a fraction of
    /// a newton per cycle; a handle whose velocity flips sign every cycle under too much
    /// damping swings it by tens of newtons.
    pub master_force_chatter_n: f64,
    /// Contact-force oscillation late in contact over early (RMS around the moving mean);
    /// < 1 means decaying.
    pub oscillation_growth: f64,
    /// Contact-force oscillation early in contact, N RMS.
    pub oscillation_early_n: f64,
    /// Contact-force oscillation late in contact, N RMS.
    pub oscillation_late_n: f64,
    /// Position drift the slave's passivity controller left (commanded minus desired slave
    /// position), mean over the last 0.5 s of contact, mm.
    pub position_drift_mm: f64,
    /// Largest position drift during the run, mm.
    pub position_drift_max_mm: f64,
    /// |F_master / scale.force − F_slave| over |F_slave|, steady contact, %.
    pub force_transparency_err_pct: f64,
    /// RMS of |slave measured − slave desired position| in free space, mm.
    pub position_tracking_err_mm: f64,
    /// Energy dissipated by both passivity controllers, J.
    pub passivity_dissipated_j: f64,
    /// Messages lost in both directions (loss, blackouts, overflow).
    pub packets_lost: u64,
    /// Messages the receive gates rejected (duplicates, reordered).
    pub packets_rejected: u64,
    /// Mean round-trip time measured by the master from the echoed send times, ms.
    pub rtt_mean_ms: f64,
    /// Settled contact time (contact episodes after `detector.settle_s`), s.
    pub contact_time_s: f64,
    /// Times the tool lost and regained contact within `detector.contact_gap_s` (bounces).
    pub contact_bounces: u64,
    /// The most impacts in a row (touches shorter than `detector.settle_s` reaching
    /// `detector.impact_force_n`, each within `detector.bounce_gap_s` of the last).
    pub bouncing_impacts: u64,
    /// Cycles whose command the slave controller rejected.
    pub slave_rejected_cycles: u64,
    /// Control cycles run (1 ms each, both sides).
    pub cycles: u64,
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Wall-clock time of the simulation, s (the only field that is not deterministic).
    pub wall_time_s: f64,
}

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

struct Channels {
    master: ChannelId,
    slave: ChannelId,
    link: ChannelId,
}

type MasterEnd = Impaired<InprocEnd<Command, Feedback>, SimClock, Command, Feedback>;
type SlaveEnd = Impaired<InprocEnd<Feedback, Command>, SimClock, Feedback, Command>;

/// The master side of the session: device, operator, gate, coupling.
pub struct MasterSide {
    /// The simulated master arm.
    pub device: SimMasterArm,
    /// The operator.
    pub operator: Operator,
    gate: Gate<Feedback>,
    /// The coupling.
    pub coupling: MasterCoupling,
    rtt_sum_ms: f64,
    rtt_n: u64,
}

/// What the master side did this cycle.
#[derive(Clone, Copy, Debug)]
pub struct MasterCycle {
    /// The coupling's step.
    pub step: MasterStep,
    /// The wrench the device applied.
    pub rendered: [f64; 4],
    /// Device state.
    pub device: crate::device::DeviceState,
    /// The hand.
    pub hand: crate::operator::HandOutput,
}

impl MasterSide {
    /// The same side speaking for arm `arm_id`: its commands carry it and its gate rejects
    /// another arm's feedback.
    pub fn for_arm(mut self, arm_id: u16) -> Self {
        self.gate = Gate::new(arm_id, 1_000_000_000);
        self.coupling.set_arm_id(arm_id);
        self
    }

    /// What the receive gate accepted and rejected.
    pub fn gate_counters(&self) -> &GateCounters {
        &self.gate.counters
    }

    /// One master cycle at `now_ns`.
    pub fn step<L: Link<Command, Feedback>>(
        &mut self,
        link: &mut L,
        now_ns: u64,
    ) -> Result<MasterCycle, SessionError> {
        let before = self.device.read();
        let hand = self
            .operator
            .step(now_ns as f64 * 1e-9, &before.pose, &before.velocity, DT_S);
        self.device.set_hand(hand.wrench, hand.clutch);
        let dev = self.device.read();
        while let Some(fb) = link.try_recv()? {
            if let Ok(f) = self.gate.accept(&fb, now_ns) {
                self.coupling.receive(&f, now_ns);
                if f.echo_send_time_ns > 0 {
                    self.rtt_sum_ms += now_ns.saturating_sub(f.echo_send_time_ns) as f64 * 1e-6;
                    self.rtt_n += 1;
                }
            }
        }
        let step = self.coupling.step(&dev, now_ns, DT_S);
        let rendered = self.device.write_wrench(&step.wrench);
        let cmd = self.coupling.finish(&rendered, &dev, now_ns);
        link.publish(&cmd)?;
        Ok(MasterCycle {
            step,
            rendered,
            device: dev,
            hand,
        })
    }
}

/// A session ready to run: both sides and the link.
pub struct Session {
    cfg: SessionConfig,
    clock: SimClock,
    /// The master side.
    pub master: MasterSide,
    /// The slave side.
    pub slave: SlaveTeleop<SimArm>,
    master_end: MasterEnd,
    slave_end: SlaveEnd,
}

impl Session {
    /// Builds a session from a validated configuration.
    pub fn new(cfg: &SessionConfig) -> Result<Self, SessionError> {
        cfg.validate()?;
        let script = match &cfg.operator.replay_file {
            Some(path) => Script::load_replay(path)?,
            None => Script::Segments(cfg.operator.intent.clone()),
        };
        script.validate()?;
        let clock = SimClock::new();
        let (m_end, s_end) = inproc::pair(1024);
        let mut rng = Rng::fork(cfg.seed, cfg.link.seed);
        let mut down = cfg.link;
        down.seed = rng.next_u64();
        let mut up = cfg.link;
        up.seed = rng.next_u64();
        let master_end = Impaired::new(m_end, clock.clone(), down, CYCLE_NS)?;
        let slave_end = Impaired::new(s_end, clock.clone(), up, CYCLE_NS)?;

        let env = &cfg.environment;
        let ws = cfg.slave.arm.workspace();
        let assumed = cfg.slave.arm.stiffness().map_err(SimError::from)?;
        let p = env.contact_point_mm;
        let slave_home = [p[0], p[1], p[2] + env.gap_mm, 0.0];
        let arm = SimArm::new(
            ws.params,
            cfg.slave.arm.actuator_stiffness_n_per_mm,
            cfg.slave.plant,
            cfg.slave.sensor,
            env.surface(),
            Pose::from(slave_home),
            cfg.seed,
        )?;
        let ctrl = SlaveController::new(ws, assumed, cfg.slave.controller);
        let pc = &cfg.passivity;
        let slave = SlaveTeleop::new(
            TeleopParams {
                arm_id: 0,
                watchdog_ms: cfg.slave.command_timeout_ms,
                restart_silence_ms: 1000.0,
                passivity: *pc,
                speed_margin: 0.9,
            },
            ctrl,
            arm,
            CYCLE_NS,
        )?;
        let device = SimMasterArm::new(cfg.master).map_err(SessionError::Master)?;
        let operator = Operator::new(cfg.operator.hand, script, cfg.master.home_pose);
        let coupling = MasterCoupling::new(CouplingParams {
            mode: cfg.coupling.mode,
            motion_scale: cfg.scale.motion,
            force_scale: cfg.scale.force,
            slave_workspace: ws,
            slave_anchor: slave_home,
            force_limit_n: cfg.coupling.force_limit_n,
            slave_speed_limit_mm_per_s: cfg.slave.controller.max_speed_mm_per_s * 0.9,
            feedback_timeout_ms: cfg.coupling.feedback_timeout_ms,
            fade_ms: cfg.coupling.fade_ms,
            passivity: pc.enabled,
            passivity_params: *pc,
            guide_stiffness_n_per_mm: cfg.coupling.guide_stiffness_n_per_mm,
            guide_setpoint_max_n: cfg.coupling.guide_setpoint_max_n,
            guide_approach_depth_mm: cfg.coupling.guide_approach_depth_mm,
            master_damping_n_s_per_mm: cfg.coupling.master_damping_n_s_per_mm,
            force_filter_hz: cfg.coupling.force_filter_hz,
            model: ModelParams {
                enabled: cfg.coupling.model,
                stiffness_max_n_per_mm: cfg.coupling.model_stiffness_max_n_per_mm,
                stiffness_initial_n_per_mm: cfg.coupling.model_stiffness_initial_n_per_mm,
                contact_n: cfg.coupling.model_contact_n,
                estimator_time_constant_s: cfg.coupling.model_estimator_time_constant_s,
                plane_rate_mm_per_s: cfg.coupling.model_plane_rate_mm_per_s,
                hold_ms: cfg.coupling.model_hold_ms,
            },
            arm_id: 0,
        });
        let master = MasterSide {
            device,
            operator,
            gate: Gate::new(0, 1_000_000_000),
            coupling,
            rtt_sum_ms: 0.0,
            rtt_n: 0,
        };
        Ok(Session {
            cfg: cfg.clone(),
            clock,
            master,
            slave,
            master_end,
            slave_end,
        })
    }

    /// One lockstep cycle: master step, slave step, physics of both arms, clock + 1 ms.
    pub fn cycle(&mut self) -> Result<(MasterCycle, TeleopCycle), SessionError> {
        let now = self.clock.now_ns();
        let m = self.master.step(&mut self.master_end, now)?;
        let s = self.slave.step(&mut self.slave_end, now, DT_S);
        self.master.device.advance(CYCLE_NS);
        self.slave.arm_mut().advance(CYCLE_NS);
        self.clock.advance_ns(CYCLE_NS);
        Ok((m, s))
    }

    /// Runs the whole session; with a recorder every cycle of both sides and every link
    /// event is recorded.
    pub fn run(mut self, mut recorder: Option<&mut Recorder>) -> Result<Summary, SessionError> {
        let cfg = self.cfg.clone();
        let channels = match recorder.as_deref_mut() {
            Some(r) => Some(Channels {
                master: r.add_channel("/master/cycle", "h4.MasterCycle", MASTER_SCHEMA)?,
                slave: r.add_channel("/slave/cycle", "h4.SlaveCycle", SLAVE_SCHEMA)?,
                link: r.add_channel("/link/events", "h4.LinkEvent", LINK_SCHEMA)?,
            }),
            None => None,
        };
        let cycles = (cfg.duration_s * 1000.0).round() as u64;
        let det = cfg.detector;
        let force_scale = cfg.scale.force;
        let mut ev = Evaluator::new(det, cycles as usize);
        let wall = Instant::now();
        for _ in 0..cycles {
            let t_ns = self.clock.now_ns();
            let (m, s) = self.cycle()?;
            let true_w = self.slave.arm().true_contact_wrench();
            let true_f = [true_w[0], true_w[1], true_w[2]];
            let intent = m.hand.intent;
            let meas = s.out.measured_pose;
            ev.push(Sample {
                true_force_n: norm3(&true_f),
                master_force_n: norm3(&m.rendered),
                master_force_vec_n: [m.rendered[0], m.rendered[1], m.rendered[2]],
                transparency_abs_n: {
                    let mut d = [0.0; 3];
                    for (i, di) in d.iter_mut().enumerate() {
                        *di = m.rendered[i] / force_scale - s.out.wrench_measured[i];
                    }
                    norm3(&d)
                },
                slave_force_n: norm3(&s.out.wrench_measured),
                steady: intent.steady && !intent.clutch && !m.device.clutch,
                observed_min_j: m.step.observed_j.min(s.port.observed_j),
                drift_mm: {
                    // The master–slave mismatch: the slave's own drift plus the offset the
                    // master's contact model put into the target.
                    let o = self.master.coupling.model_offset_mm();
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
                finite: m.device.pose.iter().all(|v| v.is_finite())
                    && meas.iter().all(|v| v.is_finite()),
            });
            if let (Some(r), Some(ch)) = (recorder.as_deref_mut(), channels.as_ref()) {
                let t = t_ns + CYCLE_NS;
                let me = self.master.coupling.port.energy;
                r.write(
                    ch.master,
                    t,
                    &MasterMsg {
                        pose: m.device.pose,
                        velocity: m.device.velocity,
                        hand_wrench: m.hand.wrench,
                        intent_target_mm: intent.target_mm,
                        clutch: m.device.clutch,
                        link_force_n: m.step.link_force_n,
                        rendered_wrench: m.rendered,
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
                let se = self.slave.port().energy;
                let tp = self.slave.arm().true_pose();
                r.write(
                    ch.slave,
                    t,
                    &SlaveMsg {
                        desired_mm: s.desired_mm,
                        commanded_pose: s.out.commanded_pose,
                        measured_pose: meas,
                        true_pose: [tp[0], tp[1], tp[2], tp[3]],
                        wrench_measured: s.out.wrench_measured,
                        true_force_n: true_f,
                        status: s.out.status.code(),
                        admittance_mm_per_n_s: s.port.admittance_mm_per_n_s,
                        observed_j: s.port.observed_j,
                        drift_mm: s.drift_mm,
                        energy_in_j: se.in_j,
                        energy_out_j: se.out_j,
                        dissipated_j: se.dissipated_j,
                    },
                )?;
                let mut result = Ok(());
                let link_ch = ch.link;
                self.master_end.drain_events(|e| {
                    if result.is_ok() {
                        result = r.write(
                            link_ch,
                            e.time_ns.max(1),
                            &LinkMsg {
                                direction: "command",
                                event: *e,
                            },
                        );
                    }
                });
                result?;
                let mut result = Ok(());
                self.slave_end.drain_events(|e| {
                    if result.is_ok() {
                        result = r.write(
                            link_ch,
                            e.time_ns.max(1),
                            &LinkMsg {
                                direction: "feedback",
                                event: *e,
                            },
                        );
                    }
                });
                result?;
            }
        }
        let wall_time_s = wall.elapsed().as_secs_f64();
        let dissipated =
            self.master.coupling.port.energy.dissipated_j + self.slave.port().energy.dissipated_j;
        let lost = self.master_end.counters.dropped() + self.slave_end.counters.dropped();
        let rejected = self.master.gate.counters.rejected() + self.slave.gate_counters().rejected();
        let rtt = if self.master.rtt_n > 0 {
            self.master.rtt_sum_ms / self.master.rtt_n as f64
        } else {
            f64::NAN
        };
        Ok(ev.finish(
            cfg.name.clone(),
            dissipated,
            lost,
            rejected,
            rtt,
            cycles,
            wall_time_s,
        ))
    }
}

/// Runs a session from its configuration.
pub fn run(cfg: &SessionConfig, recorder: Option<&mut Recorder>) -> Result<Summary, SessionError> {
    Session::new(cfg)?.run(recorder)
}

/// Window of [`Summary::master_force_chatter_n`], cycles (1 ms each).
const CHATTER_WINDOW_MS: usize = 100;

struct Sample {
    true_force_n: f64,
    master_force_n: f64,
    master_force_vec_n: [f64; 3],
    transparency_abs_n: f64,
    slave_force_n: f64,
    steady: bool,
    observed_min_j: f64,
    drift_mm: f64,
    tracking_err_mm: f64,
    free_motion: bool,
    rejected: bool,
    finite: bool,
}

/// Contact episodes: runs of cycles with the contact force above `threshold_n`, runs less
/// than `gap` cycles apart joined into one (the cycles between them belong to it: a tool
/// that bounces on and off the surface is one contact, and its bounces are oscillation).
/// Returns the episodes and the number of joins (bounces).
fn contact_episodes(force_n: &[f64], threshold_n: f64, gap: usize) -> (Vec<Range<usize>>, u64) {
    let mut episodes: Vec<Range<usize>> = Vec::new();
    let mut bounces = 0;
    let mut k = 0;
    while k < force_n.len() {
        if force_n[k] <= threshold_n {
            k += 1;
            continue;
        }
        let start = k;
        while k < force_n.len() && force_n[k] > threshold_n {
            k += 1;
        }
        match episodes.last_mut() {
            Some(last) if start - last.end < gap => {
                last.end = k;
                bounces += 1;
            }
            _ => episodes.push(start..k),
        }
    }
    (episodes, bounces)
}

/// The longest run of impacts in a row: episodes shorter than `settle` cycles whose force
/// reaches `impact_force_n`, each starting less than `gap` cycles after the last one ended
/// (a tool bouncing off the surface while the operator pushes: each touch too short to
/// settle, so the oscillation measure never sees it).
fn bouncing_impacts(
    force_n: &[f64],
    episodes: &[Range<usize>],
    settle: usize,
    impact_force_n: f64,
    gap: usize,
) -> u64 {
    let mut best = 0;
    let mut run = 0;
    let mut last_end: Option<usize> = None;
    for e in episodes {
        let impact = e.len() < settle && force_n[e.clone()].iter().any(|&f| f >= impact_force_n);
        if !impact {
            run = 0;
            last_end = None;
            continue;
        }
        run = match last_end {
            Some(end) if e.start - end < gap => run + 1,
            _ => 1,
        };
        last_end = Some(e.end);
        best = best.max(run);
    }
    best
}

/// The contact force's oscillation: for each sample of an episode past its first `settle`
/// cycles, the force minus its zero-phase moving mean. The mean is a first-order low-pass
/// (`tau_s`) run forwards then backwards over one episode at a time, the episode extended at
/// both ends by odd reflection, so that a ramp (a push, a release) leaves no residual; an
/// oscillation of frequency f leaves (2πfτ)² / (1 + (2πfτ)²) of its amplitude. Also returns,
/// for each residual, its cycle.
fn contact_residuals(
    force_n: &[f64],
    episodes: &[Range<usize>],
    settle: usize,
    tau_s: f64,
) -> Vec<(usize, f64)> {
    let a = (DT_S / tau_s.max(DT_S)).min(1.0);
    let mut out = Vec::with_capacity(force_n.len());
    let mut ext = Vec::new();
    for e in episodes {
        let seg = &force_n[e.clone()];
        let len = seg.len();
        let pad = ((5.0 * tau_s / DT_S).ceil() as usize).min(len - 1);
        let (first, last) = (seg[0], seg[len - 1]);
        ext.clear();
        ext.extend((1..=pad).rev().map(|k| 2.0 * first - seg[k]));
        ext.extend_from_slice(seg);
        ext.extend((1..=pad).map(|k| 2.0 * last - seg[len - 1 - k]));
        for i in 1..ext.len() {
            ext[i] = ext[i - 1] + a * (ext[i] - ext[i - 1]);
        }
        for i in (0..ext.len() - 1).rev() {
            ext[i] = ext[i + 1] + a * (ext[i] - ext[i + 1]);
        }
        for (j, f) in seg.iter().enumerate().skip(settle) {
            out.push((e.start + j, f - ext[pad + j]));
        }
    }
    out
}

/// Summary statistics, accumulated per cycle (the per-cycle buffers are allocated once).
struct Evaluator {
    det: DetectorConfig,
    /// True contact force of every cycle, N (contact episodes and their oscillation are
    /// found at the end: [`contact_episodes`], [`contact_residuals`]).
    force_n: Vec<f64>,
    /// Position drift of every cycle, mm.
    drift_mm: Vec<f64>,
    steady_s: f64,
    energy_min: f64,
    max_force: f64,
    max_master: f64,
    chatter_ring: Vec<f64>,
    chatter_sum: f64,
    chatter_k: usize,
    chatter_max: f64,
    prev_master_n: Option<[f64; 3]>,
    trans_abs: f64,
    trans_ref: f64,
    track_sq: f64,
    track_n: u64,
    drift_max: f64,
    rejected: u64,
    diverged: bool,
}

impl Evaluator {
    fn new(det: DetectorConfig, cycles: usize) -> Self {
        Evaluator {
            det,
            force_n: Vec::with_capacity(cycles),
            drift_mm: Vec::with_capacity(cycles),
            steady_s: 0.0,
            energy_min: 0.0,
            max_force: 0.0,
            max_master: 0.0,
            chatter_ring: vec![0.0; CHATTER_WINDOW_MS],
            chatter_sum: 0.0,
            chatter_k: 0,
            chatter_max: 0.0,
            prev_master_n: None,
            trans_abs: 0.0,
            trans_ref: 0.0,
            track_sq: 0.0,
            track_n: 0,
            drift_max: 0.0,
            rejected: 0,
            diverged: false,
        }
    }

    fn push(&mut self, s: Sample) {
        let d = &self.det;
        if !s.finite || !s.true_force_n.is_finite() {
            self.diverged = true;
            return;
        }
        self.energy_min = self.energy_min.min(s.observed_min_j);
        self.max_force = self.max_force.max(s.true_force_n);
        self.max_master = self.max_master.max(s.master_force_n);
        if let Some(p) = self.prev_master_n {
            let d = [
                s.master_force_vec_n[0] - p[0],
                s.master_force_vec_n[1] - p[1],
                s.master_force_vec_n[2] - p[2],
            ];
            let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            let slot = self.chatter_k % CHATTER_WINDOW_MS;
            self.chatter_sum += d2 - self.chatter_ring[slot];
            self.chatter_ring[slot] = d2;
            self.chatter_k += 1;
            // Re-summed once per window: no drift of the running sum.
            if self.chatter_k.is_multiple_of(CHATTER_WINDOW_MS) {
                self.chatter_sum = self.chatter_ring.iter().sum();
            }
            let rms = (self.chatter_sum.max(0.0) / CHATTER_WINDOW_MS as f64).sqrt();
            self.chatter_max = self.chatter_max.max(rms);
        }
        self.prev_master_n = Some(s.master_force_vec_n);
        self.drift_max = self.drift_max.max(s.drift_mm);
        if s.rejected {
            self.rejected += 1;
        }
        let in_contact = s.true_force_n > d.contact_threshold_n;
        self.force_n.push(s.true_force_n);
        self.drift_mm.push(s.drift_mm);
        if !in_contact && s.free_motion && s.steady {
            self.track_sq += s.tracking_err_mm * s.tracking_err_mm;
            self.track_n += 1;
        }
        self.steady_s = if s.steady { self.steady_s + DT_S } else { 0.0 };
        if in_contact && self.steady_s >= 1.0 {
            self.trans_abs += s.transparency_abs_n;
            self.trans_ref += s.slave_force_n;
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn finish(
        self,
        name: String,
        dissipated_j: f64,
        packets_lost: u64,
        packets_rejected: u64,
        rtt_mean_ms: f64,
        cycles: u64,
        wall_time_s: f64,
    ) -> Summary {
        let d = self.det;
        let win = (d.window_s / DT_S).round() as usize;
        let gap = (d.contact_gap_s / DT_S).round() as usize;
        let (episodes, bounces) = contact_episodes(&self.force_n, d.contact_threshold_n, gap);
        let settle = (d.settle_s / DT_S).round() as usize;
        let impacts = bouncing_impacts(
            &self.force_n,
            &episodes,
            settle,
            d.impact_force_n,
            (d.bounce_gap_s / DT_S).round() as usize,
        );
        let (cycle, residual): (Vec<usize>, Vec<f64>) =
            contact_residuals(&self.force_n, &episodes, settle, d.mean_time_constant_s)
                .into_iter()
                .unzip();
        let n = residual.len();
        let rms = |s: &[f64]| {
            if s.is_empty() {
                0.0
            } else {
                (s.iter().map(|x| x * x).sum::<f64>() / s.len() as f64).sqrt()
            }
        };
        let early = rms(&residual[..win.min(n)]);
        let late = rms(&residual[n.saturating_sub(win)..]);
        let growth = late / early.max(d.oscillation_floor_n);
        // The drift over the last 0.5 s of settled contact (cycles in touch).
        let drift_tail: Vec<f64> = cycle
            .iter()
            .rev()
            .filter(|&&k| self.force_n[k] > d.contact_threshold_n)
            .take(500)
            .map(|&k| self.drift_mm[k])
            .collect();
        let drift = if drift_tail.is_empty() {
            0.0
        } else {
            drift_tail.iter().sum::<f64>() / drift_tail.len() as f64
        };
        let mut reasons = Vec::new();
        if self.diverged {
            reasons.push("diverged".to_string());
        }
        if late > d.oscillation_limit_n {
            reasons.push(format!(
                "oscillation: late contact-force oscillation {late:.2} N RMS > {} N",
                d.oscillation_limit_n
            ));
        }
        if growth > d.growth_limit {
            reasons.push(format!(
                "growth: oscillation grew {growth:.2}x > {}x",
                d.growth_limit
            ));
        }
        if impacts >= d.bounce_limit {
            reasons.push(format!(
                "bouncing: {impacts} impacts in a row (touches shorter than {} s reaching {} N, \
                 each within {} s of the last) >= {}",
                d.settle_s, d.impact_force_n, d.bounce_gap_s, d.bounce_limit
            ));
        }
        if self.energy_min < -d.energy_tolerance_j {
            reasons.push(format!(
                "energy: observer reached {:.4} J < -{} J",
                self.energy_min, d.energy_tolerance_j
            ));
        }
        if self.max_force > d.force_limit_n {
            reasons.push(format!(
                "force: contact force {:.1} N > {} N",
                self.max_force, d.force_limit_n
            ));
        }
        let sim_time_s = cycles as f64 * DT_S;
        Summary {
            name,
            stable: reasons.is_empty(),
            unstable_reasons: reasons,
            energy_min_j: self.energy_min,
            max_force_n: self.max_force,
            max_master_force_n: self.max_master,
            master_force_chatter_n: self.chatter_max,
            oscillation_growth: growth,
            oscillation_early_n: early,
            oscillation_late_n: late,
            position_drift_mm: drift,
            position_drift_max_mm: self.drift_max,
            force_transparency_err_pct: if self.trans_ref > 0.0 {
                100.0 * self.trans_abs / self.trans_ref
            } else {
                f64::NAN
            },
            position_tracking_err_mm: if self.track_n > 0 {
                (self.track_sq / self.track_n as f64).sqrt()
            } else {
                f64::NAN
            },
            passivity_dissipated_j: dissipated_j,
            packets_lost,
            packets_rejected,
            rtt_mean_ms,
            contact_time_s: n as f64 * DT_S,
            contact_bounces: bounces,
            bouncing_impacts: impacts,
            slave_rejected_cycles: self.rejected,
            cycles,
            sim_time_s,
            wall_time_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rms(v: &[f64]) -> f64 {
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    }

    /// `n` samples of `f` (1 ms apart), as one contact episode, all settled.
    fn residuals_of(f: impl Fn(f64) -> f64, n: usize, tau: f64) -> Vec<f64> {
        let force: Vec<f64> = (0..n).map(|k| f(k as f64 * DT_S)).collect();
        contact_residuals(&force, std::slice::from_ref(&(0..n)), 0, tau)
            .into_iter()
            .map(|(_, r)| r)
            .collect()
    }

    /// A push and a release (ramps, also at the ends of the episode) are not oscillation;
    /// an oscillation is, by the documented fraction; episodes are filtered one at a time.
    #[test]
    fn contact_residuals_ignore_ramps_and_measure_oscillation() {
        let tau = 0.1;
        // Ramp up 0 → 20 N in 0.3 s, hold, ramp down to 0.5 N in 0.3 s at the end.
        let push_hold_release = |t: f64| {
            if t < 0.3 {
                20.0 * t / 0.3
            } else if t < 2.7 {
                20.0
            } else {
                20.0 - 19.5 * (t - 2.7) / 0.3
            }
        };
        let r = residuals_of(push_hold_release, 3000, tau);
        assert_eq!(r.len(), 3000);
        // Along a ramp and a hold nothing; a change of slope leaves about slope·τ/2
        // (here 3.3 N) for about τ. (The causal moving mean this replaced left slope·τ,
        // 6.7 N, over each whole ramp, the release included.)
        assert!(r[1000..2000].iter().all(|x| x.abs() < 0.01), "hold");
        assert!(r[2850..].iter().all(|x| x.abs() < 1.0), "release");
        assert!(rms(&r) < 1.0, "{}", rms(&r));
        // A 5 Hz, 2 N-amplitude oscillation on 10 N: (2πfτ)²/(1+(2πfτ)²) ≈ 0.91 of it.
        let osc = |t: f64| 10.0 + 2.0 * (2.0 * std::f64::consts::PI * 5.0 * t).sin();
        let r = residuals_of(osc, 4000, tau);
        let w = 2.0 * std::f64::consts::PI * 5.0 * tau;
        let expect = 2.0 / 2f64.sqrt() * w * w / (1.0 + w * w);
        let got = rms(&r[500..3500]);
        assert!((got - expect).abs() < 0.05 * expect, "{got} {expect}");
        // Two episodes at different levels: no step between them shows as oscillation.
        let mut two = vec![5.0; 1000];
        two.extend(vec![30.0; 1000]);
        let r = contact_residuals(&two, &[0..1000, 1000..2000], 0, tau);
        assert!(r.iter().all(|x| x.1.abs() < 1e-9));
        // Samples before the settle time are filtered but not reported; cycles are kept.
        let r = contact_residuals(&[5.0; 100], std::slice::from_ref(&(0..100)), 40, tau);
        assert_eq!(r.len(), 60);
        assert_eq!(r[0].0, 40);
    }

    /// Touches closer than the gap are one episode (the bounces counted); a release and a
    /// new push further apart are two.
    #[test]
    fn contact_episodes_join_bounces() {
        let th = 0.5;
        // 0.2 s free, then a tool bouncing at 8 Hz (60 ms on at 30 N, 60 ms off) for 1.2 s,
        // then 1 s free, then a held push of 1 s.
        let mut f = vec![0.0; 200];
        for _ in 0..10 {
            f.extend(vec![30.0; 60]);
            f.extend(vec![0.0; 60]);
        }
        f.extend(vec![0.0; 1000]);
        f.extend(vec![10.0; 1000]);
        f.push(0.0);
        let (e, bounces) = contact_episodes(&f, th, 250);
        assert_eq!(e, vec![200..1340, 2400..3400]);
        assert_eq!(bounces, 9);
        // With no gap every touch is its own episode.
        let (each, bounces) = contact_episodes(&f, th, 0);
        assert_eq!((each.len(), bounces), (11, 0));
        // The bouncing episode is an oscillation of about 15 N RMS around its mean: the
        // detector sees it (touch by touch it saw nothing, each touch shorter than the
        // settle time).
        let r: Vec<f64> = contact_residuals(&f, &e[..1], 0, 0.1)
            .into_iter()
            .map(|x| x.1)
            .collect();
        assert!(rms(&r[200..]) > 10.0, "{}", rms(&r));
    }

    /// A tool that bounces off the wall slowly (each touch shorter than the settle time,
    /// gaps longer than the episode gap) is counted impact by impact; a long touch, a touch
    /// too light, or a gap too long ends the run.
    #[test]
    fn bouncing_impacts_count_short_touches_in_a_row() {
        // Touches of 160 ms at 70 N every 630 ms (the bare coupling at 100 ms round trip).
        let mut f = vec![0.0; 100];
        for _ in 0..6 {
            f.extend(vec![70.0; 160]);
            f.extend(vec![0.0; 470]);
        }
        // A held push (a long touch), then three light taps, then two impacts 3 s apart.
        f.extend(vec![20.0; 2000]);
        f.extend(vec![0.0; 300]);
        for _ in 0..3 {
            f.extend(vec![1.5; 100]);
            f.extend(vec![0.0; 300]);
        }
        for _ in 0..2 {
            f.extend(vec![0.0; 3000]);
            f.extend(vec![50.0; 100]);
        }
        let (e, _) = contact_episodes(&f, 0.5, 250);
        assert_eq!(e.len(), 6 + 1 + 3 + 2);
        assert_eq!(bouncing_impacts(&f, &e, 500, 2.0, 2000), 6);
        // The light taps count only if the impact force is below them.
        assert_eq!(bouncing_impacts(&f, &e[6..], 500, 1.0, 2000), 3);
        // With a longer settle time the held push is an impact too.
        assert_eq!(bouncing_impacts(&f, &e, 2500, 2.0, 2000), 7);
    }
}
