//! The turntable: the workpiece turns about the machine's vertical axis (z) through
//! `axis_mm`, driven by its own position servo.
//!
//! The servo is a position loop of bandwidth `bandwidth_hz` (a first-order response,
//! `θ̇ = 2π f (θ_sp − θ)`, for small steps) with a speed limit, an acceleration limit (the
//! motor's torque over the table's inertia: the speed changes by at most
//! `max_accel_rad_per_s2 · dt` per step, so the table never jumps) and a braking curve
//! (`|θ̇| ≤ √(2 a |θ_sp − θ|)`, so a large step arrives without overshoot). The set-point is
//! clamped to the angle limits and the speed towards a limit to the speed from which the
//! table can still stop there; should it nevertheless reach a limit it stops on it (the
//! hard stop, counted). It is integrated with the plant's servo period (50 µs). At a
//! constant commanded speed `Ω` the table lags its set-point by `Ω / (2π f)` (while
//! `Ω < 2a / (2π f)`; faster, the braking curve's `Ω² / (2a)`).
//!
//! The workpiece frame is the base frame turned by the table's angle `θ` about the axis:
//! `p_wp = c + R(−θ) (p − c)` (z unchanged), so at `θ = 0` the two coincide.

use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

/// The turntable (`cutting.turntable` in a slave world or a session file).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TurntableConfig {
    /// The table's axis (x, y), base frame, mm (−1e4 to 1e4).
    pub axis_mm: [f64; 2],
    /// The position loop's bandwidth, Hz (0.1 to 200).
    pub bandwidth_hz: f64,
    /// Speed limit, rad/s (0.01 to 50).
    pub max_speed_rad_per_s: f64,
    /// Acceleration limit, rad/s² (0.01 to 1e4).
    pub max_accel_rad_per_s2: f64,
    /// The angle's limits `[min, max]`, rad (−1e4 to 1e4; min ≤ 0 ≤ max: it starts at 0).
    pub angle_limits_rad: [f64; 2],
    /// The angle encoder's resolution, rad (0 to 0.01; 0: exact).
    pub encoder_resolution_rad: f64,
}

impl Default for TurntableConfig {
    fn default() -> Self {
        TurntableConfig {
            axis_mm: [0.0, 0.0],
            bandwidth_hz: 10.0,
            max_speed_rad_per_s: 3.0,
            max_accel_rad_per_s2: 50.0,
            angle_limits_rad: [-100.0, 100.0],
            encoder_resolution_rad: 1e-5,
        }
    }
}

impl Section for TurntableConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |n: &str| format!("{prefix}{n}");
        for (i, v) in self.axis_mm.iter().enumerate() {
            check_range(&f(&format!("axis_mm[{i}]")), *v, -1e4, 1e4, "mm")?;
        }
        check_range(&f("bandwidth_hz"), self.bandwidth_hz, 0.1, 200.0, "Hz")?;
        check_range(
            &f("max_speed_rad_per_s"),
            self.max_speed_rad_per_s,
            0.01,
            50.0,
            "rad/s",
        )?;
        check_range(
            &f("max_accel_rad_per_s2"),
            self.max_accel_rad_per_s2,
            0.01,
            1e4,
            "rad/s²",
        )?;
        let [lo, hi] = self.angle_limits_rad;
        check_range(&f("angle_limits_rad[0]"), lo, -1e4, 0.0, "rad (≤ 0)")?;
        check_range(&f("angle_limits_rad[1]"), hi, 0.0, 1e4, "rad (≥ 0)")?;
        check_range(
            &f("encoder_resolution_rad"),
            self.encoder_resolution_rad,
            0.0,
            0.01,
            "rad",
        )
    }
}

/// The turntable's state: its true angle and speed, its servo's set-point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Turntable {
    cfg: TurntableConfig,
    /// True angle, rad.
    angle_rad: f64,
    /// True speed, rad/s.
    speed_rad_per_s: f64,
    /// The servo's set-point (clamped to the limits), rad.
    setpoint_rad: f64,
    /// The last set-point commanded (before the clamp), rad.
    commanded_rad: f64,
    /// Times the table hit an angle limit's hard stop.
    limit_hits: u64,
    /// `angle_rad.sin_cos()`, kept by rotating through each period's small step.
    sin_cos: (f64, f64),
    /// Periods since `sin_cos` was last taken exactly.
    since_exact: u32,
}

