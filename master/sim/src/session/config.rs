//! The session file: its sections, their defaults and checks, and [`load`].

use std::path::{Path, PathBuf};

use h4_shared::config::{ArmConfig, ConfigError, Section, Validate, check_range};
use h4_shared::passivity::PassivityParams;
use h4_slave::controller::{ControllerParams, FixturesConfig};
use h4_slave::teleop::ContactHandover;
use h4_slave_sim::plant::cutting::CuttingConfig;
use h4_slave_sim::plant::{
    Axis, MaterialPreset, PlantConfig, SensorConfig, ShapeKind, Surface, SurfaceConfig,
};
use h4_slave_sim::world::SlaveWorld;
use h4_transport::impair::ImpairmentConfig;
use h4_transport::playout::PlayoutConfig;
use serde::{Deserialize, Serialize};

use super::cutting::CutTarget;
use super::timing::SlaveTiming;
use super::{DetectorConfig, SessionError};
use crate::arm::MasterArmConfig;
use crate::operator::{HandConfig, IntentError, IntentSegment, Script};
use h4_master::coupling::{CouplingConfig, ScaleConfig};
use h4_master::teleop::MasterTeleopConfig;

/// Which loop a host stall freezes (`host.stalls`).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum StallSide {
    /// Both loops at once (a frozen virtual machine).
    #[default]
    Both,
    /// The master's loop only.
    Master,
    /// The slave's loop only.
    Slave,
}

/// The host the two loops run on (`[host]`): stalls during which a loop does not run while
/// the physics go on (the devices hold the last force or position written), as this
/// project's virtual machines stall for 3–66 ms a few times a minute
/// (`docs/processes.md`). The simulated clock, the physics and the link keep their 1 ms
/// steps; a stalled loop runs its next cycle after the stall, seeing what moved.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct HostConfig {
    /// Length of each stall, ms (0: none).
    pub stall_ms: f64,
    /// Mean time from one stall's start to the next's, ms; each interval is drawn
    /// uniformly in 0.5–1.5 × this (seeded).
    pub stall_every_ms: f64,
    /// Which loop stalls.
    pub stalls: StallSide,
    /// Mixed with the top-level `seed`.
    pub seed: u64,
}

impl Default for HostConfig {
    fn default() -> Self {
        HostConfig {
            stall_ms: 0.0,
            stall_every_ms: 1000.0,
            stalls: StallSide::Both,
            seed: 0,
        }
    }
}

impl HostConfig {
    /// No stalls configured and every field at its default (not written out).
    pub fn is_default(&self) -> bool {
        *self == HostConfig::default()
    }
}

impl Section for HostConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |name: &str| format!("{prefix}{name}");
        check_range(&f("stall_ms"), self.stall_ms, 0.0, 1000.0, "ms")?;
        check_range(
            &f("stall_every_ms"),
            self.stall_every_ms,
            (2.0 * self.stall_ms).max(1.0),
            3.6e6,
            "ms (at least twice host.stall_ms)",
        )
    }
}

/// The surface the slave touches.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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

    /// The surface as the slave's own section (a plane through `contact_point_mm`, tilted
    /// about y; the material's values unless overridden), so the session's slave and
    /// `h4-slave run` build the same world.
    pub fn surface_config(&self) -> SurfaceConfig {
        SurfaceConfig {
            shape: ShapeKind::Plane,
            material: self.material,
            tilt_deg: self.tilt_deg,
            radius_mm: 200.0,
            stiffness_n_per_mm: (self.stiffness_n_per_mm > 0.0).then_some(self.stiffness_n_per_mm),
            damping_ratio: (self.damping_ratio >= 0.0).then_some(self.damping_ratio),
            friction_coefficient: (self.friction_coefficient >= 0.0)
                .then_some(self.friction_coefficient),
            contact_point_mm: self.contact_point_mm,
            cylinder_axis: Axis::Y,
        }
    }

    /// The surface.
    pub fn surface(&self) -> Surface {
        self.surface_config().surface()
    }
}

/// Passivity control (`passivity.*`): the same settings on both sides.
pub type PassivityConfig = PassivityParams;

