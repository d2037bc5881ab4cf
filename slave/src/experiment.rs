//! Autonomous force-tracking experiments on the simulated clock: approach from free space,
//! contact, track along the surface, optional set-point steps; a summary of how well the
//! force was held, and optionally an MCAP recording of every 1 ms cycle.
//!
//! Every field of an experiment file is documented in `docs/slave-experiments.md`.

use std::time::Instant;

use h4_shared::config::{ArmConfig, ConfigError, Validate, check_range};
use h4_shared::kinematics::Pose;
use h4_shared::recording::{ChannelId, Recorder, RecordingError};
use h4_shared::wire::Mode;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::controller::{ControllerInput, ControllerParams, SlaveCommand, SlaveController, Status};
use crate::plant::{
    ArmDriver, Material, MaterialPreset, PlantConfig, SensorConfig, SimArm, SimError, Surface,
    SurfaceShape,
};

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
        let s = &self.surface;
        check_range("surface.tilt_deg", s.tilt_deg, -60.0, 60.0, "deg")?;
        check_range("surface.radius_mm", s.radius_mm, 10.0, 1e5, "mm")?;
        if let Some(k) = s.stiffness_n_per_mm {
            check_range("surface.stiffness_n_per_mm", k, 0.1, 1e6, "N/mm")?;
        }
        if let Some(z) = s.damping_ratio {
            check_range("surface.damping_ratio", z, 0.0, 2.0, "")?;
        }
        if let Some(mu) = s.friction_coefficient {
            check_range("surface.friction_coefficient", mu, 0.0, 2.0, "")?;
        }
        for (i, v) in s.contact_point_mm.iter().enumerate() {
            check_range(
                &format!("surface.contact_point_mm[{i}]"),
                *v,
                -1e4,
                1e4,
                "mm",
            )?;
        }
        let c = &self.controller;
        check_range(
            "controller.force_limit_n",
            c.force_limit_n,
            1.0,
            1000.0,
            "N",
        )?;
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
        )?;
        let d = Vector3::from(self.track.direction).norm();
        check_range("track.direction (length)", d, 1e-6, 1e6, "")?;
        check_range(
            "track.start_delay_s",
            self.track.start_delay_s,
            0.0,
            3600.0,
            "s",
        )?;
        check_range("approach.gap_mm", self.approach.gap_mm, 0.0, 100.0, "mm")?;
        check_range(
            "approach.target_depth_mm",
            self.approach.target_depth_mm,
            0.1,
            100.0,
            "mm",
        )?;
        let se = &self.sensor;
        check_range("sensor.noise_std_n", se.noise_std_n, 0.0, 10.0, "N")?;
        check_range(
            "sensor.noise_std_n_mm",
            se.noise_std_n_mm,
            0.0,
            1000.0,
            "N·mm",
        )?;
        check_range("sensor.quantization_n", se.quantization_n, 0.0, 5.0, "N")?;
        check_range(
            "sensor.quantization_n_mm",
            se.quantization_n_mm,
            0.0,
            100.0,
            "N·mm",
        )?;
        for (i, b) in se.bias_n.iter().enumerate() {
            check_range(&format!("sensor.bias_n[{i}]"), *b, -50.0, 50.0, "N")?;
        }
        check_range("sensor.bias_n_mm", se.bias_n_mm, -1e4, 1e4, "N·mm")?;
        check_range(
            "sensor.sample_rate_hz",
            se.sample_rate_hz,
            100.0,
            100_000.0,
            "Hz",
        )?;
        check_range(
            "sensor.filter_cutoff_hz",
            se.filter_cutoff_hz,
            1.0,
            1e5,
            "Hz",
        )?;
        let p = &self.plant;
        check_range("plant.stiffness_scale", p.stiffness_scale, 0.1, 10.0, "")?;
        for (i, v) in p.stiffness_spread.iter().enumerate() {
            check_range(&format!("plant.stiffness_spread[{i}]"), *v, -0.5, 0.5, "")?;
        }
        check_range(
            "plant.structural_damping_ratio",
            p.structural_damping_ratio,
            0.0,
            1.0,
            "",
        )?;
        check_range(
            "plant.servo_rate_hz",
            p.servo_rate_hz,
            1000.0,
            100_000.0,
            "Hz",
        )?;
        check_range(
            "plant.carriage_mass_kg",
            p.carriage_mass_kg,
            0.01,
            1000.0,
            "kg",
        )?;
        check_range(
            "plant.servo_kp_n_per_mm",
            p.servo_kp_n_per_mm,
            0.0,
            1e5,
            "N/mm",
        )?;
        check_range(
            "plant.servo_ki_n_per_mm_s",
            p.servo_ki_n_per_mm_s,
            0.0,
            1e7,
            "N/(mm·s)",
        )?;
        check_range(
            "plant.servo_kd_n_s_per_mm",
            p.servo_kd_n_s_per_mm,
            0.0,
            1e3,
            "N·s/mm",
        )?;
        check_range(
            "plant.motor_force_max_n",
            p.motor_force_max_n,
            1.0,
            1e5,
            "N",
        )?;
        check_range(
            "plant.coulomb_friction_n",
            p.coulomb_friction_n,
            0.0,
            1e3,
            "N",
        )?;
        check_range(
            "plant.viscous_friction_n_s_per_mm",
            p.viscous_friction_n_s_per_mm,
            0.0,
            100.0,
            "N·s/mm",
        )?;
        check_range(
            "plant.friction_velocity_mm_per_s",
            p.friction_velocity_mm_per_s,
            1e-4,
            100.0,
            "mm/s",
        )?;
        check_range("plant.tool_mass_kg", p.tool_mass_kg, 0.01, 100.0, "kg")?;
        check_range(
            "plant.tool_inertia_kg_mm2",
            p.tool_inertia_kg_mm2,
            1.0,
            1e7,
            "kg·mm²",
        )?;
        check_range(
            "plant.platform_damping_n_s_per_mm",
            p.platform_damping_n_s_per_mm,
            0.0,
            100.0,
            "N·s/mm",
        )?;
        check_range(
            "plant.encoder_resolution_mm",
            p.encoder_resolution_mm,
            0.0,
            1.0,
            "mm",
        )?;
        check_range(
            "controller.max_speed_mm_per_s",
            c.max_speed_mm_per_s,
            0.1,
            1000.0,
            "mm/s",
        )?;
        check_range(
            "controller.force_accel_mm_per_s2",
            c.force_accel_mm_per_s2,
            1.0,
            1e7,
            "mm/s²",
        )?;
        check_range(
            "controller.max_accel_mm_per_s2",
            c.max_accel_mm_per_s2,
            1.0,
            1e5,
            "mm/s²",
        )?;
        check_range(
            "controller.max_theta_rate_rad_per_s",
            c.max_theta_rate_rad_per_s,
            0.01,
            10.0,
            "rad/s",
        )?;
        check_range(
            "controller.approach_speed_mm_per_s",
            c.approach_speed_mm_per_s,
            0.01,
            c.max_speed_mm_per_s,
            "mm/s",
        )?;
        check_range(
            "controller.contact_threshold_n",
            c.contact_threshold_n,
            0.01,
            100.0,
            "N",
        )?;
        check_range(
            "controller.contact_lost_n",
            c.contact_lost_n,
            0.0,
            c.contact_threshold_n,
            "N (up to contact_threshold_n)",
        )?;
        check_range(
            "controller.contact_lost_cycles",
            f64::from(c.contact_lost_cycles),
            1.0,
            10_000.0,
            "cycles",
        )?;
        check_range(
            "controller.setpoint_time_constant_s",
            c.setpoint_time_constant_s,
            0.0,
            10.0,
            "s",
        )?;
        check_range("controller.kp", c.kp, 0.0, 10.0, "")?;
        check_range(
            "controller.feedforward_gain",
            c.feedforward_gain,
            0.0,
            1.5,
            "",
        )?;
        check_range("controller.ki_per_s", c.ki_per_s, 0.0, 1000.0, "1/s")?;
        check_range(
            "controller.initial_env_stiffness_n_per_mm",
            c.initial_env_stiffness_n_per_mm,
            0.1,
            1e6,
            "N/mm",
        )?;
        check_range(
            "controller.env_stiffness_min_n_per_mm",
            c.env_stiffness_min_n_per_mm,
            0.01,
            1e6,
            "N/mm",
        )?;
        check_range(
            "controller.env_stiffness_max_n_per_mm",
            c.env_stiffness_max_n_per_mm,
            c.env_stiffness_min_n_per_mm,
            1e7,
            "N/mm (≥ env_stiffness_min_n_per_mm)",
        )?;
        check_range(
            "controller.estimator_forgetting",
            c.estimator_forgetting,
            0.5,
            1.0,
            "",
        )?;
        check_range(
            "controller.estimator_window_cycles",
            f64::from(c.estimator_window_cycles),
            2.0,
            63.0,
            "cycles",
        )?;
        check_range(
            "controller.estimator_excitation_n",
            c.estimator_excitation_n,
            0.0,
            100.0,
            "N",
        )?;
        check_range(
            "controller.normal_time_constant_s",
            c.normal_time_constant_s,
            0.0,
            10.0,
            "s",
        )?;
        check_range(
            "controller.deflection_comp_time_constant_s",
            c.deflection_comp_time_constant_s,
            0.0,
            1.0,
            "s",
        )?;
        check_range(
            "controller.sensor_filter_cutoff_hz",
            c.sensor_filter_cutoff_hz,
            1.0,
            1e5,
            "Hz",
        )?;
        check_range(
            "controller.tare_cycles",
            f64::from(c.tare_cycles),
            1.0,
            100_000.0,
            "cycles",
        )?;
        check_range(
            "controller.safe_stop_ramp_s",
            c.safe_stop_ramp_s,
            0.0,
            60.0,
            "s",
        )?;
        check_range(
            "controller.safe_stop_retract_mm",
            c.safe_stop_retract_mm,
            0.0,
            100.0,
            "mm",
        )?;
        check_range(
            "controller.safe_stop_release_max_mm",
            c.safe_stop_release_max_mm,
            0.0,
            500.0,
            "mm",
        )?;
        check_range(
            "summary.transient_s",
            self.summary.transient_s,
            0.0,
            3600.0,
            "s",
        )?;
        check_range(
            "summary.settle_band_fraction",
            self.summary.settle_band_fraction,
            0.0,
            1.0,
            "",
        )?;
        check_range(
            "summary.settle_band_min_n",
            self.summary.settle_band_min_n,
            0.0,
            100.0,
            "N",
        )?;
        Ok(())
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

