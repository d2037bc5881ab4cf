//! The carriages' position servo: a PID on the encoder (derivative on the measurement,
//! anti-windup) with a saturated motor force, Coulomb and viscous friction, integrated per
//! servo period.

use super::config::PlantConfig;

/// The carriages' servo and friction constants, taken out of the substep loops.
#[derive(Clone, Copy)]
pub(super) struct CarriageServo {
    kp: f64,
    ki_dt: f64,
    kd: f64,
    u_max: f64,
    inv_v0: f64,
    fc_n: f64,
    fv: f64,
    dt: f64,
    dt_over_m_c: f64,
}

impl CarriageServo {
    pub(super) fn new(cfg: &PlantConfig, dt: f64) -> Self {
        CarriageServo {
            kp: cfg.servo_kp_n_per_mm,
            ki_dt: cfg.servo_ki_n_per_mm_s * dt,
            kd: cfg.servo_kd_n_s_per_mm,
            u_max: cfg.motor_force_max_n,
            inv_v0: 1.0 / cfg.friction_velocity_mm_per_s,
            fc_n: cfg.coulomb_friction_n,
            fv: cfg.viscous_friction_n_s_per_mm,
            dt,
            dt_over_m_c: (1.0 / (cfg.carriage_mass_kg * 1e-3)) * dt,
        }
    }

    /// One servo period of a carriage: PID on the encoder (derivative on the measurement,
    /// anti-windup), the structural force `f_struct_n` (positive when the platform pulls the
    /// carriage forward), Coulomb and viscous friction. Returns the new velocity.
    #[inline(always)]
    pub(super) fn step(
        &self,
        cmd: f64,
        q: &mut f64,
        qd: &mut f64,
        integ: &mut f64,
        f_struct_n: f64,
    ) -> f64 {
        let e = cmd - *q;
        let i_term = *integ + self.ki_dt * e;
        let u_raw = self.kp * e + i_term - self.kd * *qd;
        let u = clamp_sel(u_raw, -self.u_max, self.u_max);
        if u == u_raw {
            *integ = i_term;
        }
        let v = *qd;
        let friction = self.fc_n * clamp_sel(v * self.inv_v0, -1.0, 1.0) + self.fv * v;
        let v_new = (v + (u - friction) * self.dt_over_m_c) + f_struct_n * self.dt_over_m_c;
        *qd = v_new;
        *q += v_new * self.dt;
        v_new
    }
}

/// `x` limited to `[lo, hi]` as two selects (`maxsd`/`minsd`, no branch; `f64::clamp`
/// branches, and `f64::max`/`min` add NaN handling).
#[inline(always)]
pub(super) fn clamp_sel(x: f64, lo: f64, hi: f64) -> f64 {
    let y = if x > lo { x } else { lo };
    if y < hi { y } else { hi }
}
