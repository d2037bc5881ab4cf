//! The controller's tuning, `controller.*` in experiment and session files.

use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

/// Tuning of the controller (`controller.*` in experiment files).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ControllerParams {
    /// Use the arm's compliance matrix Λ(x) (deflection-corrected pose, arm compliance in
    /// the loop gain). `false` treats the arm as rigid.
    pub compliance_model: bool,
    /// Largest speed of the commanded tool point, mm/s.
    pub max_speed_mm_per_s: f64,
    /// Largest acceleration in position mode, mm/s².
    pub max_accel_mm_per_s2: f64,
    /// Acceleration of the motion along the surface in ForceGuided mode, mm/s².
    pub track_accel_mm_per_s2: f64,
    /// Largest acceleration of the force loop's motion along the contact normal, mm/s²
    /// (a rate limit's corners would ring the tool on the arm's stiffness; the force
    /// limit's back-off ignores it).
    pub force_accel_mm_per_s2: f64,
    /// Largest rate of theta, rad/s.
    pub max_theta_rate_rad_per_s: f64,
    /// Speed of the approach towards an unknown surface and of re-approach, mm/s.
    pub approach_speed_mm_per_s: f64,
    /// Force limit: set-points above it are rejected, measured forces above it make the arm
    /// back off, N.
    pub force_limit_n: f64,
    /// Force that signals contact, N.
    pub contact_threshold_n: f64,
    /// Normal force below which contact counts as lost, N.
    pub contact_lost_n: f64,
    /// Consecutive cycles below `contact_lost_n` before contact is declared lost.
    pub contact_lost_cycles: u32,
    /// Time constant of the set-point prefilter (critically damped, 2nd order), s.
    pub setpoint_time_constant_s: f64,
    /// Mass of the platform with sensor and tool, kg (for the contact resonance).
    pub tool_mass_kg: f64,
    /// Share of the set-point change fed forward through the compliance (0 to 1.5); below 1
    /// keeps an over-estimated compliance from overshooting, the PI terms close the rest.
    pub feedforward_gain: f64,
    /// Proportional gain of the force loop, relative (dimensionless).
    pub kp: f64,
    /// Integral gain of the force loop, 1/s.
    pub ki_per_s: f64,
    /// Environment stiffness assumed before the estimator has data, N/mm.
    pub initial_env_stiffness_n_per_mm: f64,
    /// Lower bound of the environment stiffness estimate, N/mm.
    pub env_stiffness_min_n_per_mm: f64,
    /// Upper bound of the environment stiffness estimate, N/mm.
    pub env_stiffness_max_n_per_mm: f64,
    /// Turn the online estimation of the environment's stiffness on.
    pub estimate_env_stiffness: bool,
    /// Forgetting factor of the estimator, per update (0.5 to 1).
    pub estimator_forgetting: f64,
    /// Window of the force/position increments the estimator uses, cycles (2 to 64).
    pub estimator_window_cycles: u32,
    /// Smallest force increment over the window that updates the estimate, N.
    pub estimator_excitation_n: f64,
    /// Time constant of the contact-normal filter, s.
    pub normal_time_constant_s: f64,
    /// Time constant of the low-pass filter on the difference between the measured force
    /// and the prefiltered set-point in the compensation of the arm's tangential
    /// deflection, s (0 to 1; below one cycle: no filtering).
    pub deflection_comp_time_constant_s: f64,
    /// Cut-off of the filter applied to the measured position so it lines up with the
    /// force sensor's filtered signal, Hz (set it to the sensor filter's cut-off).
    pub sensor_filter_cutoff_hz: f64,
    /// Cycles at start-up averaged (in free space) to estimate the sensor's bias.
    pub tare_cycles: u32,
    /// Take the identified tool's weight and inertia (`arm.tool`) off the sensor's reading.
    pub gravity_compensation: bool,
    /// A stall reported by the spindle drive puts the slave into its safe stop, which the
    /// master cannot clear while the stall lasts. Off only to show what it does.
    pub spindle_stall_safe_stop: bool,
    /// Gravity in the base frame as the controller knows it, mm/s² (the machine's vertical
    /// axis).
    pub gravity_mm_per_s2: [f64; 3],
    /// The read-to-command latency the controller assumes, cycles (0 to 10): a command
    /// acts this many cycles after the reading it came from; the force law predicts the
    /// force of the commands still in flight (a Smith predictor) and the compensation
    /// takes the acceleration that old.
    pub command_latency_cycles: u32,
    /// The axis the contact force is controlled along when it is known, base frame (any
    /// length, normalised): the tool's axis when milling, where the cutter's feed and
    /// cross-feed forces say nothing about the surface's normal. Unset: the normal is
    /// estimated from the force and the motion.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub force_axis: Option<[f64; 3]>,
    /// ForceGuided: gain pulling the tool point along the surface towards the commanded
    /// point's tangential part, 1/s (0 to 100; 0: the motion along the surface follows the
    /// commanded velocity only, and its ramps let the point drift from the master's).
    #[serde(skip_serializing_if = "is_zero")]
    #[schemars(!skip_serializing_if)]
    pub track_position_gain_per_s: f64,
    /// In contact: the fastest motion along the surface, mm/s (0 to 1e4; 0: none but
    /// `max_speed_mm_per_s`). A cutter's feed limit (feed per tooth × flutes × spindle
    /// speed): a tool pulled along faster than it can cut is rammed into the stock.
    #[serde(skip_serializing_if = "is_zero")]
    #[schemars(!skip_serializing_if)]
    pub max_feed_mm_per_s: f64,
    /// Contact detection: the force along the approach must exceed this many standard
    /// deviations of the sensor's noise (measured while taring) besides
    /// `contact_threshold_n` (3 to 20).
    pub contact_noise_sigmas: f64,
    /// Safe stop in contact: time the force set-point is held (motion stopped) before it
    /// ramps down, s: a link that returns within it re-pairs without the tool leaving the
    /// surface (ride-through); 0 ramps down at once.
    #[serde(default = "default_safe_stop_hold_s")]
    pub safe_stop_hold_s: f64,
    /// Safe stop: time to ramp the force to zero, s.
    pub safe_stop_ramp_s: f64,
    /// Safe stop: retraction along the contact normal, mm.
    pub safe_stop_retract_mm: f64,
    /// Safe stop out of a position-mode contact: the farthest the arm backs away along the
    /// measured force before giving up and holding, mm.
    pub safe_stop_release_max_mm: f64,
}

