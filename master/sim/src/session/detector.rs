//! The stability detector and the session's summary: per-cycle samples accumulated by the
//! [`Evaluator`], contact episodes, bouncing and the contact force's oscillation found at the
//! end, and the verdict with its reasons.

use std::ops::Range;

use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

use h4_slave::filter::Butterworth2;

use super::DT_S;

/// The stability detector.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Contact force above which the tool counts as in contact, N.
    pub contact_threshold_n: f64,
    /// Time constant of the moving mean the oscillation is measured around, s.
    pub mean_time_constant_s: f64,
    /// Contact time skipped after the start of each contact episode, s.
    pub settle_s: f64,
    /// Contact lost for less than this and regained is one episode (a bounce), s.
    pub contact_gap_s: f64,
    /// An episode shorter than `settle_s` whose force reaches this is an impact, N.
    pub impact_force_n: f64,
    /// Impacts less than this apart are in a row (one bouncing run), s.
    pub bounce_gap_s: f64,
    /// This many impacts in a row or more is sustained bouncing: unstable.
    pub bounce_limit: u64,
    /// Length of the early and late windows of contact, s.
    pub window_s: f64,
    /// Late-contact oscillation (RMS around the moving mean) above which the run is unstable, N.
    pub oscillation_limit_n: f64,
    /// Oscillation growth (late over early) above which the run is unstable.
    pub growth_limit: f64,
    /// Floor of the early oscillation in the growth ratio, N (sensor noise).
    pub oscillation_floor_n: f64,
    /// Observer energy below −this is unstable, J.
    pub energy_tolerance_j: f64,
    /// Contact force above which the run is unstable, N.
    pub force_limit_n: f64,
    /// A hold: the operator's intent at rest, pushing with at least this force, N.
    pub hold_push_min_n: f64,
    /// Time skipped at the start of each hold before its force and ripple are measured, s.
    pub hold_settle_s: f64,
    /// Ripple of the true contact force around its linear trend over a hold (every
    /// frequency above 1 / the hold's length, 0.2 Hz for a 5 s hold), N RMS, above which
    /// the run is unstable.
    pub hold_ripple_limit_n: f64,
    /// While the operator pushes, a contact lost and regained whose force reaches this is a
    /// bounce (any bounce is unstable), N.
    pub bounce_force_n: f64,
    /// In a cutting session a contact counts as lost only once the tool's tip has also
    /// risen this far above where its force was lost, mm: a cutter dwelling in its own cut
    /// (held by a fixture, or at the end of a pass) has no force and has not left the part.
    /// Without a cut the force alone says (a plain surface's force vanishes only apart).
    pub bounce_lift_mm: f64,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            contact_threshold_n: 0.5,
            mean_time_constant_s: 0.1,
            settle_s: 0.5,
            contact_gap_s: 0.25,
            impact_force_n: 2.0,
            bounce_gap_s: 2.0,
            bounce_limit: 4,
            window_s: 2.0,
            oscillation_limit_n: 1.5,
            growth_limit: 3.0,
            oscillation_floor_n: 0.5,
            energy_tolerance_j: 0.01,
            force_limit_n: 100.0,
            hold_push_min_n: 0.5,
            hold_settle_s: 1.0,
            hold_ripple_limit_n: 1.0,
            bounce_force_n: 2.0,
            bounce_lift_mm: 0.01,
        }
    }
}

impl Section for DetectorConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |name: &str| format!("{prefix}{name}");
        check_range(
            &f("contact_threshold_n"),
            self.contact_threshold_n,
            0.01,
            100.0,
            "N",
        )?;
        check_range(
            &f("mean_time_constant_s"),
            self.mean_time_constant_s,
            0.001,
            10.0,
            "s",
        )?;
        check_range(&f("settle_s"), self.settle_s, 0.0, 100.0, "s")?;
        check_range(&f("contact_gap_s"), self.contact_gap_s, 0.0, 100.0, "s")?;
        check_range(&f("impact_force_n"), self.impact_force_n, 0.0, 1e4, "N")?;
        check_range(&f("bounce_gap_s"), self.bounce_gap_s, 0.0, 100.0, "s")?;
        check_range(
            &f("bounce_limit"),
            self.bounce_limit as f64,
            2.0,
            1e6,
            "impacts in a row",
        )?;
        check_range(&f("window_s"), self.window_s, 0.05, 100.0, "s")?;
        check_range(
            &f("oscillation_limit_n"),
            self.oscillation_limit_n,
            0.0,
            1e3,
            "N",
        )?;
        check_range(&f("growth_limit"), self.growth_limit, 0.0, 1e3, "")?;
        check_range(
            &f("oscillation_floor_n"),
            self.oscillation_floor_n,
            0.0,
            100.0,
            "N",
        )?;
        check_range(
            &f("energy_tolerance_j"),
            self.energy_tolerance_j,
            0.0,
            1e3,
            "J",
        )?;
        check_range(&f("force_limit_n"), self.force_limit_n, 0.0, 1e4, "N")?;
        check_range(&f("hold_push_min_n"), self.hold_push_min_n, 0.0, 100.0, "N")?;
        check_range(&f("hold_settle_s"), self.hold_settle_s, 0.0, 100.0, "s")?;
        check_range(
            &f("hold_ripple_limit_n"),
            self.hold_ripple_limit_n,
            0.0,
            1e3,
            "N",
        )?;
        check_range(&f("bounce_force_n"), self.bounce_force_n, 0.0, 1e4, "N")?;
        check_range(&f("bounce_lift_mm"), self.bounce_lift_mm, 0.0, 100.0, "mm")
    }
}