/// The rotation kept incrementally is re-taken exactly at least this often (periods): the
/// rounding of the incremental products stays near 1e-15.
const SIN_COS_EXACT_EVERY: u32 = 1024;
/// Steps of the angle up to this size, rad, rotate the kept sine and cosine by their Taylor
/// series (terms to the fifth and sixth order: truncation below 1e-24); larger ones are
/// taken exactly.
const SIN_COS_TAYLOR_MAX_RAD: f64 = 1e-3;

impl Turntable {
    /// A table at rest at angle 0, its set-point 0.
    pub fn new(cfg: TurntableConfig) -> Self {
        Turntable {
            cfg,
            angle_rad: 0.0,
            speed_rad_per_s: 0.0,
            setpoint_rad: 0.0,
            commanded_rad: 0.0,
            limit_hits: 0,
            sin_cos: (0.0, 1.0),
            since_exact: 0,
        }
    }

    /// The sine and cosine of the true angle (kept with it: one servo period's step turns
    /// them by a small rotation, taken exactly every `SIN_COS_EXACT_EVERY` periods).
    #[inline]
    pub fn sin_cos(&self) -> (f64, f64) {
        self.sin_cos
    }

    /// The configuration.
    pub fn config(&self) -> &TurntableConfig {
        &self.cfg
    }

    /// True angle, rad (simulation truth).
    pub fn angle_rad(&self) -> f64 {
        self.angle_rad
    }

    /// True speed, rad/s (simulation truth).
    pub fn speed_rad_per_s(&self) -> f64 {
        self.speed_rad_per_s
    }

    /// The angle its encoder reads, rad (quantised to `encoder_resolution_rad`).
    pub fn measured_rad(&self) -> f64 {
        let res = self.cfg.encoder_resolution_rad;
        if res > 0.0 {
            (self.angle_rad / res).round() * res
        } else {
            self.angle_rad
        }
    }

    /// The last commanded set-point, rad.
    pub fn commanded_rad(&self) -> f64 {
        self.commanded_rad
    }

    /// Times the table reached an angle limit (its hard stop).
    pub fn limit_hits(&self) -> u64 {
        self.limit_hits
    }

    /// A new set-point, rad; clamped to the angle limits; a non-finite one is refused (the
    /// servo keeps the last).
    pub fn command(&mut self, angle_rad: f64) {
        if !angle_rad.is_finite() {
            return;
        }
        self.commanded_rad = angle_rad;
        let [lo, hi] = self.cfg.angle_limits_rad;
        self.setpoint_rad = angle_rad.clamp(lo, hi);
    }

    /// One servo period of `dt_s`: the speed moves towards the position loop's demand by
    /// at most the acceleration limit, the angle by the mean speed. Allocates nothing.
    #[inline]
    pub fn step(&mut self, dt_s: f64) {
        let c = &self.cfg;
        let a = c.max_accel_rad_per_s2;
        let k = 2.0 * std::f64::consts::PI * c.bandwidth_hz;
        let e = self.setpoint_rad - self.angle_rad;
        // The braking curves look one period ahead (the speed reaches the demand a period
        // late): the distance left after this period at the present speed.
        let ahead = self.speed_rad_per_s.abs() * dt_s;
        let brake = |d: f64| (2.0 * a * (d - ahead).max(0.0)).sqrt();
        let demand = e.signum() * (k * e.abs()).min(brake(e.abs()));
        let [lo, hi] = c.angle_limits_rad;
        let (up, down) = (brake(hi - self.angle_rad), brake(self.angle_rad - lo));
        let demand = demand
            .clamp(-c.max_speed_rad_per_s, c.max_speed_rad_per_s)
            .clamp(-down, up);
        let dv = (demand - self.speed_rad_per_s).clamp(-a * dt_s, a * dt_s);
        let v0 = self.speed_rad_per_s;
        let before_rad = self.angle_rad;
        self.speed_rad_per_s += dv;
        self.angle_rad += 0.5 * (v0 + self.speed_rad_per_s) * dt_s;
        if self.angle_rad > hi || self.angle_rad < lo {
            // On the stop: an impact if it arrived faster than one period's braking.
            if self.speed_rad_per_s.abs() > a * dt_s {
                self.limit_hits += 1;
            }
            self.angle_rad = self.angle_rad.clamp(lo, hi);
            self.speed_rad_per_s = 0.0;
        }
        self.turn_sin_cos(self.angle_rad - before_rad);
    }

