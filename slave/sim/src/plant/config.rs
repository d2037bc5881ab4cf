//! The mechanical and servo parameters of the simulated arm (`plant.*`).

use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

/// The mechanical and servo parameters of the simulated arm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PlantConfig {
    /// Plant actuator stiffness = the controller's assumed stiffness × this (0.1 to 10).
    pub stiffness_scale: f64,
    /// Extra relative deviation of each actuator's stiffness (−0.5 to 0.5): actuator i has
    /// assumed_i × stiffness_scale × (1 + stiffness_spread\[i\]).
    pub stiffness_spread: [f64; 4],
    /// Damping ratio of each actuator's structural spring (0 to 1).
    pub structural_damping_ratio: f64,
    /// Servo (inner loop) rate, Hz (1000 to 100000); the paper's dSpace ran 20 kHz.
    pub servo_rate_hz: f64,
    /// Moving mass of each carriage with its reflected motor inertia, kg.
    pub carriage_mass_kg: f64,
    /// Servo proportional gain, N/mm.
    pub servo_kp_n_per_mm: f64,
    /// Servo integral gain, N/(mm·s).
    pub servo_ki_n_per_mm_s: f64,
    /// Servo derivative gain (on the measured velocity), N·s/mm.
    pub servo_kd_n_s_per_mm: f64,
    /// Largest motor force, N (the servo output saturates here).
    pub motor_force_max_n: f64,
    /// Coulomb friction of each carriage, N.
    pub coulomb_friction_n: f64,
    /// Viscous friction of each carriage, N·s/mm.
    pub viscous_friction_n_s_per_mm: f64,
    /// Speed below which Coulomb friction is regularised (linear), mm/s.
    pub friction_velocity_mm_per_s: f64,
    /// Mass of the moving platform with sensor and tool, kg.
    pub tool_mass_kg: f64,
    /// Rotational inertia of the platform about y, kg·mm².
    pub tool_inertia_kg_mm2: f64,
    /// Viscous damping of the platform's motion (joints, air), N·s/mm.
    pub platform_damping_n_s_per_mm: f64,
    /// Encoder resolution, mm.
    pub encoder_resolution_mm: f64,
    /// Mass beyond the force sensor (the tool and its holder), kg: its weight and inertia
    /// load the sensor (0 to `tool_mass_kg`, of which it is part).
    pub payload_mass_kg: f64,
    /// Centre of mass of that payload in the sensor's frame (which turns with θ about y),
    /// mm.
    pub payload_com_mm: [f64; 3],
    /// Gravity in the base frame, mm/s² (the machine's vertical axis is z: `[0, 0, −9810]`
    /// in the experiment files; the default, all zeros, is the ideal weightless plant).
    pub gravity_mm_per_s2: [f64; 3],
    /// Read-to-command latency: a command written takes effect this long after the sensor
    /// sample it was computed from was read, s (0 to 0.1; the paper's dSpace loop and the
    /// experiment files: one 1 ms period; the default 0 is the ideal plant).
    pub command_latency_s: f64,
}

impl Default for PlantConfig {
    fn default() -> Self {
        PlantConfig {
            stiffness_scale: 1.0,
            stiffness_spread: [0.0; 4],
            structural_damping_ratio: 0.05,
            servo_rate_hz: 20_000.0,
            carriage_mass_kg: 4.0,
            servo_kp_n_per_mm: 4000.0,
            servo_ki_n_per_mm_s: 400_000.0,
            servo_kd_n_s_per_mm: 5.6,
            motor_force_max_n: 600.0,
            coulomb_friction_n: 8.0,
            viscous_friction_n_s_per_mm: 0.05,
            friction_velocity_mm_per_s: 0.2,
            tool_mass_kg: 1.0,
            tool_inertia_kg_mm2: 1000.0,
            platform_damping_n_s_per_mm: 0.02,
            encoder_resolution_mm: 0.0005,
            payload_mass_kg: 0.0,
            payload_com_mm: [0.0; 3],
            gravity_mm_per_s2: [0.0; 3],
            command_latency_s: 0.0,
        }
    }
}

impl Section for PlantConfig {
    /// Checks every field, naming it under `prefix` (e.g. `"plant."`) with its allowed
    /// range and unit.
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let field = |name: &str| format!("{prefix}{name}");
        #[rustfmt::skip]
        let checks: [(&str, f64, f64, f64, &str); 17] = [
            ("stiffness_scale", self.stiffness_scale, 0.1, 10.0, ""),
            ("structural_damping_ratio", self.structural_damping_ratio, 0.0, 1.0, ""),
            ("servo_rate_hz", self.servo_rate_hz, 1000.0, 100_000.0, "Hz"),
            ("carriage_mass_kg", self.carriage_mass_kg, 0.01, 1000.0, "kg"),
            ("servo_kp_n_per_mm", self.servo_kp_n_per_mm, 0.0, 1e5, "N/mm"),
            ("servo_ki_n_per_mm_s", self.servo_ki_n_per_mm_s, 0.0, 1e7, "N/(mm·s)"),
            ("servo_kd_n_s_per_mm", self.servo_kd_n_s_per_mm, 0.0, 1e3, "N·s/mm"),
            ("motor_force_max_n", self.motor_force_max_n, 1.0, 1e5, "N"),
            ("coulomb_friction_n", self.coulomb_friction_n, 0.0, 1e3, "N"),
            ("viscous_friction_n_s_per_mm", self.viscous_friction_n_s_per_mm, 0.0, 100.0, "N·s/mm"),
            ("friction_velocity_mm_per_s", self.friction_velocity_mm_per_s, 1e-4, 100.0, "mm/s"),
            ("tool_mass_kg", self.tool_mass_kg, 0.01, 100.0, "kg"),
            ("tool_inertia_kg_mm2", self.tool_inertia_kg_mm2, 1.0, 1e7, "kg·mm²"),
            ("platform_damping_n_s_per_mm", self.platform_damping_n_s_per_mm, 0.0, 100.0, "N·s/mm"),
            ("encoder_resolution_mm", self.encoder_resolution_mm, 0.0, 1.0, "mm"),
            ("payload_mass_kg", self.payload_mass_kg, 0.0, self.tool_mass_kg, "kg (up to tool_mass_kg)"),
            ("command_latency_s", self.command_latency_s, 0.0, 0.1, "s"),
        ];
        for (name, value, min, max, unit) in checks {
            check_range(&field(name), value, min, max, unit)?;
        }
        for (i, v) in self.stiffness_spread.iter().enumerate() {
            check_range(&field(&format!("stiffness_spread[{i}]")), *v, -0.5, 0.5, "")?;
        }
        for (i, v) in self.payload_com_mm.iter().enumerate() {
            check_range(
                &field(&format!("payload_com_mm[{i}]")),
                *v,
                -500.0,
                500.0,
                "mm",
            )?;
        }
        for (i, v) in self.gravity_mm_per_s2.iter().enumerate() {
            check_range(
                &field(&format!("gravity_mm_per_s2[{i}]")),
                *v,
                -1e5,
                1e5,
                "mm/s²",
            )?;
        }
        Ok(())
    }
}
