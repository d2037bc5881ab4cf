//! The session file: its sections, their defaults and checks, and [`load`].

use std::path::{Path, PathBuf};

use h4_shared::config::{ArmConfig, ConfigError, Validate, check_range};
use h4_shared::passivity::PassivityParams;
use h4_slave::controller::ControllerParams;
use h4_slave::plant::{Material, MaterialPreset, PlantConfig, SensorConfig, Surface, SurfaceShape};
use h4_transport::impair::ImpairmentConfig;
use serde::{Deserialize, Serialize};

use super::{DetectorConfig, SessionError};
use crate::coupling::{CouplingConfig, ScaleConfig};
use crate::device::MasterArmConfig;
use crate::operator::{HandConfig, IntentError, IntentSegment, Script};
use crate::teleop::MasterTeleopConfig;

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
    /// Where the slave starts, `gap_mm` above the contact point, slave frame, `[x_mm, y_mm,
    /// z_mm, theta_rad]`: the master's home pose maps to it.
    pub fn slave_start_pose(&self) -> [f64; 4] {
        let p = self.contact_point_mm;
        [p[0], p[1], p[2] + self.gap_mm, 0.0]
    }

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

impl OperatorConfig {
    /// The operator's script: the replay file if one is set, else the intent; validated.
    pub fn script(&self) -> Result<Script, IntentError> {
        let script = match &self.replay_file {
            Some(path) => Script::load_replay(path)?,
            None => Script::Segments(self.intent.clone()),
        };
        script.validate()?;
        Ok(script)
    }
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

impl SessionConfig {
    /// The master's endpoint configuration for arm `arm_id`: the master's sections, the
    /// slave arm it maps into, the slave's start pose as the anchor of the master's home.
    pub fn master_teleop(&self, arm_id: u16) -> MasterTeleopConfig {
        MasterTeleopConfig {
            arm_id,
            master: self.master,
            hand: self.operator.hand,
            coupling: self.coupling,
            scale: self.scale,
            passivity: self.passivity,
            slave_arm: self.slave.arm,
            slave_from_master_anchor: self.environment.slave_start_pose(),
            slave_max_speed_mm_per_s: self.slave.controller.max_speed_mm_per_s,
        }
    }
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