impl Default for ControllerParams {
    fn default() -> Self {
        ControllerParams {
            compliance_model: true,
            max_speed_mm_per_s: 100.0,
            max_accel_mm_per_s2: 1000.0,
            max_theta_rate_rad_per_s: 1.0,
            track_accel_mm_per_s2: 5.0,
            force_accel_mm_per_s2: 5000.0,
            approach_speed_mm_per_s: 2.0,
            force_limit_n: 80.0,
            contact_threshold_n: 0.8,
            contact_lost_n: 0.3,
            contact_lost_cycles: 20,
            setpoint_time_constant_s: 0.015,
            tool_mass_kg: 1.0,
            feedforward_gain: 1.0,
            kp: 0.3,
            ki_per_s: 80.0,
            initial_env_stiffness_n_per_mm: 200.0,
            env_stiffness_min_n_per_mm: 1.0,
            env_stiffness_max_n_per_mm: 20_000.0,
            estimate_env_stiffness: true,
            estimator_forgetting: 0.98,
            estimator_window_cycles: 10,
            estimator_excitation_n: 0.4,
            normal_time_constant_s: 0.1,
            deflection_comp_time_constant_s: 0.03,
            sensor_filter_cutoff_hz: 80.0,
            tare_cycles: 100,
            gravity_compensation: true,
            spindle_stall_safe_stop: true,
            gravity_mm_per_s2: [0.0, 0.0, -9810.0],
            command_latency_cycles: 0,
            force_axis: None,
            track_position_gain_per_s: 0.0,
            max_feed_mm_per_s: 0.0,
            contact_noise_sigmas: 8.0,
            safe_stop_hold_s: default_safe_stop_hold_s(),
            safe_stop_ramp_s: 0.2,
            safe_stop_retract_mm: 3.0,
            safe_stop_release_max_mm: 50.0,
        }
    }
}

