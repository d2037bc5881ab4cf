//! An experiment file: its sections and their checks.

use h4_shared::config::{ArmConfig, ConfigError, Validate, check_range};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::controller::ControllerParams;
use crate::plant::{Material, MaterialPreset, PlantConfig, SensorConfig, Surface, SurfaceShape};

/// Shape of the experiment's surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ShapeKind {
    /// A plane, tilted about y by `tilt_deg`.
    Plane,
    /// A cylinder of `radius_mm` whose axis is `cylinder_axis`, touched on top.
    Cylinder,
    /// A sphere of `radius_mm`, touched on top.
    Sphere,
}

/// A horizontal axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// The robot's x axis.
    X,
    /// The robot's y axis.
    Y,
}

/// The surface the controller does not know.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceConfig {
    /// `plane`, `cylinder` or `sphere`.
    pub shape: ShapeKind,
    /// `resin`, `steel` or `aluminium`.
    pub material: MaterialPreset,
    /// Tilt of the surface normal at the contact point about the robot's y axis, degrees.
    #[serde(default)]
    pub tilt_deg: f64,
    /// Radius of a cylinder or sphere, mm.
    #[serde(default = "default_radius")]
    pub radius_mm: f64,
    /// Overrides the material's contact stiffness, N/mm.
    #[serde(default)]
    pub stiffness_n_per_mm: Option<f64>,
    /// Overrides the material's contact damping ratio.
    #[serde(default)]
    pub damping_ratio: Option<f64>,
    /// Overrides the material's friction coefficient.
    #[serde(default)]
    pub friction_coefficient: Option<f64>,
    /// Where the tool first touches the surface, mm.
    #[serde(default = "default_contact_point")]
    pub contact_point_mm: [f64; 3],
    /// Axis of a cylinder (`x` or `y`).
    #[serde(default = "default_axis")]
    pub cylinder_axis: Axis,
}

fn default_radius() -> f64 {
    200.0
}
fn default_contact_point() -> [f64; 3] {
    [0.0, 0.0, -250.0]
}
fn default_axis() -> Axis {
    Axis::Y
}

/// One set-point change.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceStep {
    /// When, s after the first contact.
    pub time_s: f64,
    /// The new set-point, N.
    pub setpoint_n: f64,
}

/// The force set-point and its steps.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceConfig {
    /// Contact force set-point, N.
    pub setpoint_n: f64,
    /// Set-point steps, in time order.
    #[serde(default)]
    pub steps: Vec<ForceStep>,
}

/// Motion along the surface.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
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
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ApproachConfig {
    /// Start this far above the contact point (along +z), mm.
    pub gap_mm: f64,
    /// The approach target lies this far below the contact point, mm.
    pub target_depth_mm: f64,
}

impl Default for ApproachConfig {
    fn default() -> Self {
        ApproachConfig {
            gap_mm: 2.0,
            target_depth_mm: 20.0,
        }
    }
}

/// How the summary judges the run.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
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

/// One experiment, as read from a TOML file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
}

impl Validate for ExperimentConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        check_range("duration_s", self.duration_s, 0.01, 3600.0, "s")?;
        self.arm.validate_at("arm.")?;
        self.surface.validate_at("surface.")?;
        self.sensor.validate_at("sensor.")?;
        self.plant.validate_at("plant.")?;
        self.controller.validate_at("controller.")?;
        self.track.validate_at("track.")?;
        self.approach.validate_at("approach.")?;
        self.summary.validate_at("summary.")?;
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

impl SurfaceConfig {
    /// Checks every field, naming it under `prefix` (e.g. `"surface."`) with its allowed
    /// range and unit.
    pub fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let field = |name: &str| format!("{prefix}{name}");
        check_range(&field("tilt_deg"), self.tilt_deg, -60.0, 60.0, "deg")?;
        check_range(&field("radius_mm"), self.radius_mm, 10.0, 1e5, "mm")?;
        if let Some(k) = self.stiffness_n_per_mm {
            check_range(&field("stiffness_n_per_mm"), k, 0.1, 1e6, "N/mm")?;
        }
        if let Some(z) = self.damping_ratio {
            check_range(&field("damping_ratio"), z, 0.0, 2.0, "")?;
        }
        if let Some(mu) = self.friction_coefficient {
            check_range(&field("friction_coefficient"), mu, 0.0, 2.0, "")?;
        }
        for (i, v) in self.contact_point_mm.iter().enumerate() {
            check_range(
                &field(&format!("contact_point_mm[{i}]")),
                *v,
                -1e4,
                1e4,
                "mm",
            )?;
        }
        Ok(())
    }
}

impl TrackConfig {
    /// Checks the fields of the section alone (the speed's limit is the controller's),
    /// naming them under `prefix`.
    pub fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
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

impl ApproachConfig {
    /// Checks every field, naming it under `prefix`.
    pub fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        check_range(&format!("{prefix}gap_mm"), self.gap_mm, 0.0, 100.0, "mm")?;
        check_range(
            &format!("{prefix}target_depth_mm"),
            self.target_depth_mm,
            0.1,
            100.0,
            "mm",
        )
    }
}

impl SummaryConfig {
    /// Checks every field, naming it under `prefix`.
    pub fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
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
    /// The surface the simulation owns: shape placed so the tool first touches it at
    /// `contact_point_mm`, with the normal there tilted by `tilt_deg` about y.
    pub fn surface(&self) -> Surface {
        let s = &self.surface;
        let preset = s.material.material();
        let material = Material {
            stiffness_n_per_mm: s.stiffness_n_per_mm.unwrap_or(preset.stiffness_n_per_mm),
            damping_ratio: s.damping_ratio.unwrap_or(preset.damping_ratio),
            friction_coefficient: s
                .friction_coefficient
                .unwrap_or(preset.friction_coefficient),
        };
        let t = s.tilt_deg.to_radians();
        let n = [t.sin(), 0.0, t.cos()];
        let p = s.contact_point_mm;
        let centre = [
            p[0] - s.radius_mm * n[0],
            p[1] - s.radius_mm * n[1],
            p[2] - s.radius_mm * n[2],
        ];
        let shape = match s.shape {
            ShapeKind::Plane => SurfaceShape::Plane {
                point_mm: p,
                normal: n,
            },
            ShapeKind::Sphere => SurfaceShape::Sphere {
                centre_mm: centre,
                radius_mm: s.radius_mm,
            },
            ShapeKind::Cylinder => SurfaceShape::Cylinder {
                axis_point_mm: centre,
                axis_dir: match s.cylinder_axis {
                    Axis::X => [1.0, 0.0, 0.0],
                    Axis::Y => [0.0, 1.0, 0.0],
                },
                radius_mm: s.radius_mm,
            },
        };
        Surface { shape, material }
    }
}
