//! The implicit force law, incremental (bumpless when the compliance changes):
//! `Δd = c · (ff ΔF_r + g (k_p Δe + k_i e dt))`, `F_r` the set-point after a critically
//! damped second-order prefilter, `c` the compliance along the normal, `g` the oscillation
//! guard's factor; then the force limit, the speed limit and the acceleration limit of the
//! motion along the normal.

use super::gain_schedule::GainSchedule;
use super::guards::OscillationGuard;
use super::params::ControllerParams;

/// Force guard: ratio of an oscillation's peak to its mean cycle-to-cycle swing as the
/// filtered sensor shows it (a sine of amplitude A near 100 Hz swings ≈ 0.4 A per 1 ms,
/// and the 80 Hz filter shows ≈ 0.55 A of it).
const GUARD_PEAK_PER_SWING: f64 = 5.0;

/// The set-point prefilter: two first-order stages of `setpoint_time_constant_s`.
#[derive(Clone, Copy, Debug)]
pub(super) struct SetpointPrefilter {
    stage1_n: f64,
    /// The prefiltered set-point, N.
    pub(super) value_n: f64,
}

impl SetpointPrefilter {
    /// At zero.
    pub(super) fn new() -> Self {
        SetpointPrefilter {
            stage1_n: 0.0,
            value_n: 0.0,
        }
    }

    /// Starts at `force_n` (bumpless at a touch).
    pub(super) fn reset(&mut self, force_n: f64) {
        self.stage1_n = force_n;
        self.value_n = force_n;
    }

    /// One step towards `setpoint_n`; returns the change of the output, N.
    pub(super) fn step(&mut self, setpoint_n: f64, time_constant_s: f64, dt: f64) -> f64 {
        let a_sp = (dt / time_constant_s.max(dt)).min(1.0);
        let sp_prev = self.value_n;
        self.stage1_n += (setpoint_n - self.stage1_n) * a_sp;
        self.value_n += (self.stage1_n - self.value_n) * a_sp;
        self.value_n - sp_prev
    }
}

/// Steps into the surface kept for the latency's prediction (latency up to this many cycles).
const IN_FLIGHT_MAX: usize = 11;

/// The force law's state: the last error, the last step along the normal, and the steps
/// sent but not yet acting (the read-to-command latency).
#[derive(Clone, Copy, Debug)]
pub(super) struct ForceLaw {
    /// Last cycle's force error, N.
    pub(super) e_prev_n: f64,
    /// Last cycle's step along the normal, mm.
    depth_step_mm: f64,
    /// The steps into the surface sent in the last cycles, newest at `head`, mm.
    in_flight_mm: [f64; IN_FLIGHT_MAX],
    head: usize,
}

/// What the force law reads this cycle.
#[derive(Clone, Copy, Debug)]
pub(super) struct ForceLawInputs {
    /// The measured force along the normal, N.
    pub(super) f_n: f64,
    /// The prefiltered set-point, N.
    pub(super) sp: f64,
    /// Its change this cycle, N.
    pub(super) d_sp: f64,
    /// The total compliance along the normal (arm + environment), mm/N.
    pub(super) c: f64,
}

/// One cycle of the force law.
#[derive(Clone, Copy, Debug)]
pub(super) struct ForceLawStep {
    /// The step into the surface (before shaping), mm.
    pub(super) d_depth_mm: f64,
    /// The normal force with the oscillation's unseen peak added, N.
    pub(super) f_peak_n: f64,
    /// The force limit backed the command off.
    pub(super) limited: bool,
}

impl ForceLaw {
    /// At rest.
    pub(super) fn new() -> Self {
        ForceLaw {
            e_prev_n: 0.0,
            depth_step_mm: 0.0,
            in_flight_mm: [0.0; IN_FLIGHT_MAX],
            head: 0,
        }
    }

    /// At a touch: no error, no motion.
    pub(super) fn touch(&mut self) {
        self.e_prev_n = 0.0;
        self.depth_step_mm = 0.0;
        self.in_flight_mm = [0.0; IN_FLIGHT_MAX];
    }

    /// Books the step into the surface actually sent this cycle, mm.
    pub(super) fn sent(&mut self, d_depth_mm: f64) {
        self.head = (self.head + 1) % IN_FLIGHT_MAX;
        self.in_flight_mm[self.head] = d_depth_mm;
    }

    /// The force the steps of the last `latency_cycles` cycles will add once they act
    /// (they left after the reading this cycle's force came from): their depth over the
    /// compliance `c`, N (a Smith predictor of the latency).
    fn in_flight_force_n(&self, latency_cycles: u32, c: f64) -> f64 {
        let l = (latency_cycles as usize).min(IN_FLIGHT_MAX - 1);
        let mut depth = 0.0;
        for back in 0..l {
            depth += self.in_flight_mm[(self.head + IN_FLIGHT_MAX - back) % IN_FLIGHT_MAX];
        }
        depth / c.max(1e-9)
    }

    /// One cycle from `inp`; `guard` is the oscillation guard (fed this cycle's error).
    pub(super) fn step(
        &mut self,
        inp: &ForceLawInputs,
        gains: &GainSchedule,
        guard: &mut OscillationGuard,
        p: &ControllerParams,
        dt: f64,
    ) -> ForceLawStep {
        let ForceLawInputs { f_n, sp, d_sp, c } = *inp;
        let e = sp - (f_n + self.in_flight_force_n(p.command_latency_cycles, c));
        let de = e - self.e_prev_n;
        guard.observe(de);
        let mut d_depth = c
            * (p.feedforward_gain * d_sp
                + guard.gain
                    * (gains.kp_scale * p.kp * (e - self.e_prev_n)
                        + gains.ki_scale * p.ki_per_s * e * dt));
        self.e_prev_n = e;
        // The force the sensor does not show yet: a resonance's peaks are filtered down
        // (an oscillation's amplitude is a few times its mean cycle-to-cycle swing).
        let f_peak = f_n + GUARD_PEAK_PER_SWING * guard.swing_n;
        let limited = f_peak > p.force_limit_n;
        if limited {
            d_depth = -c.max(1e-6) * (f_peak - p.force_limit_n);
        }
        let dmax = p.max_speed_mm_per_s * dt;
        d_depth = d_depth.clamp(-dmax, dmax);
        if !limited {
            let amax = p.force_accel_mm_per_s2 * dt * dt;
            d_depth = d_depth.clamp(self.depth_step_mm - amax, self.depth_step_mm + amax);
        }
        self.depth_step_mm = d_depth;
        ForceLawStep {
            d_depth_mm: d_depth,
            f_peak_n: f_peak,
            limited,
        }
    }
}
