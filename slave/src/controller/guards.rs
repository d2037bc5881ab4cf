//! The limits that hold whatever the force law does: the command checks (speed, set-point,
//! workspace), the oscillation guard on the loop gains, the force guard on how far the
//! command may lead the arm into a surface, and the back-off when the measured force
//! reaches the limit.

use h4_shared::kinematics::{Pose, Workspace};
use h4_shared::wire::Mode;
use nalgebra::Vector3;

use super::Cycle;
use super::arm_model::{along_normal, quad_form};
use super::estimator::StiffnessEstimator;
use super::interface::{Rejection, SlaveCommand};
use super::params::ControllerParams;

/// Smoothing of a rising cycle-to-cycle force-error swing (per cycle).
const SWING_ATTACK: f64 = 0.3;
/// Smoothing of the cycle-to-cycle force-error swing (per cycle).
const SWING_FILTER: f64 = 0.05;
/// Mean second difference of the force error (per cycle) that counts as oscillation, N
/// (≈ 0.2 × the amplitude the sensor shows of a 90 Hz oscillation; filtered noise gives
/// ≈ 0.01).
const SWING2_LIMIT_N: f64 = 0.1;
/// Per-cycle gain reduction while oscillating, and recovery afterwards.
const GUARD_DECAY: f64 = 0.98;
const GUARD_RECOVERY: f64 = 1.0005;
/// Smallest gain factor of the oscillation guard.
const GUARD_MIN: f64 = 0.05;
/// Share of the force limit at which the measured force's magnitude (whatever the normal
/// estimate) backs the force-guided command off.
const MAGNITUDE_LIMIT_SHARE: f64 = 0.95;
/// Force guard: the arm may be this much stiffer than assumed.
const GUARD_ARM_STIFFNESS_MARGIN: f64 = 1.5;
/// Force guard: share of the measured compliance it counts on.
const GUARD_MEASURED_COMPLIANCE_SHARE: f64 = 0.5;
/// Force guard: compliance along the normal when Λ(x) cannot be evaluated, mm/N.
const GUARD_FALLBACK_COMPLIANCE_MM_PER_N: f64 = 1e-3;

/// Checks the command against the limits; returns its speed, mm/s.
pub(super) fn check_command(
    cmd: &SlaveCommand,
    p: &ControllerParams,
    ws: &Workspace,
) -> Result<f64, Rejection> {
    let speed = Vector3::new(cmd.velocity[0], cmd.velocity[1], cmd.velocity[2]).norm();
    if speed > p.max_speed_mm_per_s {
        return Err(Rejection::SpeedOutOfRange {
            value_mm_per_s: speed,
            limit_mm_per_s: p.max_speed_mm_per_s,
        });
    }
    if cmd.mode == Mode::ForceGuided
        && !(cmd.force_setpoint_n >= 0.0 && cmd.force_setpoint_n <= p.force_limit_n)
    {
        return Err(Rejection::SetpointOutOfRange {
            value_n: cmd.force_setpoint_n,
            limit_n: p.force_limit_n,
        });
    }
    // A Position target must lie in the workspace. (A ForceGuided approach target may lie
    // beyond the surface: every commanded step is still checked when it is committed.)
    if cmd.mode == Mode::Position
        && let Err(e) = ws.ik(&Pose::from(cmd.pose))
    {
        return Err(Rejection::Workspace(e));
    }
    Ok(speed)
}

/// Oscillation guard: a force error that swings from cycle to cycle far beyond the sensor
/// noise means a resonance inside the loop (e.g. the tool's mass between the arm and a
/// stiff surface): the loop gains back off until it calms down, then recover slowly. The
/// detector uses the error's second difference, which a ramp (a soft surface's fast,
/// legitimate force rise) leaves alone; the first difference's swing is kept for the force
/// guard's estimate of an oscillation's peak.
#[derive(Clone, Copy, Debug)]
pub(super) struct OscillationGuard {
    /// Mean cycle-to-cycle swing of the force error (fast attack, slow release), N.
    pub(super) swing_n: f64,
    /// Mean second difference of the force error, N.
    swing2_n: f64,
    /// Last cycle's first difference, N.
    de_prev_n: f64,
    /// The factor on the loop gains (`GUARD_MIN` to 1).
    pub(super) gain: f64,
}