/// The result of one session.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// The session's name.
    pub name: String,
    /// The detector's verdict: no growing or sustained oscillation in contact, observers
    /// within tolerance, forces within limits, nothing diverged.
    pub stable: bool,
    /// Why the detector said unstable (empty when stable).
    pub unstable_reasons: Vec<String>,
    /// Lowest energy of the passivity observers (master and slave ports), J.
    pub energy_min_j: f64,
    /// Largest contact force at the slave (simulation truth), N.
    pub max_force_n: f64,
    /// Largest force rendered to the operator, N.
    pub max_master_force_n: f64,
    /// Chatter of the force rendered to the operator: the largest RMS, over any
    /// `CHATTER_WINDOW_MS` (100 ms) window, of the cycle-to-cycle change of the rendered
    /// force vector (|F_k − F_{k−1}|), N per cycle. A smooth push changes it by a fraction of
    /// a newton per cycle; a handle whose velocity flips sign every cycle under too much
    /// damping swings it by tens of newtons.
    pub master_force_chatter_n: f64,
    /// Contact-force oscillation late in contact over early (RMS around the moving mean);
    /// < 1 means decaying.
    pub oscillation_growth: f64,
    /// Contact-force oscillation early in contact, N RMS.
    pub oscillation_early_n: f64,
    /// Contact-force oscillation late in contact, N RMS.
    pub oscillation_late_n: f64,
    /// Position drift the slave's passivity controller left (commanded minus desired slave
    /// position), mean over the last 0.5 s of contact, mm.
    pub position_drift_mm: f64,
    /// Largest position drift during the run, mm.
    pub position_drift_max_mm: f64,
    /// |F_master / scale.force − F_slave| over |F_slave|, steady contact, %.
    pub force_transparency_err_pct: f64,
    /// RMS of |slave measured − slave desired position| in free space, mm.
    pub position_tracking_err_mm: f64,
    /// Energy dissipated by both passivity controllers, J.
    pub passivity_dissipated_j: f64,
    /// Messages lost in both directions (loss, blackouts, overflow).
    pub packets_lost: u64,
    /// Messages the receive gates rejected, all reasons, both directions (duplicates and
    /// reordered messages of the impaired link are `stale`).
    pub packets_rejected: u64,
    /// The slave's receive gate (commands): accepted, rejected by reason, pairings
    /// (docs/processes.md).
    pub slave_gate: h4_transport::gate::GateCounters,
    /// The master's receive gate (feedback), same fields.
    pub master_gate: h4_transport::gate::GateCounters,
    /// Mean round-trip time measured by the master from the echoed send times, ms.
    pub rtt_mean_ms: f64,
    /// The slave's own round trip (protocol 3: now − the echoed send time of its feedback),
    /// median over the session, ms; NaN (null) when no command echoed a feedback.
    pub rtt_measured_p50_ms: f64,
    /// Its 99th percentile, ms.
    pub rtt_measured_p99_ms: f64,
    /// Its jitter over the session, p95 − p50, ms (what a playout buffer must add to cover
    /// 95 % of the commands).
    pub rtt_jitter_ms: f64,
    /// Active slave cycles that used the told round trip (`slave.contact.round_trip_ms`, the
    /// fallback) because the slave had measured none yet or measuring was off.
    pub rtt_fallback_cycles: u64,
    /// Settled contact time (contact episodes after `detector.settle_s`), s.
    pub contact_time_s: f64,
    /// Times the tool lost and regained contact within `detector.contact_gap_s` (bounces).
    pub contact_bounces: u64,
    /// The most impacts in a row (touches shorter than `detector.settle_s` reaching
    /// `detector.impact_force_n`, each within `detector.bounce_gap_s` of the last).
    pub bouncing_impacts: u64,
    /// Cycles whose command the slave controller rejected.
    pub slave_rejected_cycles: u64,
    /// Control cycles run (1 ms each, both sides).
    pub cycles: u64,
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Wall-clock time of the simulation, s (the only field that is not deterministic).
    pub wall_time_s: f64,
    /// Largest true contact force from the first touch until the first hold has settled
    /// (`detector.hold_settle_s` into it), N (0: no contact).
    pub first_touch_peak_n: f64,
    /// Mean true contact force of each hold (intent at rest, pushing), after
    /// `detector.hold_settle_s`, N.
    pub hold_force_n: Vec<f64>,
    /// The force the operator's hand applied to the handle along its push in each hold
    /// (mean over the settled hold), N at the master: the push the slave must follow. Less
    /// than the scripted `push_n` where the hand's arm spring pulls back towards its
    /// intended point.
    pub hold_push_n: Vec<f64>,
    /// What each hold asks for: `hold_push_n` / `scale.force`, N at the slave.
    pub hold_target_n: Vec<f64>,
    /// Largest, over the holds, RMS of the true contact force around its linear trend
    /// (least squares over the settled hold): every oscillation slower than the hold
    /// itself down to 1 / its length counts, N.
    pub hold_ripple_rms_n: f64,
    /// Chatter the operator's hand feels in a hold: the largest, over the holds (their
    /// settled cycles, as `hold_force_n`), RMS of the rendered force vector's content above
    /// 20 Hz (`HF_CUTOFF_HZ`; zero-phase, [`high_frequency_rms`]), N at the master: the
    /// sensor's noise and the steps at lost feedback that reach the hand (0: no hold).
    pub rendered_hf_rms_n: f64,
    /// The same measure of the true contact force, N at the slave: what the wall itself
    /// does in the holds.
    pub true_hf_rms_n: f64,
    /// Largest force rendered to the operator while the handle rests in free space after a
    /// release: from the end of the first hold on, cycles with no push (below
    /// `detector.hold_push_min_n`), the intent at rest and the slave out of contact (true
    /// force at most `detector.contact_threshold_n`) for longer than the mean round trip,
    /// N (0: no such cycle).
    pub free_space_rendered_max_n: f64,
    /// Contacts lost and regained, reaching `detector.bounce_force_n`, while the operator
    /// pushes (after the first touch of each push).
    pub bounces: u64,
    /// Safe stops of the slave (its watchdog).
    pub slave_safe_stops: u64,
    /// Safe stops the master saw in the feedback (and faded out for).
    pub master_saw_safe_stops: u64,
    /// Re-engagements after a safe stop (each on the master's acknowledgement).
    pub repairs: u64,
    /// A state of the run went non-finite (NaN or infinite): the run is unstable and fails
    /// every safety verdict.
    pub diverged: bool,
    /// The slave's safety monitor's trips by reason (each also one of `slave_safe_stops`).
    pub safety_trips: h4_slave::safety::SafetyTrips,
    /// The session ran with `--unsafe-test-override` (a safety layer may have been off).
    pub unsafe_test_override: bool,
    /// The cut and the part, in a cutting session (`docs/cutting.md`).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub cutting: Option<super::cutting::CutSummary>,
}

impl Summary {
    /// The verdict in one line of words: `stable, 14 000 cycles (14.0 s simulated), round
    /// trip mean 1.0 ms, max force 12.5 N, rendered 13.0 N` or `UNSTABLE: <reasons>; …`.
    pub fn in_words(&self) -> String {
        let figures = format!(
            "{} cycles ({:.1} s simulated), round trip mean {:.1} ms, max force {:.1} N \
             (true, at the slave), rendered {:.1} N, observer min {:.2} mJ",
            h4_telemetry::progress::grouped(self.cycles),
            self.sim_time_s,
            self.rtt_mean_ms,
            self.max_force_n,
            self.max_master_force_n,
            self.energy_min_j * 1e3
        );
        if self.stable {
            format!("stable, {figures}")
        } else {
            format!("UNSTABLE: {}; {figures}", self.unstable_reasons.join("; "))
        }
    }
}

/// The holds of a run and what they show (see [`Summary`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct Holds {
    pub(super) first_touch_peak_n: f64,
    pub(super) force_n: Vec<f64>,
    pub(super) push_n: Vec<f64>,
    pub(super) target_n: Vec<f64>,
    pub(super) ripple_rms_n: f64,
    pub(super) bounces: u64,
    /// The settled cycles of each hold.
    pub(super) settled: Vec<Range<usize>>,
}

impl Holds {
    #[cfg(test)]
    fn hold_count(&self) -> usize {
        self.force_n.len()
    }
}

/// RMS of `y` around its least-squares line.
fn detrended_rms(y: &[f64]) -> f64 {
    let n = y.len() as f64;
    if y.len() < 3 {
        return 0.0;
    }
    let mx = (n - 1.0) / 2.0;
    let my = y.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (i, v) in y.iter().enumerate() {
        let dx = i as f64 - mx;
        sxy += dx * (v - my);
        sxx += dx * dx;
    }
    let b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let ss: f64 = y
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let r = v - my - b * (i as f64 - mx);
            r * r
        })
        .sum();
    (ss / n).sqrt()
}

