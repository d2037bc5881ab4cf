//! The environment's stiffness, estimated online: recursive least squares on the force and
//! position increments along the normal over `estimator_window_cycles` (as in
//! Chiaverini–Siciliano–Villani's stiffness adaptation) give the total compliance along the
//! normal; the arm's part (from the model) taken off leaves the environment's. On a soft
//! surface the force build-up before the touch seeds the estimate.

use nalgebra::Vector3;

use super::params::ControllerParams;
use super::window::{MotionWindow, WINDOW_MAX};

/// Estimator updates on this contact after which its figure counts as measured (the force
/// guard then relies on it).
const TRUSTED_UPDATES: u32 = 10;
/// Touch-down estimate: the force along the normal below which the approach counts as not
/// yet touching (≈ 2.5 × the filtered noise: the fit averages the noise), N.
const TOUCHDOWN_FLOOR_N: f64 = 0.1;
/// Touch-down estimate: the build-up starts this many standard deviations of the sensor's
/// noise above zero at least (below it a noisy approach looks like a build-up of many
/// cycles, and the fit of noise gave a bogus stiffness: 19 % overshoot on steel at 0.3 N σ).
const TOUCHDOWN_NOISE_SIGMAS: f64 = 4.0;
/// Touch-down estimate: fewest cycles of force build-up before contact.
const TOUCHDOWN_MIN_CYCLES: usize = 10;

/// The estimate and the least-squares state.
#[derive(Clone, Copy, Debug)]
pub(super) struct StiffnessEstimator {
    /// The environment's compliance along the normal, mm/N.
    pub(super) c_env: f64,
    /// The total compliance (arm + environment) the least squares track, mm/N.
    c_tot: f64,
    /// The least squares' covariance.
    p_rls: f64,
    /// Updates on this contact.
    updates: u32,
    /// Smallest force increment that updates the estimate on this contact: the larger of
    /// `estimator_excitation_n` and [`EXCITATION_NOISE_SIGMAS`] × the sensor's noise, N.
    excitation_n: f64,
    /// The environment's compliance at the last cycle the force was settled at its
    /// set-point (or at the touch), mm/N: what a contact loss falls back to.
    c_env_settled: f64,
    /// Consecutive cycles with the force at its set-point.
    settled_cycles: u32,
}

/// Cycles the force must stay at its set-point for the estimate to count as settled.
const SETTLED_CYCLES: u32 = 50;

/// Force increments within this many standard deviations of the sensor's noise (along the
/// normal, measured while taring) do not update the estimate: at 0.3 N σ raw noise they
/// would drag it to its bound.
const EXCITATION_NOISE_SIGMAS: f64 = 6.0;

impl StiffnessEstimator {
    /// Before any data: the initial stiffness of `p`.
    pub(super) fn new(p: &ControllerParams) -> Self {
        let c_env = 1.0 / p.initial_env_stiffness_n_per_mm.max(1e-6);
        StiffnessEstimator {
            c_env,
            c_tot: c_env,
            p_rls: 100.0,
            updates: 0,
            excitation_n: p.estimator_excitation_n,
            c_env_settled: c_env,
            settled_cycles: 0,
        }
    }

    /// Whether the estimate has been measured on this contact.
    pub(super) fn trusted(&self) -> bool {
        self.updates >= TRUSTED_UPDATES
    }

    /// At a touch: the least squares restart from the current estimate, `c_arm` being the
    /// arm's compliance along the new normal `n`; with estimation on, seeded from the force
    /// build-up before the touch (`cycles`: the controller's cycles so far); `noise_n` is
    /// the sensor's noise along `n`.
    pub(super) fn touch(
        &mut self,
        window: &MotionWindow,
        n: &Vector3<f64>,
        c_arm: f64,
        cycles: u64,
        noise_n: f64,
        p: &ControllerParams,
    ) {
        self.excitation_n = p
            .estimator_excitation_n
            .max(EXCITATION_NOISE_SIGMAS * noise_n);
        self.p_rls = 100.0;
        self.updates = 0;
        self.c_tot = c_arm + self.c_env;
        if p.estimate_env_stiffness {
            // The build-up starts where the force leaves the noise, not the fixed floor.
            let floor_n = TOUCHDOWN_FLOOR_N.max(TOUCHDOWN_NOISE_SIGMAS * noise_n);
            self.seed_from_touchdown(window, n, c_arm, cycles, floor_n, p);
        }
        self.c_env_settled = self.c_env;
        self.settled_cycles = 0;
    }

    /// Books whether the force is at its set-point this cycle: once it has stayed there for
    /// [`SETTLED_CYCLES`] in a row, the estimate counts as the one of a settled contact, which
    /// a later loss of contact falls back to (a force merely passing through its set-point,
    /// as it falls away from a surface that left the tool, does not count).
    pub(super) fn settled(&mut self, at_setpoint: bool) {
        if at_setpoint {
            self.settled_cycles = self.settled_cycles.saturating_add(1);
            if self.settled_cycles >= SETTLED_CYCLES {
                self.c_env_settled = self.c_env;
            }
        } else {
            self.settled_cycles = 0;
        }
    }