/// How one contact or set-point step went.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct EventSummary {
    /// Time of the event, s (first contact, or the step).
    pub time_s: f64,
    /// Set-point before, N (0 for the first contact).
    pub from_n: f64,
    /// Set-point after, N.
    pub to_n: f64,
    /// Largest excursion beyond the new set-point in the step's direction, % of the step.
    pub overshoot_pct: f64,
    /// Time until the force stays within the settling band, ms.
    pub settling_ms: f64,
    /// Whether the force settled before the next event (or the end).
    pub settled: bool,
}

/// The result of one experiment.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// The experiment's name.
    pub name: String,
    /// RMS of |F_n − F_d| over the steady tracking phases, N (true contact force along the
    /// true surface normal). A steady phase starts `summary.transient_s` after the first
    /// contact, after each step and after the tracking motion starts, and ends at the next
    /// step or the end of the run.
    pub force_error_rms_n: f64,
    /// 99th percentile of |F_n − F_d| over the steady tracking phases, N.
    pub force_error_p99_n: f64,
    /// Largest |F_n − F_d| over the steady tracking phases, N.
    pub force_error_max_n: f64,
    /// Largest |F_n − F_d| from the start of the tracking motion on (its start included,
    /// 'transient_s' after steps excluded), N.
    pub force_error_max_tracking_n: f64,
    /// Largest overshoot over the first contact and every step, % of the step.
    pub overshoot_pct: f64,
    /// Longest settling time over the first contact and every step, ms.
    pub settling_ms: f64,
    /// Largest contact force magnitude, N.
    pub max_force_n: f64,
    /// Time without contact after tracking started, ms.
    pub contact_lost_ms: f64,
    /// Path length of the tool along the surface while tracking, mm.
    pub tracked_distance_mm: f64,
    /// Time of the first contact, s.
    pub first_contact_s: f64,
    /// The controller's final estimate of the environment's stiffness, N/mm.
    pub env_stiffness_estimate_n_per_mm: f64,
    /// The surface's true stiffness, N/mm.
    pub env_stiffness_true_n_per_mm: f64,
    /// Cycles whose command the controller rejected.
    pub rejected_cycles: u64,
    /// The first contact and every step.
    pub events: Vec<EventSummary>,
    /// Control cycles run (1 ms each).
    pub cycles: u64,
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Wall-clock time of the simulation, s (the only field that is not deterministic).
    pub wall_time_s: f64,
    /// sim_time_s / wall_time_s (not deterministic).
    pub speedup: f64,
}