/// The holds of a run from the true force, the operator's intended push (|push| per cycle,
/// N: where the holds are), the force the hand really applies to the handle along that push
/// (per cycle, N: what each hold asks of the slave) and whether the intent was at rest, per
/// cycle; in a cutting session `tip_z_mm`, the tool tip's true height per cycle (a contact
/// is lost only once the tip has risen `bounce_lift_mm` above where its force was lost).
pub(super) fn holds(
    force_n: &[f64],
    push_n: &[f64],
    applied_n: &[f64],
    steady: &[bool],
    tip_z_mm: Option<&[f64]>,
    force_scale: f64,
    d: &DetectorConfig,
) -> Holds {
    let mut h = Holds::default();
    let settle = (d.hold_settle_s / DT_S).round() as usize;
    let len = force_n
        .len()
        .min(push_n.len())
        .min(applied_n.len())
        .min(steady.len());
    // Holds: runs of steady cycles pushing with at least hold_push_min_n. In a cutting
    // session also in contact: the operator's push is steady from before the tool meets the
    // stock, and after the last of the material is cut (a closed ring) the tool dwells in its
    // own cut, pushing on the fixture's floor with no force at the tool; neither the plunge
    // nor that end is the hold of a contact (with them the cut-profile session's one hold
    // read 2.06 N RMS of "ripple": the force's rise at the plunge and its fall at the ring's
    // end, around a force steady to 0.12 N RMS).
    let cutting = tip_z_mm.is_some();
    let holding = |k: usize| {
        steady[k]
            && push_n[k] >= d.hold_push_min_n
            && (!cutting || force_n[k] > d.contact_threshold_n)
    };
    let mut k = 0;
    let mut first_hold_settled: Option<usize> = None;
    while k < len {
        if !holding(k) {
            k += 1;
            continue;
        }
        let start = k;
        while k < len && holding(k) {
            k += 1;
        }
        if k - start > settle + 2 {
            let seg = &force_n[start + settle..k];
            let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len() as f64;
            h.force_n.push(mean(seg));
            let applied = mean(&applied_n[start + settle..k]);
            h.push_n.push(applied);
            h.target_n.push(applied / force_scale);
            h.ripple_rms_n = h.ripple_rms_n.max(detrended_rms(seg));
            h.settled.push(start + settle..k);
            first_hold_settled.get_or_insert(start + settle);
        }
    }
    // The first touch: from the first contact until the first hold has settled.
    if let Some(first) = force_n[..len]
        .iter()
        .position(|&f| f > d.contact_threshold_n)
    {
        let end = first_hold_settled.unwrap_or(len).max(first + 1).min(len);
        h.first_touch_peak_n = force_n[first..end].iter().fold(0.0, |a: f64, &b| a.max(b));
    }
    // Bounces: while pushing, after the first touch of the push, a contact lost (force
    // below the threshold; in a cut, with the tip risen bounce_lift_mm above where the
    // force was lost) and regained reaching bounce_force_n.
    let mut touched = false;
    let mut lost = false;
    let mut peak = 0.0_f64;
    let mut counting = false;
    let mut dropped_at_z: Option<f64> = None;
    for kk in 0..len {
        let pushing = push_n[kk] >= d.hold_push_min_n;
        if !pushing {
            touched = false;
            lost = false;
            counting = false;
            dropped_at_z = None;
            continue;
        }
        let contact = force_n[kk] > d.contact_threshold_n;
        let apart = match tip_z_mm.and_then(|z| z.get(kk)) {
            _ if contact => {
                dropped_at_z = None;
                false
            }
            None => true,
            Some(&z) => z > *dropped_at_z.get_or_insert(z) + d.bounce_lift_mm,
        };
        if contact && !touched {
            touched = true;
        } else if touched && apart {
            if counting && peak >= d.bounce_force_n {
                h.bounces += 1;
            }
            counting = false;
            lost = true;
        } else if touched && contact && lost && !counting {
            counting = true;
            peak = 0.0;
        }
        if counting {
            peak = peak.max(force_n[kk]);
        }
    }
    if counting && peak >= d.bounce_force_n {
        h.bounces += 1;
    }
    h
}

/// Cut-off above which the rendered force's content is chatter, Hz
/// ([`Summary::rendered_hf_rms_n`]): the hand feels a contact's force change through its grip
/// and arm well below it; above it is the sensor's noise and the loop's steps.
pub const HF_CUTOFF_HZ: f64 = 20.0;

/// RMS of the content of the vector signal `x` (one sample per 1 ms cycle) above
/// `cutoff_hz`, N: `x` minus its zero-phase low-pass, a 2nd-order Butterworth at `cutoff_hz`
/// run forwards then backwards, the window extended at both ends by odd reflection (five
/// periods of the cut-off) so that a level, a ramp or the window's edges leave nothing. Of a
/// sine of frequency `f` the residual keeps `(f/fc)⁴ / (1 + (f/fc)⁴)` of the amplitude: 6 %
/// at half the cut-off, half at it, 94 % at twice it. The components' mean squares are summed
/// (the RMS of the vector's high-frequency part). Fewer than 3 samples: 0.
pub fn high_frequency_rms(x: &[[f64; 3]], cutoff_hz: f64) -> f64 {
    let len = x.len();
    if len < 3 {
        return 0.0;
    }
    let pad = ((5.0 / (cutoff_hz.max(1e-3) * DT_S)).ceil() as usize).min(len - 1);
    let mut ext = Vec::with_capacity(len + 2 * pad);
    let mut sum_sq = 0.0;
    for i in 0..3 {
        let (first, last) = (x[0][i], x[len - 1][i]);
        ext.clear();
        ext.extend((1..=pad).rev().map(|k| 2.0 * first - x[k][i]));
        ext.extend(x.iter().map(|v| v[i]));
        ext.extend((1..=pad).map(|k| 2.0 * last - x[len - 1 - k][i]));
        let mut f = Butterworth2::new(cutoff_hz, 1.0 / DT_S);
        f.reset(ext[0]);
        for e in ext.iter_mut() {
            *e = f.update(*e);
        }
        let mut b = Butterworth2::new(cutoff_hz, 1.0 / DT_S);
        b.reset(ext[ext.len() - 1]);
        for e in ext.iter_mut().rev() {
            *e = b.update(*e);
        }
        sum_sq += x
            .iter()
            .zip(&ext[pad..pad + len])
            .map(|(v, lp)| (v[i] - lp) * (v[i] - lp))
            .sum::<f64>();
    }
    (sum_sq / len as f64).sqrt()
}

/// The root mean square of `s` (0 when empty).
fn rms_of(s: &[f64]) -> f64 {
    if s.is_empty() {
        0.0
    } else {
        (s.iter().map(|x| x * x).sum::<f64>() / s.len() as f64).sqrt()
    }
}

