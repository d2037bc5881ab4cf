//! The mechanical and servo parameters of the simulated arm (`plant.*`).

use serde::{Deserialize, Serialize};

/// The mechanical and servo parameters of the simulated arm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlantConfig {
    /// Plant actuator stiffness = the controller's assumed stiffness × this (0.1 to 10).
    pub stiffness_scale: f64,
    /// Extra relative deviation of each actuator's stiffness (−0.5 to 0.5): actuator i has
    /// assumed_i × stiffness_scale × (1 + stiffness_spread[i]).
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
        }
    }
}