    /// Keeps `sin_cos` with the angle after a step of `d_rad`.
    #[inline]
    fn turn_sin_cos(&mut self, d_rad: f64) {
        self.since_exact += 1;
        if d_rad.abs() > SIN_COS_TAYLOR_MAX_RAD || self.since_exact >= SIN_COS_EXACT_EVERY {
            self.sin_cos = self.angle_rad.sin_cos();
            self.since_exact = 0;
            return;
        }
        let d2 = d_rad * d_rad;
        let sd = d_rad * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0));
        let cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0));
        let (s, c) = self.sin_cos;
        self.sin_cos = (s * cd + c * sd, c * cd - s * sd);
    }

    /// The base-frame point `p_mm` in the workpiece frame (at the true angle), mm.
    #[inline]
    pub fn to_workpiece(&self, p_mm: [f64; 3]) -> [f64; 3] {
        let (s, co) = self.sin_cos;
        let [ax, ay] = self.cfg.axis_mm;
        let (rx, ry) = (p_mm[0] - ax, p_mm[1] - ay);
        [ax + co * rx + s * ry, ay - s * rx + co * ry, p_mm[2]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 50e-6;

    /// The sine and cosine kept through the steps match the angle's own: ramps at full
    /// speed up to an angle limit and back, 400 000 periods.
    #[test]
    fn the_kept_sin_cos_is_the_angles() {
        let mut t = table(10.0, 3.0, 50.0, [-10.0, 10.0]);
        let mut worst: f64 = 0.0;
        let mut highest: f64 = 0.0;
        for k in 0..400_000u32 {
            if k % 100_000 == 0 {
                t.command(if k % 200_000 == 0 { 45.0 } else { -3.0 });
            }
            t.step(DT);
            let (s, c) = t.angle_rad().sin_cos();
            let (ks, kc) = t.sin_cos();
            worst = worst.max((s - ks).abs()).max((c - kc).abs());
            highest = highest.max(t.angle_rad());
        }
        assert!(highest > 9.99, "the ramp reached the limit: {highest}");
        assert!(worst < 1e-12, "kept sin/cos off by {worst}");
    }

    fn table(bw: f64, v: f64, a: f64, lim: [f64; 2]) -> Turntable {
        Turntable::new(TurntableConfig {
            bandwidth_hz: bw,
            max_speed_rad_per_s: v,
            max_accel_rad_per_s2: a,
            angle_limits_rad: lim,
            encoder_resolution_rad: 0.0,
            ..TurntableConfig::default()
        })
    }

    /// A small step (inside the linear region of the loop) follows the first-order
    /// response of the configured bandwidth, `1 − e^{−2π f t}`, and never overshoots.
    #[test]
    fn small_step_follows_the_bandwidth() {
        for bw in [2.0, 10.0] {
            let mut t = table(bw, 3.0, 1e4, [-100.0, 100.0]);
            let step = 1e-3;
            t.command(step);
            let k = 2.0 * std::f64::consts::PI * bw;
            let mut worst: f64 = 0.0;
            let mut peak: f64 = 0.0;
            let steps = (5.0 / k / DT) as usize;
            for i in 1..=steps {
                t.step(DT);
                let time = i as f64 * DT;
                let want = step * (1.0 - (-k * time).exp());
                worst = worst.max((t.angle_rad() - want).abs());
                peak = peak.max(t.angle_rad());
            }
            assert!(worst < 0.03 * step, "{bw} Hz: off the response by {worst}");
            assert!(peak <= step * (1.0 + 1e-9), "{bw} Hz: overshoot {peak}");
            // A 63 % rise at 1/(2π f): within 5 %.
            let mut t = table(bw, 3.0, 1e4, [-100.0, 100.0]);
            t.command(step);
            let mut n = 0;
            while t.angle_rad() < 0.632 * step {
                t.step(DT);
                n += 1;
            }
            let rise = n as f64 * DT;
            assert!((rise * k - 1.0).abs() < 0.05, "{bw} Hz: rise {rise} s");
        }
    }

    /// A large step meets the speed and acceleration limits: the speed never exceeds its
    /// limit, it changes by at most the acceleration limit per period, the angle moves
    /// continuously and arrives without overshoot.
    #[test]
    fn a_large_step_respects_speed_and_acceleration_limits() {
        let (vmax, amax) = (2.0, 8.0);
        let mut t = table(10.0, vmax, amax, [-100.0, 100.0]);
        t.command(5.0);
        let (mut top, mut acc, mut jump, mut peak) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        let (mut v_prev, mut a_prev) = (0.0, 0.0);
        for _ in 0..(8.0 / DT) as usize {
            t.step(DT);
            top = top.max(t.speed_rad_per_s().abs());
            acc = acc.max((t.speed_rad_per_s() - v_prev).abs() / DT);
            jump = jump.max((t.angle_rad() - a_prev).abs());
            peak = peak.max(t.angle_rad());
            v_prev = t.speed_rad_per_s();
            a_prev = t.angle_rad();
        }
        assert!(top <= vmax + 1e-9 && top > 0.99 * vmax, "speed {top}");
        assert!(acc <= amax * (1.0 + 1e-9), "acceleration {acc}");
        assert!(
            jump <= vmax * DT * (1.0 + 1e-9),
            "jumped {jump} rad in a period"
        );
        assert!(peak <= 5.0 + 1e-6, "overshoot to {peak}");
        assert!((t.angle_rad() - 5.0).abs() < 1e-4, "{}", t.angle_rad());
    }

    /// Commanded beyond its limits, the table stops at the limit (braking before it, not
    /// against the hard stop), and NaN commands are refused.
    #[test]
    fn the_angle_limits_hold() {
        let mut t = table(10.0, 3.0, 20.0, [-0.5, 1.0]);
        t.command(7.0);
        let mut peak: f64 = 0.0;
        for _ in 0..(4.0 / DT) as usize {
            t.step(DT);
            peak = peak.max(t.angle_rad());
        }
        assert!(peak <= 1.0, "past the limit: {peak}");
        assert!((t.angle_rad() - 1.0).abs() < 1e-4, "{}", t.angle_rad());
        assert_eq!(t.limit_hits(), 0, "braked against the hard stop");
        assert_eq!(t.commanded_rad(), 7.0);
        t.command(-9.0);
        t.command(f64::NAN);
        let mut low: f64 = 0.0;
        for _ in 0..(4.0 / DT) as usize {
            t.step(DT);
            low = low.min(t.angle_rad());
        }
        assert!(low >= -0.5 && (t.angle_rad() + 0.5).abs() < 1e-4, "{low}");
        assert_eq!(t.commanded_rad(), -9.0);
    }

    /// A constant-speed ramp is followed with the lag `Ω / (2π f)`; the encoder quantises.
    #[test]
    fn a_ramp_lags_by_speed_over_bandwidth() {
        let mut t = Turntable::new(TurntableConfig::default());
        let omega = 0.8;
        let mut sp = 0.0;
        for _ in 0..3000 {
            sp += omega * 1e-3;
            t.command(sp);
            for _ in 0..20 {
                t.step(DT);
            }
        }
        let lag = sp - t.angle_rad();
        let want = omega / (2.0 * std::f64::consts::PI * 10.0);
        assert!((lag - want).abs() < 0.02 * want, "lag {lag} vs {want}");
        // The set-point is a 1 kHz staircase: the speed ripples about Ω within each step.
        assert!((t.speed_rad_per_s() - omega).abs() < 0.1 * omega);
        let m = t.measured_rad();
        assert!((m - t.angle_rad()).abs() <= 0.5e-5 + 1e-12);
        assert!(((m / 1e-5).round() * 1e-5 - m).abs() < 1e-12);
    }

    #[test]
    fn workpiece_frame_turns_with_the_table() {
        let mut t = Turntable::new(TurntableConfig {
            axis_mm: [10.0, -5.0],
            ..TurntableConfig::default()
        });
        assert_eq!(t.to_workpiece([13.0, -5.0, 2.0]), [13.0, -5.0, 2.0]);
        t.angle_rad = std::f64::consts::FRAC_PI_2;
        t.sin_cos = t.angle_rad.sin_cos();
        // A quarter turn on: the base point at +x of the axis was the part's −y.
        let p = t.to_workpiece([13.0, -5.0, 2.0]);
        assert!(
            (p[0] - 10.0).abs() < 1e-12 && (p[1] + 8.0).abs() < 1e-12,
            "{p:?}"
        );
    }

    #[test]
    fn config_names_its_fields() {
        assert!(TurntableConfig::default().validate_at("t.").is_ok());
        let c = TurntableConfig {
            angle_limits_rad: [0.5, 1.0],
            ..TurntableConfig::default()
        };
        let e = c.validate_at("cutting.turntable.").unwrap_err().to_string();
        assert!(e.contains("cutting.turntable.angle_limits_rad[0]"), "{e}");
        let c = TurntableConfig {
            bandwidth_hz: 0.0,
            ..TurntableConfig::default()
        };
        let e = c.validate_at("cutting.turntable.").unwrap_err().to_string();
        assert!(e.contains("bandwidth_hz"), "{e}");
    }
}