/// Why an experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// The simulation could not be built.
    #[error("simulation: {0}")]
    Sim(#[from] SimError),
    /// The recording failed.
    #[error("{0}")]
    Recording(#[from] RecordingError),
    /// The configuration is not usable.
    #[error("{0}")]
    Config(#[from] ConfigError),
}

struct Channels {
    force: ChannelId,
    pose: ChannelId,
    contact: ChannelId,
}

const FORCE_SCHEMA: &str = r#"{"type":"object","title":"h4.SlaveForce","properties":{
"fn_measured_n":{"type":"number","description":"measured force along the estimated normal, N"},
"fn_true_n":{"type":"number","description":"true contact force along the true normal, N"},
"fn_desired_n":{"type":"number","description":"prefiltered set-point, N"},
"setpoint_n":{"type":"number","description":"commanded set-point, N"},
"wrench_measured":{"type":"array","items":{"type":"number"},"description":"[Fx,Fy,Fz,My] bias-corrected, N, N·mm"},
"wrench_desired":{"type":"array","items":{"type":"number"},"description":"[Fx,Fy,Fz,My] desired, N, N·mm"},
"env_stiffness_n_per_mm":{"type":"number"},
"compliance_mm_per_n":{"type":"number"},
"status":{"type":"integer"}}}"#;

