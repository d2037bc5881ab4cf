//! Gain schedule (docs/slave-results.md, "Gain schedule"). With the compliance right, the
//! loop (command c·ΔF → force) is an integrator of gain ki at low frequency: the same
//! bandwidth on every surface. What limits the gains is the contact mode, the tool's mass
//! between the arm's and the surface's stiffness (in parallel: both hold the tool),
//! ω_m = sqrt((k_arm + k_env)/m), which only the arm's structural damping damps on a soft
//! surface (resonance gain up to [`MODE_Q`]). The controller's gain at ω_m,
//! |kp + ki/(jω_m)|, times the resonance gain and the sensor filter's |H(jω_m)| must stay
//! below [`MODE_LOOP_GAIN`]. On a stiff surface ω_m is far above the filter's cut-off and
//! the tuned gains pass; on a soft one ω_m sits at the cut-off: the proportional gain (which
//! acts at high frequency) goes first, then the integral gain.

use super::params::ControllerParams;

/// Resonance gain assumed for the contact mode (the tool's mass between the arm and the
/// surface) where only the arm's structural damping damps it (ζ ≈ 0.05).
pub(super) const MODE_Q: f64 = 10.0;
/// Largest loop gain at the contact mode.
const MODE_LOOP_GAIN: f64 = 0.6;

/// The contact mode and the gain factors of this cycle (no state: it follows the
/// compliance estimates).
#[derive(Clone, Copy, Debug)]
pub(super) struct GainSchedule {
    /// Stiffness of the contact mode, arm and environment in parallel, N/mm.
    pub(super) k_par_n_per_mm: f64,
    /// Angular frequency of the contact mode, rad/s.
    pub(super) omega_m_rad_per_s: f64,
    /// Factor on `kp` (0 to 1).
    pub(super) kp_scale: f64,
    /// Factor on `ki_per_s` (0 to 1).
    pub(super) ki_scale: f64,
}

impl GainSchedule {
    /// The schedule for the arm's compliance `c_arm` and the environment's `c_env` along
    /// the normal, mm/N.
    pub(super) fn at(c_arm: f64, c_env: f64, p: &ControllerParams) -> Self {
        let c_arm_s = c_arm.max(1e-9);
        let k_par = 1.0 / c_arm_s + 1.0 / c_env.max(1e-9);
        let omega_m = (1000.0 * k_par / p.tool_mass_kg.max(1e-6)).sqrt();
        let w_f = omega_m / (2.0 * std::f64::consts::PI * p.sensor_filter_cutoff_hz.max(1.0));
        let h_f = 1.0 / (1.0 + w_f * w_f * w_f * w_f).sqrt();
        let allowed = MODE_LOOP_GAIN / (MODE_Q * h_f);
        let ki_w = p.ki_per_s / omega_m;
        let ki_scale = (allowed / ki_w.max(1e-12)).min(1.0);
        let kp_scale = if p.kp > 0.0 {
            ((allowed - ki_w).max(0.0) / p.kp).min(1.0)
        } else {
            1.0
        };
        GainSchedule {
            k_par_n_per_mm: k_par,
            omega_m_rad_per_s: omega_m,
            kp_scale,
            ki_scale,
        }
    }
}