impl OscillationGuard {
    /// Calm: full gains.
    pub(super) fn new() -> Self {
        OscillationGuard {
            swing_n: 0.0,
            swing2_n: 0.0,
            de_prev_n: 0.0,
            gain: 1.0,
        }
    }

    /// At a touch: a new contact's loop starts at full gain, its second difference from
    /// rest (what the guard saw before belonged to the last contact: after a loss, the
    /// payload ringing in free space had cut the gains to ≈ 0.5, and the re-contact then
    /// took 0.3–0.7 s to settle). The swing, the force guard's estimate of an
    /// oscillation's unseen peak, is kept: it decays by itself.
    pub(super) fn touch(&mut self) {
        self.de_prev_n = 0.0;
        self.swing2_n = 0.0;
        self.gain = 1.0;
    }

    /// Feeds this cycle's change of the force error `de`.
    pub(super) fn observe(&mut self, de: f64) {
        // Fast attack, slow release: a bounce's first swings already count.
        let k_swing = if de.abs() > self.swing_n {
            SWING_ATTACK
        } else {
            SWING_FILTER
        };
        self.swing_n += (de.abs() - self.swing_n) * k_swing;
        self.swing2_n += ((de - self.de_prev_n).abs() - self.swing2_n) * SWING_FILTER;
        self.de_prev_n = de;
        if self.swing2_n > SWING2_LIMIT_N {
            self.gain = (self.gain * GUARD_DECAY).max(GUARD_MIN);
        } else {
            self.gain = (self.gain * GUARD_RECOVERY).min(1.0);
        }
    }
}

/// Force guard, a safety limiter independent of the force law (and of whether the Λ model
/// is used): the command `next` (plus the deflection compensation `comp`) may lead the
/// encoders' position (filtered like the sensor, so that both lag alike) into the surface
/// along `n` only by as much as would keep the force under the limit if the surface were
/// rigid (or, once measured, `c_measured` compliant), the arm
/// [`GUARD_ARM_STIFFNESS_MARGIN`] times stiffer than assumed and the tool's mass rang to
/// twice the static force (a lightly damped step response). `f_peak` is the normal force
/// with the oscillation's unseen peak. Returns whether it clipped the command.
pub(super) fn force_guard(
    next: &mut Pose,
    cx: &Cycle,
    f_peak: f64,
    n: &Vector3<f64>,
    comp: &Pose,
    c_measured: f64,
    p: &ControllerParams,
) -> bool {
    let dmax = p.max_speed_mm_per_s * cx.dt_s;
    let c_rigid = (match cx.compliance.guard.as_ref() {
        Some(l) => quad_form(l, n).max(0.0),
        None => GUARD_FALLBACK_COMPLIANCE_MM_PER_N,
    } / GUARD_ARM_STIFFNESS_MARGIN)
        .max(c_measured);
    let headroom = p.force_limit_n - f_peak;
    let allowed = 0.5 * headroom * c_rigid;
    let xf = cx.xf;
    let pending = (0..3)
        .map(|i| n[i] * (xf[i] - (next[i] + comp[i])))
        .sum::<f64>();
    if pending > allowed {
        let back = (pending - allowed).min(dmax);
        for i in 0..3 {
            next[i] += n[i] * back;
        }
        true
    } else {
        false
    }
}