    /// Contact lost: the estimate falls back to the one of the last settled contact. The
    /// cycles between carry no stiffness: the force falls away from a surface that left
    /// the tool, and the sensor shows the payload ringing on the arm (measured: an
    /// aluminium-class 550 N/mm estimate on steel dragged to 100 N/mm by a 3 mm drop, and
    /// the re-contact, with the loop gain 3.6× too high, overshot by 20 %).
    pub(super) fn lost(&mut self) {
        self.c_env = self.c_env_settled;
        self.updates = 0;
    }

    /// One update in contact, `contact_cycles` after the touch: the force and position
    /// increments along the normal `n` over the estimator's window (`xf` the newest
    /// position), the arm's compliance `c_arm` along it.
    pub(super) fn update(
        &mut self,
        window: &MotionWindow,
        n: &Vector3<f64>,
        xf: [f64; 3],
        c_arm: f64,
        contact_cycles: u32,
        p: &ControllerParams,
    ) {
        let win = (p.estimator_window_cycles as usize).clamp(2, WINDOW_MAX - 1);
        if !(p.estimate_env_stiffness && contact_cycles as usize > win) {
            return;
        }
        let old = window.back(win);
        let d_f = window.f[window.head].dot(n) - window.f[old].dot(n);
        let xo = window.x[old];
        let d_p = n[0] * (xf[0] - xo[0]) + n[1] * (xf[1] - xo[1]) + n[2] * (xf[2] - xo[2]);
        // Pushing in can only raise the force: increments of the other sign are lag or
        // noise and would drag the estimate through zero.
        if d_f.abs() > self.excitation_n && -d_p * d_f > 0.0 {
            let lam = p.estimator_forgetting.clamp(0.5, 1.0);
            let y = -d_p;
            let g = self.p_rls * d_f / (lam + d_f * self.p_rls * d_f);
            self.c_tot += g * (y - self.c_tot * d_f);
            self.p_rls = ((self.p_rls - g * d_f * self.p_rls) / lam).clamp(1e-9, 100.0);
            let (c_min, c_max) = compliance_bounds(p);
            self.c_env = (self.c_tot - c_arm).clamp(c_min, c_max);
            self.updates = self.updates.saturating_add(1);
        }
    }

    /// On a soft surface the force builds up over many cycles of the approach before
    /// contact is declared: the force and the (filtered, like the force) position since the
    /// force left the noise floor (a least-squares fit) measure the contact's total
    /// compliance at touch-down, long before the estimator's window has data after it. Used
    /// only when the build-up lasted at least [`TOUCHDOWN_MIN_CYCLES`] (a stiff surface
    /// crosses the threshold within a cycle or two, too few to measure); the estimate then
    /// counts as measured for the force guard.
    fn seed_from_touchdown(
        &mut self,
        window: &MotionWindow,
        n: &Vector3<f64>,
        c_arm: f64,
        cycles: u64,
        floor_n: f64,
        p: &ControllerParams,
    ) {
        let at = |back: usize| window.back(back);
        let onset = (1..WINDOW_MAX).find(|&back| window.f[at(back)].dot(n) < floor_n);
        let Some(samples) = onset else {
            return;
        };
        if samples < TOUCHDOWN_MIN_CYCLES || cycles < WINDOW_MAX as u64 {
            return;
        }
        // Least-squares slope of the force over the depth (into the surface) since the
        // onset: the noise of a few samples averages out.
        let depth = |idx: usize| {
            let x = window.x[idx];
            -(n[0] * x[0] + n[1] * x[1] + n[2] * x[2])
        };
        let m = samples as f64;
        let (mut sp, mut sf) = (0.0, 0.0);
        for back in 0..samples {
            sp += depth(at(back));
            sf += window.f[at(back)].dot(n);
        }
        let (mp, mf) = (sp / m, sf / m);
        let (mut spp, mut spf) = (0.0, 0.0);
        for back in 0..samples {
            let dp = depth(at(back)) - mp;
            spp += dp * dp;
            spf += dp * (window.f[at(back)].dot(n) - mf);
        }
        if spp > 0.0 && spf > 0.0 {
            let (c_min, c_max) = compliance_bounds(p);
            self.c_env = (spp / spf - c_arm).clamp(c_min, c_max);
            self.c_tot = c_arm + self.c_env;
            self.updates = TRUSTED_UPDATES;
        }
    }
}

/// The environment compliance's bounds from the stiffness bounds, mm/N.
fn compliance_bounds(p: &ControllerParams) -> (f64, f64) {
    let c_min = 1.0 / p.env_stiffness_max_n_per_mm.max(1e-6);
    let c_max = 1.0 / p.env_stiffness_min_n_per_mm.max(1e-6);
    (c_min, c_max)
}