/// The largest of `|rendered_n|` while the handle is in free space after a release: cycles
/// from the end of the first hold (`after`) on in which the operator does not push (below
/// `hold_push_min_n`), the intent is at rest, and the slave has been out of contact (true
/// force at most `contact_threshold_n`) for more than `out_for` cycles (the round trip: the
/// feedback that the slave has left has reached the master). 0 with no such cycle.
fn free_space_max(
    rendered_n: &[[f64; 3]],
    force_n: &[f64],
    push_n: &[f64],
    steady: &[bool],
    after: usize,
    out_for: usize,
    d: &DetectorConfig,
) -> f64 {
    let len = rendered_n
        .len()
        .min(force_n.len())
        .min(push_n.len())
        .min(steady.len());
    let mut out_cycles = 0usize;
    let mut max = 0.0_f64;
    for k in 0..len {
        out_cycles = if force_n[k] > d.contact_threshold_n {
            0
        } else {
            out_cycles + 1
        };
        if k >= after && out_cycles > out_for && steady[k] && push_n[k] < d.hold_push_min_n {
            let r = rendered_n[k];
            max = nan_max(max, (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt());
        }
    }
    max
}

/// What the run knows beyond the per-cycle samples.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct RunFacts {
    /// `scale.force`.
    pub(super) force_scale: f64,
    /// Safe stops of the slave.
    pub(super) slave_safe_stops: u64,
    /// Safe stops the master saw.
    pub(super) master_saw_safe_stops: u64,
    /// Re-engagements after a safe stop.
    pub(super) repairs: u64,
    /// The monitor's trips.
    pub(super) safety_trips: h4_slave::safety::SafetyTrips,
    /// `--unsafe-test-override`.
    pub(super) unsafe_test_override: bool,
}

/// The larger of `a` and `b`, NaN if either is (a diverged run's peak is NaN, never a
/// number that passes a limit).
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// Window of [`Summary::master_force_chatter_n`], cycles (1 ms each).
const CHATTER_WINDOW_MS: usize = 100;

pub(super) struct Sample {
    pub(super) true_force_n: f64,
    pub(super) master_force_n: f64,
    pub(super) master_force_vec_n: [f64; 3],
    /// The true contact force vector at the slave, N.
    pub(super) true_force_vec_n: [f64; 3],
    pub(super) transparency_abs_n: f64,
    pub(super) slave_force_n: f64,
    pub(super) steady: bool,
    pub(super) observed_min_j: f64,
    pub(super) drift_mm: f64,
    pub(super) tracking_err_mm: f64,
    pub(super) free_motion: bool,
    pub(super) rejected: bool,
    pub(super) finite: bool,
    /// |The operator's intended push|, N at the handle.
    pub(super) push_n: f64,
    /// The force the hand applies to the handle along the intended push, N (0 without one).
    pub(super) applied_push_n: f64,
    /// The intent at rest (holds): like `steady` but the clutch does not matter.
    pub(super) intent_steady: bool,
    /// In a cutting session, the tool tip's true height (base frame), mm; `None` without a
    /// cut.
    pub(super) tip_z_mm: Option<f64>,
}

/// Contact episodes: runs of cycles with the contact force above `threshold_n`, runs less
/// than `gap` cycles apart joined into one (the cycles between them belong to it: a tool
/// that bounces on and off the surface is one contact, and its bounces are oscillation).
/// Returns the episodes and the number of joins (bounces).
fn contact_episodes(force_n: &[f64], threshold_n: f64, gap: usize) -> (Vec<Range<usize>>, u64) {
    let mut episodes: Vec<Range<usize>> = Vec::new();
    let mut bounces = 0;
    let mut k = 0;
    while k < force_n.len() {
        if force_n[k] <= threshold_n {
            k += 1;
            continue;
        }
        let start = k;
        while k < force_n.len() && force_n[k] > threshold_n {
            k += 1;
        }
        match episodes.last_mut() {
            Some(last) if start - last.end < gap => {
                last.end = k;
                bounces += 1;
            }
            _ => episodes.push(start..k),
        }
    }
    (episodes, bounces)
}

/// The longest run of impacts in a row: episodes shorter than `settle` cycles whose force
/// reaches `impact_force_n`, each starting less than `gap` cycles after the last one ended
/// (a tool bouncing off the surface while the operator pushes: each touch too short to
/// settle, so the oscillation measure never sees it).
fn bouncing_impacts(
    force_n: &[f64],
    episodes: &[Range<usize>],
    settle: usize,
    impact_force_n: f64,
    gap: usize,
) -> u64 {
    let mut best = 0;
    let mut run = 0;
    let mut last_end: Option<usize> = None;
    for e in episodes {
        let impact = e.len() < settle && force_n[e.clone()].iter().any(|&f| f >= impact_force_n);
        if !impact {
            run = 0;
            last_end = None;
            continue;
        }
        run = match last_end {
            Some(end) if e.start - end < gap => run + 1,
            _ => 1,
        };
        last_end = Some(e.end);
        best = best.max(run);
    }
    best
}

/// The contact force's oscillation: for each sample of an episode past its first `settle`
/// cycles, the force minus its zero-phase moving mean. The mean is a first-order low-pass
/// (`tau_s`) run forwards then backwards over one episode at a time, the episode extended at
/// both ends by odd reflection, so that a ramp (a push, a release) leaves no residual; an
/// oscillation of frequency f leaves (2πfτ)² / (1 + (2πfτ)²) of its amplitude. Also returns,
/// for each residual, its cycle.
fn contact_residuals(
    force_n: &[f64],
    episodes: &[Range<usize>],
    settle: usize,
    tau_s: f64,
) -> Vec<(usize, f64)> {
    let a = (DT_S / tau_s.max(DT_S)).min(1.0);
    let mut out = Vec::with_capacity(force_n.len());
    let mut ext = Vec::new();
    for e in episodes {
        let seg = &force_n[e.clone()];
        let len = seg.len();
        let pad = ((5.0 * tau_s / DT_S).ceil() as usize).min(len - 1);
        let (first, last) = (seg[0], seg[len - 1]);
        ext.clear();
        ext.extend((1..=pad).rev().map(|k| 2.0 * first - seg[k]));
        ext.extend_from_slice(seg);
        ext.extend((1..=pad).map(|k| 2.0 * last - seg[len - 1 - k]));
        for i in 1..ext.len() {
            ext[i] = ext[i - 1] + a * (ext[i] - ext[i - 1]);
        }
        for i in (0..ext.len() - 1).rev() {
            ext[i] = ext[i + 1] + a * (ext[i] - ext[i + 1]);
        }
        for (j, f) in seg.iter().enumerate().skip(settle) {
            out.push((e.start + j, f - ext[pad + j]));
        }
    }
    out
}