/// The operator.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// Contact hand-over to the slave's force loop (position mode).
    pub contact: ContactHandover,
    /// The playout (jitter) buffer on the slave's command link.
    pub playout: PlayoutConfig,
    /// The slave's safety monitor (`h4_slave::safety`: the arm's ratings enforced between
    /// the controller and the arm); `false` is refused without `--unsafe-test-override`.
    pub safety_monitor: bool,
    /// When the slave's cycle takes the master's command: `phase-locked` (in the period the
    /// master sent it, its feedback read at the master's next step: what `h4-slave run`
    /// does) or `own-clock` (a slave on its own clock takes it one period later).
    pub timing: SlaveTiming,
}

impl Default for SlaveConfig {
    fn default() -> Self {
        SlaveConfig {
            arm: ArmConfig::default(),
            plant: PlantConfig::default(),
            sensor: SensorConfig::default(),
            controller: ControllerParams::default(),
            command_timeout_ms: 20.0,
            contact: ContactHandover::default(),
            playout: PlayoutConfig::default(),
            safety_monitor: true,
            timing: SlaveTiming::default(),
        }
    }
}

/// One session, as read from a TOML file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// The host's stalls (none by default).
    #[serde(default, skip_serializing_if = "HostConfig::is_default")]
    pub host: HostConfig,
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
    /// The workpiece and the spindle's tool: the slave cuts (`docs/cutting.md`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cutting: Option<CuttingConfig>,
    /// Virtual fixtures the slave holds the tool point in (`docs/cutting.md`).
    #[serde(default, skip_serializing_if = "FixturesConfig::is_empty")]
    pub fixtures: FixturesConfig,
    /// The shape the session should cut, against which the part is judged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cut_target: Option<CutTarget>,
    /// `--unsafe-test-override` was given: the slave accepts a safety layer turned off
    /// (passivity, the spindle-stall stop, the monitor) and gains beyond the arm's stable
    /// range. Not a key of the file: only the command-line flag (or a test) sets it.
    #[serde(skip)]
    #[schemars(skip)]
    pub unsafe_test_override: bool,
}

impl SessionConfig {
    /// Without `unsafe_test_override`: every safety layer on (`passivity.enabled`,
    /// `slave.controller.spindle_stall_safe_stop`, `slave.safety_monitor`) and the
    /// controller's gains within the arm's stable range (`slave.arm.ratings.kp_max`,
    /// `ki_max_per_s`). The slave's endpoint checks the same when it is built.
    pub fn check_safety_layers(&self) -> Result<(), ConfigError> {
        if self.unsafe_test_override {
            return Ok(());
        }
        let flag = "only with --unsafe-test-override (a safety layer may be off only for a \
                    negative control)";
        for (off, field) in [
            (!self.passivity.enabled, "passivity.enabled"),
            (
                !self.slave.controller.spindle_stall_safe_stop,
                "slave.controller.spindle_stall_safe_stop",
            ),
            (!self.slave.safety_monitor, "slave.safety_monitor"),
        ] {
            if off {
                return Err(ConfigError::OutOfRange {
                    field: field.to_string(),
                    value: "false".to_string(),
                    allowed: format!("true; false {flag}"),
                });
            }
        }
        let r = &self.slave.arm.ratings;
        let c = &self.slave.controller;
        for (field, value, max, rating) in [
            ("slave.controller.kp", c.kp, r.kp_max, "kp_max"),
            (
                "slave.controller.ki_per_s",
                c.ki_per_s,
                r.ki_max_per_s,
                "ki_max_per_s",
            ),
        ] {
            if value > max {
                return Err(ConfigError::OutOfRange {
                    field: field.to_string(),
                    value: value.to_string(),
                    allowed: format!(
                        "0 to {max}, the range the controller is stable in on this arm \
                         (slave.arm.ratings.{rating}); beyond it {flag}"
                    ),
                });
            }
        }
        Ok(())
    }

    /// The slave's world (arm, surface, sensor, plant, controller) as the slave's own
    /// sections: what the simulated slave and `h4-slave run` are built from.
    pub fn slave_world(&self) -> SlaveWorld {
        SlaveWorld {
            arm: self.slave.arm,
            surface: self.environment.surface_config(),
            sensor: self.slave.sensor,
            plant: self.slave.plant,
            controller: self.slave.controller,
            cutting: self.cutting,
            fixtures: self.fixtures.clone(),
        }
    }

