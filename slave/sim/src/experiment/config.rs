//! An experiment file: its sections and their checks. The slave-side sections (arm,
//! surface, sensor, plant, controller) are a [`SlaveWorld`]; the experiment adds the
//! force set-point, the tracking motion, the approach and the summary.

use h4_shared::config::{ArmConfig, ConfigError, Section, Validate, check_range};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::plant::cutting::CuttingConfig;
use crate::plant::{PlantConfig, SensorConfig, Surface, SurfaceConfig};
use crate::world::SlaveWorld;
use h4_slave::controller::{ControllerParams, FixturesConfig};

/// One set-point change.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ForceStep {
    /// When, s after the first contact.
    pub time_s: f64,
    /// The new set-point, N.
    pub setpoint_n: f64,
}

/// The force set-point and its steps.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ForceConfig {
    /// Contact force set-point, N.
    pub setpoint_n: f64,
    /// Set-point steps, in time order.
    #[serde(default)]
    pub steps: Vec<ForceStep>,
}

/// Motion along the surface.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TrackConfig {
    /// Tracking speed along the surface, mm/s (21 cm/min = 3.5 mm/s).
    pub speed_mm_per_s: f64,
    /// Desired direction of motion (any length > 0); the controller projects it on the
    /// surface's tangent plane.
    #[serde(default = "default_direction")]
    pub direction: [f64; 3],
    /// Delay between the first contact and the start of tracking, s.
    #[serde(default = "default_start_delay")]
    pub start_delay_s: f64,
}

fn default_direction() -> [f64; 3] {
    [1.0, 0.0, 0.0]
}
fn default_start_delay() -> f64 {
    0.5
}

/// The approach from free space.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ApproachConfig {
    /// Start this far above the contact point (along +z), mm.
    pub gap_mm: f64,
    /// The approach target lies this far below the contact point, mm (negative: above it,
    /// the tool never touches; a free-space test).
    pub target_depth_mm: f64,
    /// The tool's tilt θ about y commanded from the start (the arm starts at θ = 0, tares
    /// its sensor there and turns while approaching), rad (−1 to 1).
    pub theta_rad: f64,
}

impl Default for ApproachConfig {
    fn default() -> Self {
        ApproachConfig {
            gap_mm: 2.0,
            target_depth_mm: 20.0,
            theta_rad: 0.0,
        }
    }
}

/// How the summary judges the run.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SummaryConfig {
    /// The steady phase starts this long after the first contact or a step, s.
    pub transient_s: f64,
    /// Settling band, fraction of the step size.
    pub settle_band_fraction: f64,
    /// Smallest settling band, N.
    pub settle_band_min_n: f64,
}

impl Default for SummaryConfig {
    fn default() -> Self {
        SummaryConfig {
            transient_s: 0.3,
            settle_band_fraction: 0.05,
            settle_band_min_n: 0.5,
        }
    }
}

/// The targets the run is judged against (`h4-slave experiment` exits 1 when one is
/// missed); the true force staying at or below `controller.force_limit_n` and the tool
/// touching its surface are always required.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TargetsConfig {
    /// Largest `force_error_p99_n` (steady tracking), N.
    pub force_error_p99_n: f64,
    /// Largest `force_error_p99_contact_n` (the whole contact), N.
    pub force_error_p99_contact_n: f64,
    /// Largest `force_error_max_n` (the whole contact), N.
    pub force_error_max_n: f64,
    /// Largest overshoot, %.
    pub overshoot_pct: f64,
    /// Longest settling, ms.
    pub settling_ms: f64,
    /// Longest time without contact once tracking, ms.
    pub contact_lost_ms: f64,
}

impl Default for TargetsConfig {
    fn default() -> Self {
        TargetsConfig {
            force_error_p99_n: 1.0,
            force_error_p99_contact_n: 1.0,
            force_error_max_n: 2.0,
            overshoot_pct: 5.0,
            settling_ms: 150.0,
            contact_lost_ms: 0.0,
        }
    }
}

impl Section for TargetsConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let field = |name: &str| format!("{prefix}{name}");
        #[rustfmt::skip]
        let checks: [(&str, f64, f64, f64, &str); 6] = [
            ("force_error_p99_n", self.force_error_p99_n, 0.0, 1e4, "N"),
            ("force_error_p99_contact_n", self.force_error_p99_contact_n, 0.0, 1e4, "N"),
            ("force_error_max_n", self.force_error_max_n, 0.0, 1e4, "N"),
            ("overshoot_pct", self.overshoot_pct, 0.0, 1e4, "%"),
            ("settling_ms", self.settling_ms, 0.0, 3.6e6, "ms"),
            ("contact_lost_ms", self.contact_lost_ms, 0.0, 3.6e6, "ms"),
        ];
        for (name, value, min, max, unit) in checks {
            check_range(&field(name), value, min, max, unit)?;
        }
        Ok(())
    }
}