/// Summary statistics, accumulated per cycle (the per-cycle buffers are allocated once).
pub(super) struct Evaluator {
    det: DetectorConfig,
    /// True contact force of every cycle, N (contact episodes and their oscillation are
    /// found at the end: [`contact_episodes`], [`contact_residuals`]).
    force_n: Vec<f64>,
    /// Position drift of every cycle, mm.
    drift_mm: Vec<f64>,
    /// |Push| of every cycle, N.
    push_n: Vec<f64>,
    /// The hand's force on the handle along the push, every cycle, N.
    applied_push_n: Vec<f64>,
    /// The intent at rest, every cycle.
    intent_steady: Vec<bool>,
    tip_z_mm: Vec<f64>,
    /// The rendered force vector of every cycle, N.
    rendered_n: Vec<[f64; 3]>,
    /// The true contact force vector of every cycle, N.
    true_vec_n: Vec<[f64; 3]>,
    steady_s: f64,
    energy_min: f64,
    max_force: f64,
    max_master: f64,
    chatter_ring: Vec<f64>,
    chatter_sum: f64,
    chatter_k: usize,
    chatter_max: f64,
    prev_master_n: Option<[f64; 3]>,
    trans_abs: f64,
    trans_ref: f64,
    track_sq: f64,
    track_n: u64,
    drift_max: f64,
    rejected: u64,
    diverged: bool,
}

impl Evaluator {
    pub(super) fn new(det: DetectorConfig, cycles: usize) -> Self {
        Evaluator {
            det,
            force_n: Vec::with_capacity(cycles),
            drift_mm: Vec::with_capacity(cycles),
            push_n: Vec::with_capacity(cycles),
            applied_push_n: Vec::with_capacity(cycles),
            intent_steady: Vec::with_capacity(cycles),
            tip_z_mm: Vec::with_capacity(cycles),
            rendered_n: Vec::with_capacity(cycles),
            true_vec_n: Vec::with_capacity(cycles),
            steady_s: 0.0,
            energy_min: 0.0,
            max_force: 0.0,
            max_master: 0.0,
            chatter_ring: vec![0.0; CHATTER_WINDOW_MS],
            chatter_sum: 0.0,
            chatter_k: 0,
            chatter_max: 0.0,
            prev_master_n: None,
            trans_abs: 0.0,
            trans_ref: 0.0,
            track_sq: 0.0,
            track_n: 0,
            drift_max: 0.0,
            rejected: 0,
            diverged: false,
        }
    }

    pub(super) fn push(&mut self, s: Sample) {
        let d = &self.det;
        if !s.finite || !s.true_force_n.is_finite() {
            self.diverged = true;
            return;
        }
        self.energy_min = self.energy_min.min(s.observed_min_j);
        // A NaN stays (`f64::max` would drop it and a diverging run would pass).
        self.max_force = nan_max(self.max_force, s.true_force_n);
        self.max_master = nan_max(self.max_master, s.master_force_n);
        if let Some(p) = self.prev_master_n {
            let d = [
                s.master_force_vec_n[0] - p[0],
                s.master_force_vec_n[1] - p[1],
                s.master_force_vec_n[2] - p[2],
            ];
            let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            let slot = self.chatter_k % CHATTER_WINDOW_MS;
            self.chatter_sum += d2 - self.chatter_ring[slot];
            self.chatter_ring[slot] = d2;
            self.chatter_k += 1;
            // Re-summed once per window: no drift of the running sum.
            if self.chatter_k.is_multiple_of(CHATTER_WINDOW_MS) {
                self.chatter_sum = self.chatter_ring.iter().sum();
            }
            let rms = (self.chatter_sum.max(0.0) / CHATTER_WINDOW_MS as f64).sqrt();
            self.chatter_max = self.chatter_max.max(rms);
        }
        self.prev_master_n = Some(s.master_force_vec_n);
        self.drift_max = self.drift_max.max(s.drift_mm);
        if s.rejected {
            self.rejected += 1;
        }
        let in_contact = s.true_force_n > d.contact_threshold_n;
        self.force_n.push(s.true_force_n);
        self.drift_mm.push(s.drift_mm);
        self.push_n.push(s.push_n);
        self.applied_push_n.push(s.applied_push_n);
        self.intent_steady.push(s.intent_steady);
        self.rendered_n.push(s.master_force_vec_n);
        self.true_vec_n.push(s.true_force_vec_n);
        if let Some(z) = s.tip_z_mm {
            self.tip_z_mm.push(z);
        }
        if !in_contact && s.free_motion && s.steady {
            self.track_sq += s.tracking_err_mm * s.tracking_err_mm;
            self.track_n += 1;
        }
        self.steady_s = if s.steady { self.steady_s + DT_S } else { 0.0 };
        if in_contact && self.steady_s >= 1.0 {
            self.trans_abs += s.transparency_abs_n;
            self.trans_ref += s.slave_force_n;
        }
    }

    /// The mean drift over the last 0.5 s of settled contact (`cycle`: the settled contact
    /// cycles; only those in touch count), mm.
    fn settled_drift_mm(&self, cycle: &[usize], contact_threshold_n: f64) -> f64 {
        let drift_tail: Vec<f64> = cycle
            .iter()
            .rev()
            .filter(|&&k| self.force_n[k] > contact_threshold_n)
            .take(500)
            .map(|&k| self.drift_mm[k])
            .collect();
        if drift_tail.is_empty() {
            0.0
        } else {
            drift_tail.iter().sum::<f64>() / drift_tail.len() as f64
        }
    }

    /// What the operator's hand feels (issue 32): the rendered and the true force's content
    /// above [`HF_CUTOFF_HZ`] in the settled holds (worst hold), and the largest rendered force
    /// in free space after the first hold's release.
    fn rendered_measures(
        &self,
        holds: &Holds,
        rtt_mean_ms: f64,
        d: &DetectorConfig,
    ) -> (f64, f64, f64) {
        let hf_max = |x: &[[f64; 3]]| {
            holds
                .settled
                .iter()
                .map(|r| high_frequency_rms(&x[r.clone()], HF_CUTOFF_HZ))
                .fold(0.0, nan_max)
        };
        let rendered_hf_rms_n = hf_max(&self.rendered_n);
        let true_hf_rms_n = hf_max(&self.true_vec_n);
        let free_space_rendered_max_n = match holds.settled.first() {
            Some(first) => free_space_max(
                &self.rendered_n,
                &self.force_n,
                &self.push_n,
                &self.intent_steady,
                first.end,
                if rtt_mean_ms.is_finite() {
                    (rtt_mean_ms.max(0.0) * 1e-3 / DT_S).ceil() as usize
                } else {
                    0
                },
                d,
            ),
            None => 0.0,
        };
        (rendered_hf_rms_n, true_hf_rms_n, free_space_rendered_max_n)
    }

    /// The force transparency error, % of the reference (NaN without one).
    fn transparency_err_pct(&self) -> f64 {
        if self.trans_ref > 0.0 {
            100.0 * self.trans_abs / self.trans_ref
        } else {
            f64::NAN
        }
    }