    /// The master's endpoint configuration for arm `arm_id`: the master's sections, the
    /// slave arm it maps into, the slave's start pose as the anchor of the master's home.
    pub fn master_teleop(&self, arm_id: u16) -> MasterTeleopConfig {
        MasterTeleopConfig {
            arm_id,
            coupling: self.coupling,
            scale: self.scale,
            passivity: self.passivity,
            slave_arm: self.slave.arm,
            slave_anchor_pose: self.environment.slave_start_pose(),
            slave_max_speed_mm_per_s: self.slave.controller.max_speed_mm_per_s,
        }
    }

    /// The simulated haptic device: the master arm (`master.*`) with the operator's hand
    /// (`operator.*`) following its script.
    pub fn sim_device(&self) -> Result<crate::hand::SimHandDevice, super::SessionError> {
        let script = self.operator.script()?;
        crate::hand::SimHandDevice::new(self.master, self.operator.hand, script)
            .map_err(super::SessionError::Master)
    }
}

impl Section for EnvironmentConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |name: &str| format!("{prefix}{name}");
        if self.stiffness_n_per_mm != 0.0 {
            check_range(
                &f("stiffness_n_per_mm"),
                self.stiffness_n_per_mm,
                0.1,
                1e6,
                "N/mm (0 = the material's)",
            )?;
        }
        check_range(
            &f("damping_ratio"),
            self.damping_ratio,
            -1.0,
            2.0,
            "(negative = the material's)",
        )?;
        check_range(
            &f("friction_coefficient"),
            self.friction_coefficient,
            -1.0,
            2.0,
            "(negative = the material's)",
        )?;
        for (i, v) in self.contact_point_mm.iter().enumerate() {
            check_range(&f(&format!("contact_point_mm[{i}]")), *v, -1e4, 1e4, "mm")?;
        }
        check_range(&f("tilt_deg"), self.tilt_deg, -60.0, 60.0, "deg")?;
        check_range(&f("gap_mm"), self.gap_mm, 0.0, 100.0, "mm")
    }
}

impl Section for OperatorConfig {
    /// The hand, and the scripted intent unless a replay file replaces it (the replay file
    /// is checked when it is read).
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        self.hand.validate_at(&format!("{prefix}hand."))?;
        if self.replay_file.is_none() {
            Script::Segments(self.intent.clone())
                .validate()
                .map_err(|e| ConfigError::OutOfRange {
                    field: format!("{prefix}intent"),
                    value: String::new(),
                    allowed: e.to_string(),
                })?;
        }
        Ok(())
    }
}

impl Section for SlaveConfig {
    /// The slave crate's own sections (`arm.`, `controller.`, `plant.`, `sensor.`): the same
    /// verdict as in an experiment file; `command_timeout_ms` is the session's.
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |name: &str| format!("{prefix}{name}");
        self.arm.validate_at(&f("arm."))?;
        self.controller.validate_at(&f("controller."))?;
        self.plant.validate_at(&f("plant."))?;
        self.sensor.validate_at(&f("sensor."))?;
        self.contact.validate_at(&f("contact."))?;
        self.playout.validate_at(&f("playout."))?;
        check_range(
            &f("command_timeout_ms"),
            self.command_timeout_ms,
            1.0,
            1e5,
            "ms",
        )
    }
}