const POSE_SCHEMA: &str = r#"{"type":"object","title":"h4.SlavePose","properties":{
"measured":{"type":"array","items":{"type":"number"},"description":"[x,y,z,theta] mm, rad"},
"commanded":{"type":"array","items":{"type":"number"},"description":"[x,y,z,theta] mm, rad"},
"true_pose":{"type":"array","items":{"type":"number"},"description":"[x,y,z,theta] mm, rad (simulation truth)"},
"actuators_cmd_mm":{"type":"array","items":{"type":"number"}}}}"#;

const CONTACT_SCHEMA: &str = r#"{"type":"object","title":"h4.SlaveContact","properties":{
"normal":{"type":"array","items":{"type":"number"},"description":"estimated outward contact normal"},
"tracking_direction":{"type":"array","items":{"type":"number"}},
"true_normal":{"type":"array","items":{"type":"number"}},
"penetration_mm":{"type":"number"}}}"#;

#[derive(Serialize)]
struct ForceMsg {
    fn_measured_n: f64,
    fn_true_n: f64,
    fn_desired_n: f64,
    setpoint_n: f64,
    wrench_measured: [f64; 4],
    wrench_desired: [f64; 4],
    env_stiffness_n_per_mm: f64,
    compliance_mm_per_n: f64,
    status: u8,
}

#[derive(Serialize)]
struct PoseMsg {
    measured: [f64; 4],
    commanded: [f64; 4],
    true_pose: [f64; 4],
    actuators_cmd_mm: [f64; 4],
}

#[derive(Serialize)]
struct ContactMsg {
    normal: [f64; 3],
    tracking_direction: [f64; 3],
    true_normal: [f64; 3],
    penetration_mm: f64,
}

const CYCLE_NS: u64 = 1_000_000;