    /// The position tracking error's RMS, mm (NaN without a sample).
    fn tracking_err_mm(&self) -> f64 {
        if self.track_n > 0 {
            (self.track_sq / self.track_n as f64).sqrt()
        } else {
            f64::NAN
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn finish(
        self,
        name: String,
        dissipated_j: f64,
        packets_lost: u64,
        packets_rejected: u64,
        rtt_mean_ms: f64,
        cycles: u64,
        wall_time_s: f64,
        fin: &RunFacts,
    ) -> Summary {
        let d = self.det;
        let diverged = self.diverged;
        let win = (d.window_s / DT_S).round() as usize;
        let gap = (d.contact_gap_s / DT_S).round() as usize;
        let (episodes, bounces) = contact_episodes(&self.force_n, d.contact_threshold_n, gap);
        let settle = (d.settle_s / DT_S).round() as usize;
        let impacts = bouncing_impacts(
            &self.force_n,
            &episodes,
            settle,
            d.impact_force_n,
            (d.bounce_gap_s / DT_S).round() as usize,
        );
        let (cycle, residual): (Vec<usize>, Vec<f64>) =
            contact_residuals(&self.force_n, &episodes, settle, d.mean_time_constant_s)
                .into_iter()
                .unzip();
        let n = residual.len();
        let early = rms_of(&residual[..win.min(n)]);
        let late = rms_of(&residual[n.saturating_sub(win)..]);
        let growth = late / early.max(d.oscillation_floor_n);
        let drift = self.settled_drift_mm(&cycle, d.contact_threshold_n);
        let mut reasons = Vec::new();
        if self.diverged {
            reasons.push("diverged".to_string());
        }
        if late > d.oscillation_limit_n {
            reasons.push(format!(
                "oscillation: late contact-force oscillation {late:.2} N RMS > {} N",
                d.oscillation_limit_n
            ));
        }
        if growth > d.growth_limit {
            reasons.push(format!(
                "growth: oscillation grew {growth:.2}x > {}x",
                d.growth_limit
            ));
        }
        if impacts >= d.bounce_limit {
            reasons.push(format!(
                "bouncing: {impacts} impacts in a row (touches shorter than {} s reaching {} N, \
                 each within {} s of the last) >= {}",
                d.settle_s, d.impact_force_n, d.bounce_gap_s, d.bounce_limit
            ));
        }
        if self.energy_min.is_nan() || self.energy_min < -d.energy_tolerance_j {
            reasons.push(format!(
                "energy: observer reached {:.4} J < -{} J",
                self.energy_min, d.energy_tolerance_j
            ));
        }
        if self.max_force.is_nan() || self.max_force > d.force_limit_n {
            reasons.push(format!(
                "force: contact force {:.1} N > {} N",
                self.max_force, d.force_limit_n
            ));
        }
        // The tip's height, when every cycle had one (a cutting session).
        let tip_z = (self.tip_z_mm.len() == self.force_n.len()).then_some(&self.tip_z_mm[..]);
        let holds = holds(
            &self.force_n,
            &self.push_n,
            &self.applied_push_n,
            &self.intent_steady,
            tip_z,
            fin.force_scale,
            &d,
        );
        let (rendered_hf_rms_n, true_hf_rms_n, free_space_rendered_max_n) =
            self.rendered_measures(&holds, rtt_mean_ms, &d);
        if holds.ripple_rms_n > d.hold_ripple_limit_n {
            reasons.push(format!(
                "hold ripple: true force {:.2} N RMS around its trend > {} N",
                holds.ripple_rms_n, d.hold_ripple_limit_n
            ));
        }
        if holds.bounces > 0 {
            reasons.push(format!(
                "bounces: {} contacts lost and regained (reaching {} N) while pushing",
                holds.bounces, d.bounce_force_n
            ));
        }
        let sim_time_s = cycles as f64 * DT_S;
        Summary {
            name,
            stable: reasons.is_empty(),
            unstable_reasons: reasons,
            energy_min_j: self.energy_min,
            max_force_n: self.max_force,
            max_master_force_n: self.max_master,
            master_force_chatter_n: self.chatter_max,
            oscillation_growth: growth,
            oscillation_early_n: early,
            oscillation_late_n: late,
            position_drift_mm: drift,
            position_drift_max_mm: self.drift_max,
            force_transparency_err_pct: self.transparency_err_pct(),
            position_tracking_err_mm: self.tracking_err_mm(),
            passivity_dissipated_j: dissipated_j,
            packets_lost,
            packets_rejected,
            rtt_mean_ms,
            contact_time_s: n as f64 * DT_S,
            contact_bounces: bounces,
            bouncing_impacts: impacts,
            slave_rejected_cycles: self.rejected,
            slave_gate: Default::default(),
            master_gate: Default::default(),
            rtt_measured_p50_ms: f64::NAN,
            rtt_measured_p99_ms: f64::NAN,
            rtt_jitter_ms: f64::NAN,
            rtt_fallback_cycles: 0,
            cycles,
            sim_time_s,
            wall_time_s,
            first_touch_peak_n: holds.first_touch_peak_n,
            hold_force_n: holds.force_n,
            hold_push_n: holds.push_n,
            hold_target_n: holds.target_n,
            hold_ripple_rms_n: holds.ripple_rms_n,
            rendered_hf_rms_n,
            true_hf_rms_n,
            free_space_rendered_max_n,
            bounces: holds.bounces,
            slave_safe_stops: fin.slave_safe_stops,
            master_saw_safe_stops: fin.master_saw_safe_stops,
            repairs: fin.repairs,
            diverged,
            safety_trips: fin.safety_trips,
            unsafe_test_override: fin.unsafe_test_override,
            cutting: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rms(v: &[f64]) -> f64 {
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    }

    /// `n` samples of `f` (1 ms apart), as one contact episode, all settled.
    fn residuals_of(f: impl Fn(f64) -> f64, n: usize, tau: f64) -> Vec<f64> {
        let force: Vec<f64> = (0..n).map(|k| f(k as f64 * DT_S)).collect();
        contact_residuals(&force, std::slice::from_ref(&(0..n)), 0, tau)
            .into_iter()
            .map(|(_, r)| r)
            .collect()
    }

    /// The high-frequency measure: a level, a ramp and a slow (2 Hz) swing leave next to
    /// nothing, the window's edges included; a 60 Hz ripple is measured at its RMS (94 % or
    /// more of it above twice the cut-off), a 20 Hz one at about half; a burst of 1 N for
    /// 5 ms every 20 ms (a force stepping at lost feedback) is caught.
    #[test]
    fn high_frequency_rms_keeps_only_the_content_above_the_cut_off() {
        let n = 3000;
        let sig = |f: &dyn Fn(f64) -> f64| -> Vec<[f64; 3]> {
            (0..n)
                .map(|k| {
                    let t = k as f64 * DT_S;
                    [0.2 * f(t), -1.0, 6.0 + 0.5 * t + f(t)]
                })
                .collect()
        };
        let sine = |hz: f64, a: f64| move |t: f64| a * (2.0 * std::f64::consts::PI * hz * t).sin();
        let flat = high_frequency_rms(&sig(&|_| 0.0), HF_CUTOFF_HZ);
        assert!(flat < 1e-9, "{flat}");
        let slow = high_frequency_rms(&sig(&sine(2.0, 1.0)), HF_CUTOFF_HZ);
        assert!(slow < 1e-3, "{slow}");
        // Amplitude 0.1 N on z and 0.02 N on x: RMS 0.102 / √2.
        let rms60 = 0.1 * (1.0f64 + 0.04).sqrt() / 2f64.sqrt();
        let fast = high_frequency_rms(&sig(&sine(60.0, 0.1)), HF_CUTOFF_HZ);
        assert!(fast > 0.94 * rms60 && fast < 1.01 * rms60, "{fast} {rms60}");
        let at_cut = high_frequency_rms(&sig(&sine(20.0, 0.1)), HF_CUTOFF_HZ);
        assert!((at_cut - 0.5 * rms60).abs() < 0.05 * rms60, "{at_cut}");
        let bursts = high_frequency_rms(
            &sig(&|t: f64| {
                if (t * 1e3) as usize % 20 < 5 {
                    1.0
                } else {
                    0.0
                }
            }),
            HF_CUTOFF_HZ,
        );
        assert!(bursts > 0.3, "{bursts}");
        assert_eq!(high_frequency_rms(&[[1.0; 3]; 2], HF_CUTOFF_HZ), 0.0);
    }

    /// Free space after a release: only the cycles after the first hold with no push, the
    /// intent at rest and the slave out of contact for longer than the round trip count; a
    /// force left rendered there is seen, the same force during the hold or within the
    /// round trip after the contact ends is not.
    #[test]
    fn free_space_counts_only_rest_out_of_contact_after_a_release() {
        let d = DetectorConfig::default();
        let n = 4000;
        // Hold until 2000, release move 2000-2300 (not steady), contact lost at 2100, rest.
        let force: Vec<f64> = (0..n).map(|k| if k < 2100 { 10.0 } else { 0.0 }).collect();
        let push: Vec<f64> = (0..n).map(|k| if k < 2000 { 5.0 } else { 0.0 }).collect();
        let steady: Vec<bool> = (0..n).map(|k| !(2000..2300).contains(&k)).collect();
        let rendered = |left_n: f64| -> Vec<[f64; 3]> {
            (0..n)
                .map(|k| {
                    if k < 2150 {
                        [0.0, 0.0, 5.0]
                    } else {
                        [0.0, left_n, 0.0]
                    }
                })
                .collect()
        };
        // With a 100 ms round trip: free from 2300 (rest) on; 2150 is within it anyway.
        let clean = free_space_max(&rendered(0.0), &force, &push, &steady, 2000, 100, &d);
        assert_eq!(clean, 0.0);
        let left = free_space_max(&rendered(0.6), &force, &push, &steady, 2000, 100, &d);
        assert!((left - 0.6).abs() < 1e-12, "{left}");
        // A 500 ms round trip: the master cannot know before 2600; the contact's force
        // rendered until then is not free space's.
        let mut late = rendered(0.0);
        for r in late.iter_mut().take(2600).skip(2150) {
            *r = [0.0, 0.0, 5.0];
        }
        assert_eq!(
            free_space_max(&late, &force, &push, &steady, 2000, 500, &d),
            0.0
        );
        assert!(free_space_max(&late, &force, &push, &steady, 2000, 100, &d) > 4.0);
    }

    /// A push and a release (ramps, also at the ends of the episode) are not oscillation;
    /// an oscillation is, by the documented fraction; episodes are filtered one at a time.
    #[test]
    fn contact_residuals_ignore_ramps_and_measure_oscillation() {
        let tau = 0.1;
        // Ramp up 0 → 20 N in 0.3 s, hold, ramp down to 0.5 N in 0.3 s at the end.
        let push_hold_release = |t: f64| {
            if t < 0.3 {
                20.0 * t / 0.3
            } else if t < 2.7 {
                20.0
            } else {
                20.0 - 19.5 * (t - 2.7) / 0.3
            }
        };
        let r = residuals_of(push_hold_release, 3000, tau);
        assert_eq!(r.len(), 3000);
        // Along a ramp and a hold nothing; a change of slope leaves about slope·τ/2
        // (here 3.3 N) for about τ. (The causal moving mean this replaced left slope·τ,
        // 6.7 N, over each whole ramp, the release included.)
        assert!(r[1000..2000].iter().all(|x| x.abs() < 0.01), "hold");
        assert!(r[2850..].iter().all(|x| x.abs() < 1.0), "release");
        assert!(rms(&r) < 1.0, "{}", rms(&r));
        // A 5 Hz, 2 N-amplitude oscillation on 10 N: (2πfτ)²/(1+(2πfτ)²) ≈ 0.91 of it.
        let osc = |t: f64| 10.0 + 2.0 * (2.0 * std::f64::consts::PI * 5.0 * t).sin();
        let r = residuals_of(osc, 4000, tau);
        let w = 2.0 * std::f64::consts::PI * 5.0 * tau;
        let expect = 2.0 / 2f64.sqrt() * w * w / (1.0 + w * w);
        let got = rms(&r[500..3500]);
        assert!((got - expect).abs() < 0.05 * expect, "{got} {expect}");
        // Two episodes at different levels: no step between them shows as oscillation.
        let mut two = vec![5.0; 1000];
        two.extend(vec![30.0; 1000]);
        let r = contact_residuals(&two, &[0..1000, 1000..2000], 0, tau);
        assert!(r.iter().all(|x| x.1.abs() < 1e-9));
        // Samples before the settle time are filtered but not reported; cycles are kept.
        let r = contact_residuals(&[5.0; 100], std::slice::from_ref(&(0..100)), 40, tau);
        assert_eq!(r.len(), 60);
        assert_eq!(r[0].0, 40);
    }

    /// Touches closer than the gap are one episode (the bounces counted); a release and a
    /// new push further apart are two.
    #[test]
    fn contact_episodes_join_bounces() {
        let th = 0.5;
        // 0.2 s free, then a tool bouncing at 8 Hz (60 ms on at 30 N, 60 ms off) for 1.2 s,
        // then 1 s free, then a held push of 1 s.
        let mut f = vec![0.0; 200];
        for _ in 0..10 {
            f.extend(vec![30.0; 60]);
            f.extend(vec![0.0; 60]);
        }
        f.extend(vec![0.0; 1000]);
        f.extend(vec![10.0; 1000]);
        f.push(0.0);
        let (e, bounces) = contact_episodes(&f, th, 250);
        assert_eq!(e, vec![200..1340, 2400..3400]);
        assert_eq!(bounces, 9);
        // With no gap every touch is its own episode.
        let (each, bounces) = contact_episodes(&f, th, 0);
        assert_eq!((each.len(), bounces), (11, 0));
        // The bouncing episode is an oscillation of about 15 N RMS around its mean: the
        // detector sees it (touch by touch it saw nothing, each touch shorter than the
        // settle time).
        let r: Vec<f64> = contact_residuals(&f, &e[..1], 0, 0.1)
            .into_iter()
            .map(|x| x.1)
            .collect();
        assert!(rms(&r[200..]) > 10.0, "{}", rms(&r));
    }

    /// A tool that bounces off the wall slowly (each touch shorter than the settle time,
    /// gaps longer than the episode gap) is counted impact by impact; a long touch, a touch
    /// too light, or a gap too long ends the run.
    #[test]
    fn bouncing_impacts_count_short_touches_in_a_row() {
        // Touches of 160 ms at 70 N every 630 ms (the bare coupling at 100 ms round trip).
        let mut f = vec![0.0; 100];
        for _ in 0..6 {
            f.extend(vec![70.0; 160]);
            f.extend(vec![0.0; 470]);
        }
        // A held push (a long touch), then three light taps, then two impacts 3 s apart.
        f.extend(vec![20.0; 2000]);
        f.extend(vec![0.0; 300]);
        for _ in 0..3 {
            f.extend(vec![1.5; 100]);
            f.extend(vec![0.0; 300]);
        }
        for _ in 0..2 {
            f.extend(vec![0.0; 3000]);
            f.extend(vec![50.0; 100]);
        }
        let (e, _) = contact_episodes(&f, 0.5, 250);
        assert_eq!(e.len(), 6 + 1 + 3 + 2);
        assert_eq!(bouncing_impacts(&f, &e, 500, 2.0, 2000), 6);
        // The light taps count only if the impact force is below them.
        assert_eq!(bouncing_impacts(&f, &e[6..], 500, 1.0, 2000), 3);
        // With a longer settle time the held push is an impact too.
        assert_eq!(bouncing_impacts(&f, &e, 2500, 2.0, 2000), 7);
    }

    /// In a cutting session a hold is the push's stretch in contact: a steady push that
    /// starts before the tool meets the stock and goes on after the last material is cut
    /// (the force 0, then 9 N steady, then falling to 0 in a cycle) has no ripple, and a
    /// limit cycle of ±2 N while in contact is still caught. Control: the same force without
    /// the cut (a plain surface) is one hold through the plunge and the end, and its
    /// ripple is large.
    #[test]
    fn a_cutting_hold_is_the_push_in_contact_and_its_oscillation_still_counts() {
        let d = DetectorConfig::default();
        let n = 14_000;
        let push = vec![5.0; n];
        let applied = vec![5.0; n];
        let steady: Vec<bool> = (0..n).map(|k| k >= 500).collect();
        let force = |wobble: f64| -> Vec<f64> {
            (0..n)
                .map(|k| {
                    if (1300..13_000).contains(&k) {
                        9.0 + wobble * (2.0 * std::f64::consts::PI * 3.0 * k as f64 * DT_S).sin()
                    } else {
                        0.0
                    }
                })
                .collect()
        };
        let tip = vec![-251.0; n];
        let steady_cut = holds(&force(0.0), &push, &applied, &steady, Some(&tip), 0.5, &d);
        assert!(steady_cut.ripple_rms_n < 0.01, "{steady_cut:?}");
        assert_eq!(steady_cut.hold_count(), 1);
        let wobbly_cut = holds(&force(2.0), &push, &applied, &steady, Some(&tip), 0.5, &d);
        assert!(wobbly_cut.ripple_rms_n > 1.2, "{wobbly_cut:?}");
        let plain = holds(&force(0.0), &push, &applied, &steady, None, 0.5, &d);
        assert!(plain.ripple_rms_n > 2.0, "control: {plain:?}");
    }

    /// The holds' measures on synthetic forces, with negative controls: a slow (0.3 Hz)
    /// limit cycle of ±2 N around a held 12 N is caught as ripple, while a steady push
    /// ramping up by 4 N over the hold (a trend) is not; a contact lost and regained while
    /// pushing is a bounce; the first-touch peak is the impact before the hold.
    #[test]
    fn holds_see_slow_oscillation_bounces_and_the_first_touch() {
        let d = DetectorConfig::default();
        let n = 8000;
        let push = vec![6.0; n];
        // The hand applies 5 N of its intended 6 (its arm spring takes the rest): the hold
        // asks for what it applies.
        let applied = vec![5.0; n];
        let steady: Vec<bool> = (0..n).map(|k| k >= 1000).collect();
        let touch = |k: usize| {
            if k < 500 {
                0.0
            } else if k < 520 {
                30.0
            } else {
                12.0
            }
        };
        let slow: Vec<f64> = (0..n)
            .map(|k| {
                touch(k)
                    + if k >= 520 {
                        2.0 * (2.0 * std::f64::consts::PI * 0.3 * k as f64 * DT_S).sin()
                    } else {
                        0.0
                    }
            })
            .collect();
        let h = holds(&slow, &push, &applied, &steady, None, 0.5, &d);
        assert!(h.ripple_rms_n > 1.2, "{h:?}");
        assert_eq!(h.hold_count(), 1);
        assert!((h.target_n[0] - 10.0).abs() < 1e-9, "{h:?}");
        assert!((h.push_n[0] - 5.0).abs() < 1e-9, "{h:?}");
        assert!((h.first_touch_peak_n - 30.0).abs() < 1e-9, "{h:?}");
        let ramp: Vec<f64> = (0..n)
            .map(|k| {
                touch(k)
                    + if k >= 520 {
                        4.0 * k as f64 / n as f64
                    } else {
                        0.0
                    }
            })
            .collect();
        let h = holds(&ramp, &push, &applied, &steady, None, 0.5, &d);
        assert!(h.ripple_rms_n < 0.01, "{h:?}");
        assert!(
            (h.force_n[0] - 12.0 - 4.0 * 5000.0 / 8000.0).abs() < 0.3,
            "{h:?}"
        );
        assert_eq!(h.bounces, 0);
        // Two bounces: contact lost for 50 ms twice, regained at 12 N.
        let bouncy: Vec<f64> = (0..n)
            .map(|k| {
                if (3000..3050).contains(&k) || (5000..5050).contains(&k) {
                    0.0
                } else {
                    touch(k)
                }
            })
            .collect();
        let h = holds(&bouncy, &push, &applied, &steady, None, 0.5, &d);
        assert_eq!(h.bounces, 2, "{h:?}");
        // A release (no push) and a new touch is not a bounce.
        let mut push2 = push.clone();
        for p in push2.iter_mut().take(5100).skip(4900) {
            *p = 0.0;
        }
        let rel: Vec<f64> = (0..n)
            .map(|k| {
                if (5000..5050).contains(&k) {
                    0.0
                } else {
                    touch(k)
                }
            })
            .collect();
        assert_eq!(
            holds(&rel, &push2, &applied, &steady, None, 0.5, &d).bounces,
            0
        );
        // In a cut: the same two force losses with the tip where it was (a cutter dwelling
        // in its own cut) are no bounce; with the tip lifted 0.3 mm off the part, two.
        let still = vec![-252.0; n];
        let h = holds(&bouncy, &push, &applied, &steady, Some(&still), 0.5, &d);
        assert_eq!(h.bounces, 0, "{h:?}");
        let lifted: Vec<f64> = (0..n)
            .map(|k| {
                if (3010..3040).contains(&k) || (5010..5040).contains(&k) {
                    -251.7
                } else {
                    -252.0
                }
            })
            .collect();
        let h = holds(&bouncy, &push, &applied, &steady, Some(&lifted), 0.5, &d);
        assert_eq!(h.bounces, 2, "{h:?}");
        // A lift of less than bounce_lift_mm is no lift.
        let rise: Vec<f64> = lifted.iter().map(|z| -252.0 + (z + 252.0) * 0.02).collect();
        let h = holds(&bouncy, &push, &applied, &steady, Some(&rise), 0.5, &d);
        assert_eq!(h.bounces, 0, "{h:?}");
    }
}