impl Validate for SessionConfig {
    /// Every section's own checks, then the checks across sections.
    fn validate(&self) -> Result<(), ConfigError> {
        check_range("duration_s", self.duration_s, 0.01, 3600.0, "s")?;
        self.link.validate_at("link.")?;
        self.host.validate_at("host.")?;
        self.environment.validate_at("environment.")?;
        self.passivity.validate_at("passivity.")?;
        self.coupling.validate_at("coupling.")?;
        // Across sections: the force-guided set-point stays within the slave's force limit.
        check_range(
            "coupling.guide_setpoint_max_n",
            self.coupling.guide_setpoint_max_n,
            0.0,
            self.slave.controller.force_limit_n,
            "N (up to slave.controller.force_limit_n)",
        )?;
        self.scale.validate_at("scale.")?;
        self.master.validate_at("master.")?;
        self.operator.validate_at("operator.")?;
        self.slave.validate_at("slave.")?;
        // The arm's ratings: a session may lower them, never raise them; the controller's
        // limits lie within them.
        let ratings = &self.slave.arm.ratings;
        ratings.check_within(
            &h4_shared::config::ArmRatings::default(),
            "slave.arm.ratings.",
        )?;
        check_range(
            "slave.controller.force_limit_n",
            self.slave.controller.force_limit_n,
            1.0,
            ratings.force_limit_n,
            "N (up to slave.arm.ratings.force_limit_n, the arm's rating)",
        )?;
        check_range(
            "slave.controller.max_speed_mm_per_s",
            self.slave.controller.max_speed_mm_per_s,
            0.1,
            ratings.max_speed_mm_per_s,
            "mm/s (up to slave.arm.ratings.max_speed_mm_per_s, the arm's rating)",
        )?;
        self.detector.validate_at("detector.")?;
        if let Some(c) = &self.cutting {
            c.validate_at("cutting.")?;
        }
        if let Some(t) = &self.cut_target {
            t.validate_at("cut_target.")?;
        }
        self.fixtures.validate_at("fixtures.")?;
        let table = self.cutting.is_some_and(|c| c.turntable.is_some());
        self.fixtures.check_turntable("fixtures.", table)
    }
}

/// Loads a session file with `--set` overrides; a relative `operator.replay_file` is
/// resolved against the session file's directory. A safety layer turned off or a gain
/// beyond the arm's stable range is refused ([`SessionConfig::check_safety_layers`]): only
/// [`load_with`] and `--unsafe-test-override` accept them.
pub fn load(path: &Path, overrides: &[String]) -> Result<SessionConfig, SessionError> {
    load_with(path, overrides, false)
}

/// [`load`], with `unsafe_test_override` (`--unsafe-test-override`): the session may turn
/// a safety layer off (passivity, the spindle-stall stop, the safety monitor) and ask for
/// gains beyond the arm's stable range, for the negative controls; the summary says so. No
/// rating may be raised either way.
pub fn load_with(
    path: &Path,
    overrides: &[String],
    unsafe_test_override: bool,
) -> Result<SessionConfig, SessionError> {
    let mut cfg: SessionConfig = h4_shared::config::load(path, overrides)?;
    cfg.unsafe_test_override = unsafe_test_override;
    cfg.check_safety_layers()?;
    if let Some(rf) = &cfg.operator.replay_file
        && rf.is_relative()
        && let Some(dir) = path.parent()
    {
        cfg.operator.replay_file = Some(dir.join(rf));
    }
    // A part from a mesh: read, checked and its distance grid built now, before any run.
    let dir = path.parent().unwrap_or(Path::new("."));
    // Its path made absolute, so that the slave's world written from this session
    // (`loopback`, `slave-config`) names the same file wherever that world is read from.
    if let Some(t) = cfg.cut_target.as_mut()
        && let Some(rel) = t.mesh.as_ref()
        && rel.is_relative()
    {
        let joined = dir.join(rel);
        t.mesh = Some(std::path::absolute(&joined).unwrap_or(joined));
    }
    h4_slave_sim::plant::cutting::judge::load_mesh_target(
        cfg.cut_target.as_mut(),
        &mut cfg.fixtures,
        cfg.cutting.as_ref(),
        dir,
    )?;
    Ok(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each section names its own fields, under the section's dotted path, with the range.
    #[test]
    fn sections_name_their_fields() {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sessions/wall-push.toml");
        assert!(load(&path, &[]).is_ok());
        for (set, field) in [
            ("environment.tilt_deg=61", "environment.tilt_deg"),
            ("slave.controller.kp=-5", "slave.controller.kp"),
            ("coupling.fade_ms=0", "coupling.fade_ms"),
            (
                "coupling.guide_setpoint_max_n=900",
                "coupling.guide_setpoint_max_n",
            ),
            ("scale.force=0", "scale.force"),
            ("master.substeps=0", "master.substeps"),
            ("operator.hand.hand_mass_kg=0", "operator.hand.hand_mass_kg"),
            ("detector.window_s=0", "detector.window_s"),
            ("slave.command_timeout_ms=0", "slave.command_timeout_ms"),
        ] {
            let err = load(&path, &[set.to_string()]).err().map(|e| e.to_string());
            let text = err.unwrap_or_default();
            assert!(
                text.contains(field) && text.contains("allowed"),
                "{set}: {text}"
            );
        }
    }
}
