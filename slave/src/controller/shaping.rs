//! Input shaping of the motion into the surface, so that its corners (the speed and
//! acceleration limits, the set-point's start) do not ring the contact mode.

use super::gain_schedule::MODE_Q;

/// Length of the input shaper's history, cycles (its longest span, a full period of the
/// contact mode, is at most `SHAPER_LEN − 2`: modes down to ≈ 33 Hz).
const SHAPER_LEN: usize = 32;
/// Share of the contact mode's stiffness held by the environment up to which the motion
/// into the surface is fully shaped (k_env ≤ k_arm / 9: 5–35 N/mm on the prototype).
const SHAPER_FULL_SHARE: f64 = 0.1;
/// Share from which it is not shaped at all (k_env ≥ 0.43 k_arm: ≈ 140 N/mm and stiffer).
const SHAPER_NONE_SHARE: f64 = 0.3;

/// Past increments of the motion into the surface, newest at `head`, mm.
#[derive(Clone, Copy, Debug)]
pub(super) struct InputShaper {
    hist: [f64; SHAPER_LEN],
    head: usize,
}

impl InputShaper {
    /// No history.
    pub(super) fn new() -> Self {
        InputShaper {
            hist: [0.0; SHAPER_LEN],
            head: 0,
        }
    }

    /// Forgets the history (at a touch).
    pub(super) fn clear(&mut self) {
        self.hist = [0.0; SHAPER_LEN];
    }

    /// Zero vibration and derivative (ZVD) shaping of the increment `d`: spread over three
    /// impulses half a period of the contact mode (`omega_m`) apart, weighted for the mode's
    /// damping ([`MODE_Q`]). Only where the mode is the arm's own, lightly damped one:
    /// fully where the environment holds at most [`SHAPER_FULL_SHARE`] of the mode's
    /// stiffness (`env_share`), blended out up to [`SHAPER_NONE_SHARE`] (a stiffer surface
    /// damps the mode itself, and the delay would only cost phase). A weighted mean of past
    /// increments, so the speed and acceleration limits still hold. Returns the shaped
    /// increment.
    pub(super) fn shape(&mut self, d: f64, omega_m: f64, env_share: f64, dt: f64) -> f64 {
        self.head = (self.head + 1) % SHAPER_LEN;
        self.hist[self.head] = d;
        let blend = ((SHAPER_NONE_SHARE - env_share) / (SHAPER_NONE_SHARE - SHAPER_FULL_SHARE))
            .clamp(0.0, 1.0);
        if blend.is_nan() || blend <= 0.0 {
            return d;
        }
        let max_half = 0.5 * (SHAPER_LEN as f64 - 2.0);
        let half = (std::f64::consts::PI / (omega_m.max(1e-6) * dt)).clamp(0.0, max_half);
        let k = (-std::f64::consts::PI / (4.0 * MODE_Q * MODE_Q - 1.0).sqrt()).exp();
        let norm = 1.0 / ((1.0 + k) * (1.0 + k));
        let zvd = norm * (d + 2.0 * k * self.at(half) + k * k * self.at(2.0 * half));
        d + blend * (zvd - d)
    }

    /// The input `delay_cycles` ago, linearly interpolated.
    fn at(&self, delay_cycles: f64) -> f64 {
        let whole = delay_cycles.floor();
        let frac = delay_cycles - whole;
        let i = whole as usize;
        let at = |back: usize| self.hist[(self.head + SHAPER_LEN - back) % SHAPER_LEN];
        at(i) + (at(i + 1) - at(i)) * frac
    }
}