/// Runs one experiment; with a recorder, every cycle is recorded on `/slave/force`,
/// `/slave/pose` and `/slave/contact`, stamped with the simulated time.
pub fn run(
    cfg: &ExperimentConfig,
    mut recorder: Option<&mut Recorder>,
) -> Result<Summary, ExperimentError> {
    cfg.validate()?;
    let ws = cfg.arm.workspace();
    let assumed = cfg.arm.stiffness().map_err(SimError::from)?;
    let surface = cfg.surface();
    let p = cfg.surface.contact_point_mm;
    let start = Pose::new(p[0], p[1], p[2] + cfg.approach.gap_mm, 0.0);
    let target = [p[0], p[1], p[2] - cfg.approach.target_depth_mm, 0.0];
    let mut arm = SimArm::new(
        ws.params,
        cfg.arm.actuator_stiffness_n_per_mm,
        cfg.plant,
        cfg.sensor,
        surface,
        start,
        cfg.seed,
    )?;
    let mut ctrl = SlaveController::new(ws, assumed, cfg.controller);
    let channels = match recorder.as_deref_mut() {
        Some(r) => Some(Channels {
            force: r.add_channel("/slave/force", "h4.SlaveForce", FORCE_SCHEMA)?,
            pose: r.add_channel("/slave/pose", "h4.SlavePose", POSE_SCHEMA)?,
            contact: r.add_channel("/slave/contact", "h4.SlaveContact", CONTACT_SCHEMA)?,
        }),
        None => None,
    };

    let cycles = (cfg.duration_s * 1000.0).round() as u64;
    let dir = Vector3::from(cfg.track.direction).normalize() * cfg.track.speed_mm_per_s;
    let mut f_true = Vec::with_capacity(cycles as usize);
    let mut sp_log = Vec::with_capacity(cycles as usize);
    let mut first_true_contact: Option<usize> = None;
    let mut ctrl_contact_ms: Option<u64> = None;
    let mut track_start: Option<usize> = None;
    let mut contact_lost_ms = 0u64;
    let mut tracked = 0.0;
    let mut max_force: f64 = 0.0;
    let mut rejected = 0u64;
    let mut prev_true = arm.true_pose();
    let mut env_estimate = f64::NAN;
    let wall = Instant::now();
    for k in 0..cycles {
        let t_ms = k;
        let reading = arm.read();
        let mut setpoint = cfg.force.setpoint_n;
        let mut velocity = [0.0; 4];
        if let Some(tc) = ctrl_contact_ms {
            let since = (t_ms - tc) as f64 * 1e-3;
            for st in &cfg.force.steps {
                if since >= st.time_s {
                    setpoint = st.setpoint_n;
                }
            }
            if since >= cfg.track.start_delay_s {
                velocity = [dir[0], dir[1], dir[2], 0.0];
                if track_start.is_none() {
                    track_start = Some(k as usize);
                }
            }
        }
        let input = ControllerInput {
            actuators_mm: reading.actuators_mm,
            wrench: reading.wrench,
            command: SlaveCommand {
                mode: Mode::ForceGuided,
                pose: target,
                velocity,
                force_setpoint_n: setpoint,
                clutch: false,
            },
        };
        let out = ctrl.step(&input, 1e-3);
        if out.rejection.is_some() {
            rejected += 1;
        }
        if ctrl_contact_ms.is_none() && out.status == Status::Contact {
            ctrl_contact_ms = Some(t_ms);
        }
        arm.command(&out.actuators_cmd_mm);
        arm.advance(CYCLE_NS);

        // Truth.
        let pose = arm.true_pose();
        let tip = Vector3::new(pose[0], pose[1], pose[2]);
        let (pen, n_true) = arm.surface().penetration(&tip);
        let w = arm.true_contact_wrench();
        let f3 = Vector3::new(w[0], w[1], w[2]);
        let fn_true = f3.dot(&n_true);
        max_force = max_force.max(f3.norm());
        if first_true_contact.is_none() && fn_true > 0.0 {
            first_true_contact = Some(k as usize);
        }
        if track_start.is_some() {
            if fn_true <= 0.0 {
                contact_lost_ms += 1;
            }
            tracked += Vector3::new(
                pose[0] - prev_true[0],
                pose[1] - prev_true[1],
                pose[2] - prev_true[2],
            )
            .norm();
        }
        prev_true = pose;
        f_true.push(fn_true);
        sp_log.push(if ctrl_contact_ms.is_some() {
            setpoint
        } else {
            f64::NAN
        });

        if let (Some(r), Some(ch)) = (recorder.as_deref_mut(), channels.as_ref()) {
            let t_ns = arm.time_ns();
            r.write(
                ch.force,
                t_ns,
                &ForceMsg {
                    fn_measured_n: out.normal_force_n,
                    fn_true_n: fn_true,
                    fn_desired_n: out.setpoint_n,
                    setpoint_n: setpoint,
                    wrench_measured: out.wrench_measured,
                    wrench_desired: out.wrench_desired,
                    env_stiffness_n_per_mm: out.env_stiffness_n_per_mm,
                    compliance_mm_per_n: out.compliance_mm_per_n,
                    status: out.status.code(),
                },
            )?;
            r.write(
                ch.pose,
                t_ns,
                &PoseMsg {
                    measured: out.measured_pose,
                    commanded: out.commanded_pose,
                    true_pose: [pose[0], pose[1], pose[2], pose[3]],
                    actuators_cmd_mm: out.actuators_cmd_mm,
                },
            )?;
            r.write(
                ch.contact,
                t_ns,
                &ContactMsg {
                    normal: out.contact_normal,
                    tracking_direction: out.tracking_direction,
                    true_normal: [n_true[0], n_true[1], n_true[2]],
                    penetration_mm: pen,
                },
            )?;
        }
        env_estimate = out.env_stiffness_n_per_mm;
    }
    let wall_time_s = wall.elapsed().as_secs_f64();

    // Events: the first contact, then every step.
    let mut events: Vec<(usize, f64, f64)> = Vec::new();
    if let Some(fc) = first_true_contact {
        events.push((fc, 0.0, cfg.force.setpoint_n));
        if let Some(tc) = ctrl_contact_ms {
            let mut prev = cfg.force.setpoint_n;
            for st in &cfg.force.steps {
                let idx = tc as usize + (st.time_s * 1000.0).round() as usize;
                if idx < f_true.len() {
                    events.push((idx, prev, st.setpoint_n));
                }
                prev = st.setpoint_n;
            }
        }
    }
    let n = f_true.len();
    let transient = (cfg.summary.transient_s * 1000.0).round() as usize;
    let mut errors: Vec<f64> = Vec::new();
    let mut event_summaries = Vec::new();
    let mut tracking_max: f64 = 0.0;
    for (i, &(idx, from, to)) in events.iter().enumerate() {
        let end = events.get(i + 1).map_or(n, |e| e.0).max(idx);
        let step = (to - from).abs().max(1e-9);
        let sign = if to >= from { 1.0 } else { -1.0 };
        let mut peak: f64 = 0.0;
        let band = (cfg.summary.settle_band_fraction * step).max(cfg.summary.settle_band_min_n);
        let mut last_out_of_band: Option<usize> = None;
        for (j, f) in f_true.iter().enumerate().take(end).skip(idx) {
            peak = peak.max(sign * (f - to));
            if (f - to).abs() > band {
                last_out_of_band = Some(j);
            }
        }
        let settle_idx = last_out_of_band.map_or(idx, |j| j + 1);
        let settled = settle_idx < end;
        event_summaries.push(EventSummary {
            time_s: idx as f64 * 1e-3,
            from_n: from,
            to_n: to,
            overshoot_pct: 100.0 * peak / step,
            settling_ms: (settle_idx - idx) as f64,
            settled,
        });
        // Steady tracking: 'transient_s' after the event and after the tracking starts.
        let steady_from = (idx + transient).max(track_start.map_or(n, |t| t + transient));
        for f in f_true.iter().take(end).skip(steady_from) {
            errors.push((f - to).abs());
        }
        // Everything while tracking (the start of the motion included), for the record.
        let tracking_from = (idx + transient).max(track_start.unwrap_or(n));
        for f in f_true.iter().take(end).skip(tracking_from) {
            tracking_max = tracking_max.max((f - to).abs());
        }
    }
    let rms = if errors.is_empty() {
        f64::NAN
    } else {
        (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt()
    };
    let error_max = errors
        .iter()
        .copied()
        .max_by(f64::total_cmp)
        .unwrap_or(f64::NAN);
    // The 99th percentile by selection (the same element a sort would put there).
    let p99 = if errors.is_empty() {
        f64::NAN
    } else {
        let rank = ((errors.len() as f64 * 0.99).ceil() as usize).clamp(1, errors.len()) - 1;
        *errors.select_nth_unstable_by(rank, f64::total_cmp).1
    };
    let sim_time_s = cycles as f64 * 1e-3;
    Ok(Summary {
        name: cfg.name.clone(),
        force_error_rms_n: rms,
        force_error_p99_n: p99,
        force_error_max_n: error_max,
        force_error_max_tracking_n: tracking_max,
        overshoot_pct: event_summaries
            .iter()
            .map(|e| e.overshoot_pct)
            .fold(f64::NAN, f64::max),
        settling_ms: event_summaries
            .iter()
            .map(|e| {
                if e.settled {
                    e.settling_ms
                } else {
                    f64::INFINITY
                }
            })
            .fold(f64::NAN, f64::max),
        max_force_n: max_force,
        contact_lost_ms: contact_lost_ms as f64,
        tracked_distance_mm: tracked,
        first_contact_s: first_true_contact.map_or(f64::NAN, |i| i as f64 * 1e-3),
        env_stiffness_estimate_n_per_mm: env_estimate,
        env_stiffness_true_n_per_mm: surface.material.stiffness_n_per_mm,
        rejected_cycles: rejected,
        events: event_summaries,
        cycles,
        sim_time_s,
        wall_time_s,
        speedup: sim_time_s / wall_time_s.max(1e-9),
    })
}