/// Force guard of position mode (a teleoperated push into a wall: no force law runs):
/// along the measured force, the command `next` may lead the encoders' position (filtered
/// like the sensor) into the surface only by as much as keeps the force under the limit if
/// the surface were rigid, the arm [`GUARD_ARM_STIFFNESS_MARGIN`] times stiffer than
/// assumed and the tool rang to twice the static force. Returns the direction and the
/// distance it moved the command back (none when it did not clip).
pub(super) fn position_force_guard(
    next: &mut Pose,
    cx: &Cycle,
    p: &ControllerParams,
) -> Option<Vector3<f64>> {
    let n = cx.f3 / cx.f_mag;
    let c_rigid = match cx.compliance.lambda.as_ref() {
        Some(l) => quad_form(l, &n).max(0.0),
        None => GUARD_FALLBACK_COMPLIANCE_MM_PER_N,
    } / GUARD_ARM_STIFFNESS_MARGIN;
    // 5 % of the limit is kept for the sensor's filter lag and noise.
    let allowed = 0.5 * (0.95 * p.force_limit_n - cx.f_mag).max(0.0) * c_rigid;
    let xf = cx.xf;
    let lead = (0..3).map(|i| n[i] * (xf[i] - next[i])).sum::<f64>();
    if lead <= allowed {
        return None;
    }
    let back = (lead - allowed).min(p.max_speed_mm_per_s * cx.dt_s);
    for i in 0..3 {
        next[i] += n[i] * back;
    }
    Some(n)
}

/// Whatever the normal estimate says, the measured force's magnitude near the limit backs
/// the force-guided command off along the force (as Hold and Position mode do). A normal
/// estimate tilted by friction (a soft surface with dry friction) would otherwise let the
/// true force drift past the limit over seconds while the force along the estimate stayed
/// at the set-point. 5 % of the limit is kept for the filter's lag and noise. `c_env` is
/// the environment's compliance, mm/N. Returns whether it backed off.
pub(super) fn magnitude_limit(
    next: &mut Pose,
    cx: &Cycle,
    c_env: f64,
    p: &ControllerParams,
) -> bool {
    let dmax = p.max_speed_mm_per_s * cx.dt_s;
    let magnitude_limit = MAGNITUDE_LIMIT_SHARE * p.force_limit_n;
    if cx.f_mag <= magnitude_limit {
        return false;
    }
    let dir = cx.f3 / cx.f_mag;
    let c_dir = cx
        .compliance
        .guard
        .as_ref()
        .map_or(0.0, |l| quad_form(l, &dir).max(0.0))
        + c_env;
    let step = (c_dir * (cx.f_mag - magnitude_limit)).min(dmax);
    for i in 0..3 {
        next[i] += dir[i] * step;
    }
    true
}

/// Above the force limit (Hold and Position mode): the command `next` backs off along the
/// measured force by the compliance (the model's and the environment's `c_env`) times the
/// excess, at most at the speed limit.
pub(super) fn back_off(next: &mut Pose, cx: &Cycle, c_env: f64, p: &ControllerParams) {
    let dir = cx.f3 / cx.f_mag;
    let c = match cx.compliance.lambda.as_ref() {
        Some(l) => quad_form(l, &dir).max(0.0),
        None => 0.0,
    } + c_env;
    let step = (c * (cx.f_mag - p.force_limit_n)).min(p.max_speed_mm_per_s * cx.dt_s);
    for i in 0..3 {
        next[i] += dir[i] * step;
    }
}

/// The compliance along the normal `n` the force guard may count on: once the estimator
/// has measured this contact, half the measured one (the contact up to twice as stiff as
/// measured), the arm's part from the model (`c_arm_model`) or, without the model, from the
/// guard's own Λ; before that none (a rigid contact).
pub(super) fn measured_compliance(
    c_arm_model: f64,
    cx: &Cycle,
    n: &Vector3<f64>,
    estimator: &StiffnessEstimator,
    p: &ControllerParams,
) -> f64 {
    if p.estimate_env_stiffness && estimator.trusted() {
        let c_arm_guard = if p.compliance_model {
            c_arm_model
        } else {
            along_normal(cx.compliance.guard.as_ref(), n)
        };
        GUARD_MEASURED_COMPLIANCE_SHARE * (c_arm_guard + estimator.c_env)
    } else {
        0.0
    }
}