impl Section for ControllerParams {
    /// Checks every field (the switches aside), naming it under `prefix` (e.g.
    /// `"controller."`) with its allowed range and unit.
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let field = |name: &str| format!("{prefix}{name}");
        #[rustfmt::skip]
        let checks: [(&str, f64, f64, f64, &str); 32] = [
            ("force_limit_n", self.force_limit_n, 1.0, 1000.0, "N"),
            ("max_speed_mm_per_s", self.max_speed_mm_per_s, 0.1, 1000.0, "mm/s"),
            ("force_accel_mm_per_s2", self.force_accel_mm_per_s2, 1.0, 1e7, "mm/s²"),
            ("max_accel_mm_per_s2", self.max_accel_mm_per_s2, 1.0, 1e5, "mm/s²"),
            ("track_accel_mm_per_s2", self.track_accel_mm_per_s2, 0.01, 1e5, "mm/s²"),
            ("max_theta_rate_rad_per_s", self.max_theta_rate_rad_per_s, 0.01, 10.0, "rad/s"),
            (
                "approach_speed_mm_per_s",
                self.approach_speed_mm_per_s,
                0.01, self.max_speed_mm_per_s, "mm/s",
            ),
            ("contact_threshold_n", self.contact_threshold_n, 0.01, 100.0, "N"),
            (
                "contact_lost_n",
                self.contact_lost_n,
                0.0, self.contact_threshold_n, "N (up to contact_threshold_n)",
            ),
            ("contact_lost_cycles", f64::from(self.contact_lost_cycles), 1.0, 10_000.0, "cycles"),
            ("setpoint_time_constant_s", self.setpoint_time_constant_s, 0.0, 10.0, "s"),
            ("tool_mass_kg", self.tool_mass_kg, 0.01, 100.0, "kg"),
            ("kp", self.kp, 0.0, 10.0, ""),
            ("feedforward_gain", self.feedforward_gain, 0.0, 1.5, ""),
            ("ki_per_s", self.ki_per_s, 0.0, 1000.0, "1/s"),
            (
                "initial_env_stiffness_n_per_mm",
                self.initial_env_stiffness_n_per_mm,
                0.1, 1e6, "N/mm",
            ),
            ("env_stiffness_min_n_per_mm", self.env_stiffness_min_n_per_mm, 0.01, 1e6, "N/mm"),
            (
                "env_stiffness_max_n_per_mm",
                self.env_stiffness_max_n_per_mm,
                self.env_stiffness_min_n_per_mm, 1e7, "N/mm (≥ env_stiffness_min_n_per_mm)",
            ),
            ("estimator_forgetting", self.estimator_forgetting, 0.5, 1.0, ""),
            (
                "estimator_window_cycles",
                f64::from(self.estimator_window_cycles),
                2.0, 63.0, "cycles",
            ),
            ("estimator_excitation_n", self.estimator_excitation_n, 0.0, 100.0, "N"),
            ("normal_time_constant_s", self.normal_time_constant_s, 0.0, 10.0, "s"),
            (
                "deflection_comp_time_constant_s",
                self.deflection_comp_time_constant_s,
                0.0, 1.0, "s",
            ),
            ("sensor_filter_cutoff_hz", self.sensor_filter_cutoff_hz, 1.0, 1e5, "Hz"),
            ("tare_cycles", f64::from(self.tare_cycles), 1.0, 100_000.0, "cycles"),
            ("command_latency_cycles", f64::from(self.command_latency_cycles), 0.0, 10.0, "cycles"),
            ("contact_noise_sigmas", self.contact_noise_sigmas, 3.0, 20.0, ""),
            ("max_feed_mm_per_s", self.max_feed_mm_per_s, 0.0, 1e4, "mm/s"),
            ("safe_stop_hold_s", self.safe_stop_hold_s, 0.0, 5.0, "s"),
            ("safe_stop_ramp_s", self.safe_stop_ramp_s, 0.0, 60.0, "s"),
            ("safe_stop_retract_mm", self.safe_stop_retract_mm, 0.0, 100.0, "mm"),
            ("safe_stop_release_max_mm", self.safe_stop_release_max_mm, 0.0, 500.0, "mm"),
        ];
        for (name, value, min, max, unit) in checks {
            check_range(&field(name), value, min, max, unit)?;
        }
        for (i, g) in self.gravity_mm_per_s2.iter().enumerate() {
            check_range(
                &field(&format!("gravity_mm_per_s2[{i}]")),
                *g,
                -1e5,
                1e5,
                "mm/s²",
            )?;
        }
        check_range(
            &field("track_position_gain_per_s"),
            self.track_position_gain_per_s,
            0.0,
            100.0,
            "1/s",
        )?;
        if let Some(a) = self.force_axis {
            let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            check_range(&field("force_axis"), n, 1e-3, 1e3, "(length of the vector)")?;
        }
        Ok(())
    }
}

fn default_safe_stop_hold_s() -> f64 {
    0.5
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl ControllerParams {
    /// [`ControllerParams::force_axis`] as a unit vector.
    pub fn force_axis_unit(&self) -> Option<[f64; 3]> {
        let a = self.force_axis?;
        let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        (n > 1e-3 && n.is_finite()).then(|| [a[0] / n, a[1] / n, a[2] / n])
    }
}