/// One experiment, as read from a TOML file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ExperimentConfig {
    /// Free-text name.
    #[serde(default)]
    pub name: String,
    /// Seed of every random draw (sensor noise).
    pub seed: u64,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// The arm: geometry, the actuator stiffness the controller assumes, workspace.
    #[serde(default)]
    pub arm: ArmConfig,
    /// The surface.
    pub surface: SurfaceConfig,
    /// The force set-point.
    pub force: ForceConfig,
    /// Motion along the surface.
    pub track: TrackConfig,
    /// The approach.
    #[serde(default)]
    pub approach: ApproachConfig,
    /// The force sensor.
    #[serde(default)]
    pub sensor: SensorConfig,
    /// The simulated arm.
    #[serde(default)]
    pub plant: PlantConfig,
    /// The controller.
    #[serde(default)]
    pub controller: ControllerParams,
    /// The summary.
    #[serde(default)]
    pub summary: SummaryConfig,
    /// The targets the run is judged against.
    #[serde(default)]
    pub targets: TargetsConfig,
    /// The workpiece and the spindle's tool, when the arm cuts (`docs/cutting.md`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cutting: Option<CuttingConfig>,
    /// Virtual fixtures (`docs/cutting.md`).
    #[serde(default, skip_serializing_if = "FixturesConfig::is_empty")]
    pub fixtures: FixturesConfig,
    /// The shape a cutting arm should cut, in the workpiece frame: `h4-slave run` judges
    /// the part against it at the end (`surface_error_p99_mm`, `gouge_max_mm`,
    /// `deviation.png`; `docs/cutting.md`). `h4-master loopback` passes the session's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cut_target: Option<crate::plant::cutting::judge::CutTarget>,
}

impl Validate for ExperimentConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        check_range("duration_s", self.duration_s, 0.01, 3600.0, "s")?;
        self.world().validate_at("")?;
        self.track.validate_at("track.")?;
        self.approach.validate_at("approach.")?;
        self.summary.validate_at("summary.")?;
        self.targets.validate_at("targets.")?;
        if let Some(t) = &self.cut_target {
            t.validate_at("cut_target.")?;
        }
        self.validate_across()
    }
}

impl ExperimentConfig {
    /// The checks across sections: the set-points up to the controller's force limit, the
    /// steps in time order within the run, the tracking speed up to the controller's speed
    /// limit.
    fn validate_across(&self) -> Result<(), ConfigError> {
        let c = &self.controller;
        check_range(
            "force.setpoint_n",
            self.force.setpoint_n,
            0.5,
            c.force_limit_n,
            "N (up to controller.force_limit_n)",
        )?;
        let mut t_prev = 0.0;
        for (i, st) in self.force.steps.iter().enumerate() {
            check_range(
                &format!("force.steps[{i}].time_s"),
                st.time_s,
                t_prev,
                self.duration_s,
                "s (after the previous step, within duration_s)",
            )?;
            check_range(
                &format!("force.steps[{i}].setpoint_n"),
                st.setpoint_n,
                0.5,
                c.force_limit_n,
                "N",
            )?;
            t_prev = st.time_s;
        }
        check_range(
            "track.speed_mm_per_s",
            self.track.speed_mm_per_s,
            0.0,
            c.max_speed_mm_per_s,
            "mm/s (up to controller.max_speed_mm_per_s)",
        )
    }
}

impl Section for TrackConfig {
    /// Checks the fields of the section alone (the speed's limit is the controller's:
    /// [`ExperimentConfig`] checks it).
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let d = Vector3::from(self.direction).norm();
        check_range(&format!("{prefix}direction (length)"), d, 1e-6, 1e6, "")?;
        check_range(
            &format!("{prefix}start_delay_s"),
            self.start_delay_s,
            0.0,
            3600.0,
            "s",
        )
    }
}

impl Section for ApproachConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        check_range(&format!("{prefix}gap_mm"), self.gap_mm, 0.0, 100.0, "mm")?;
        check_range(
            &format!("{prefix}theta_rad"),
            self.theta_rad,
            -1.0,
            1.0,
            "rad",
        )?;
        check_range(
            &format!("{prefix}target_depth_mm"),
            self.target_depth_mm,
            -100.0,
            100.0,
            "mm (negative: above the contact point, the tool stays in free space)",
        )
    }
}

impl Section for SummaryConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let field = |name: &str| format!("{prefix}{name}");
        check_range(&field("transient_s"), self.transient_s, 0.0, 3600.0, "s")?;
        check_range(
            &field("settle_band_fraction"),
            self.settle_band_fraction,
            0.0,
            1.0,
            "",
        )?;
        check_range(
            &field("settle_band_min_n"),
            self.settle_band_min_n,
            0.0,
            100.0,
            "N",
        )
    }
}
impl ExperimentConfig {
    /// The slave-side sections: arm, surface, sensor, plant, controller.
    pub fn world(&self) -> SlaveWorld {
        SlaveWorld {
            arm: self.arm,
            surface: self.surface,
            sensor: self.sensor,
            plant: self.plant,
            controller: self.controller,
            cutting: self.cutting,
            fixtures: self.fixtures.clone(),
        }
    }

    /// The surface the simulation owns (see [`SurfaceConfig::surface`]).
    pub fn surface(&self) -> Surface {
        self.surface.surface()
    }
}
