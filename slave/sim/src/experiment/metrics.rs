//! The summary of a run: how well the force was held over the steady tracking phases, how
//! each contact and set-point step went.

use serde::Serialize;

use super::config::ExperimentConfig;
use super::run::Trace;
use h4_slave::controller::Status;

/// How one contact or set-point step went.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct EventSummary {
    /// Time of the event, s (first contact, or the step).
    pub time_s: f64,
    /// Set-point before, N (0 for the first contact).
    pub from_n: f64,
    /// Set-point after, N.
    pub to_n: f64,
    /// Largest excursion beyond the new set-point in the step's direction, % of the step.
    pub overshoot_pct: f64,
    /// Time until the force stays within the settling band, ms.
    pub settling_ms: f64,
    /// Whether the force settled before the next event (or the end).
    pub settled: bool,
}

/// The result of one experiment.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// The experiment's name.
    pub name: String,
    /// RMS of |F_n − F_d| over the steady tracking phases, N (true contact force along the
    /// true surface normal). A steady phase starts `summary.transient_s` after the first
    /// contact, after each step and after the tracking motion starts, and ends at the next
    /// step or the end of the run.
    pub force_error_rms_n: f64,
    /// 99th percentile of |F_n − F_d| over the steady tracking phases, N.
    pub force_error_p99_n: f64,
    /// 99th percentile of |F_n − F_d| over the whole contact, transients kept: from the
    /// first touch to the end, each event (first touch, step) counted from the cycle its
    /// force first comes within `summary.settle_band_min_n` of the new set-point (the rise
    /// itself is the set-point prefilter's, not an error), N.
    pub force_error_p99_contact_n: f64,
    /// Largest |F_n − F_d| over the same cycles (overshoots, ringing, the start of the
    /// motion, contact losses all count), N.
    pub force_error_max_n: f64,
    /// Largest |F_n − F_d| over the steady tracking phases, N.
    pub force_error_max_steady_n: f64,
    /// Largest |F_n − F_d| from the start of the tracking motion on (its start included,
    /// 'transient_s' after steps excluded), N.
    pub force_error_max_tracking_n: f64,
    /// Largest overshoot over the first contact and every step, % of the step.
    pub overshoot_pct: f64,
    /// Longest settling time over the first contact and every step, ms.
    pub settling_ms: f64,
    /// Largest contact force magnitude, N.
    pub max_force_n: f64,
    /// Time without contact after tracking started, ms.
    pub contact_lost_ms: f64,
    /// Path length of the tool along the surface while tracking, mm.
    pub tracked_distance_mm: f64,
    /// Time of the first contact, s.
    pub first_contact_s: f64,
    /// The controller's final estimate of the environment's stiffness, N/mm.
    pub env_stiffness_estimate_n_per_mm: f64,
    /// The surface's true stiffness, N/mm.
    pub env_stiffness_true_n_per_mm: f64,
    /// Cycles whose command the controller rejected.
    pub rejected_cycles: u64,
    /// The first contact and every step.
    pub events: Vec<EventSummary>,
    /// Control cycles run (1 ms each).
    pub cycles: u64,
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Whether the tool ever touched the surface (true contact force).
    pub contact_reached: bool,
    /// Time from the first true contact to the controller's touch, ms (negative: a false
    /// contact before it; NaN: either never happened).
    pub contact_detection_delay_ms: f64,
    /// The verdict against the file's `[targets]`.
    pub verdict: Verdict,
    /// Wall-clock time of the simulation, s (the only field that is not deterministic).
    pub wall_time_s: f64,
    /// sim_time_s / wall_time_s (not deterministic).
    pub speedup: f64,
}

/// The run judged against the experiment file's `[targets]`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Verdict {
    /// Every target met (`h4-slave experiment` exits 0), or not (exits 1).
    pub passed: bool,
    /// Each miss, named with its figure and target (a run that never touched its surface
    /// says so and why).
    pub failures: Vec<String>,
}

/// An event: its cycle, the set-point before and after, N.
type Event = (usize, f64, f64);

/// The summary of the run `trace` of `cfg`; `env_true_n_per_mm` is the surface's true
/// stiffness, `wall_time_s` the run's wall-clock time.
pub(super) fn summarise(
    cfg: &ExperimentConfig,
    trace: &Trace,
    env_true_n_per_mm: f64,
    wall_time_s: f64,
) -> Summary {
    let events = events(cfg, trace);
    let mut phases = Phases {
        errors: Vec::new(),
        contact_errors: Vec::new(),
        tracking_max: 0.0,
    };
    let event_summaries: Vec<EventSummary> = (0..events.len())
        .map(|i| judge_event(cfg, trace, &events, i, &mut phases))
        .collect();
    let errors = &mut phases.errors;
    let rms = if errors.is_empty() {
        f64::NAN
    } else {
        (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt()
    };
    let error_max = max_of(errors);
    let p99 = p99_of(errors);
    let contact_max = max_of(&phases.contact_errors);
    let contact_p99 = p99_of(&mut phases.contact_errors);
    let cycles = trace.fn_true_n.len() as u64;
    let sim_time_s = cycles as f64 * 1e-3;
    Summary {
        name: cfg.name.clone(),
        force_error_rms_n: rms,
        force_error_p99_n: p99,
        force_error_p99_contact_n: contact_p99,
        force_error_max_n: contact_max,
        force_error_max_steady_n: error_max,
        force_error_max_tracking_n: phases.tracking_max,
        overshoot_pct: event_summaries
            .iter()
            .map(|e| e.overshoot_pct)
            .fold(f64::NAN, f64::max),
        settling_ms: event_summaries
            .iter()
            .map(|e| {
                if e.settled {
                    e.settling_ms
                } else {
                    f64::INFINITY
                }
            })
            .fold(f64::NAN, f64::max),
        max_force_n: trace.max_force_n,
        contact_lost_ms: trace.contact_lost_ms as f64,
        tracked_distance_mm: trace.tracked_mm,
        first_contact_s: trace
            .first_true_contact
            .map_or(f64::NAN, |i| i as f64 * 1e-3),
        env_stiffness_estimate_n_per_mm: trace.env_estimate_n_per_mm,
        env_stiffness_true_n_per_mm: env_true_n_per_mm,
        rejected_cycles: trace.rejected_cycles,
        events: event_summaries,
        cycles,
        sim_time_s,
        contact_reached: trace.first_true_contact.is_some(),
        contact_detection_delay_ms: match (trace.ctrl_contact_ms, trace.first_true_contact) {
            (Some(tc), Some(fc)) => tc as f64 - fc as f64,
            _ => f64::NAN,
        },
        verdict: Verdict {
            passed: true,
            failures: Vec::new(),
        },
        wall_time_s,
        speedup: sim_time_s / wall_time_s.max(1e-9),
    }
}

/// The verdict of `summary` (of the run `trace` of `cfg`) against `cfg.targets`: every
/// miss named with its figure and target.
pub(super) fn judge(cfg: &ExperimentConfig, trace: &Trace, summary: &Summary) -> Verdict {
    let mut failures = Vec::new();
    if let Some(why) = no_contact_reason(cfg, trace) {
        failures.push(why);
    }
    let t = &cfg.targets;
    // `!(x <= limit)`: a NaN figure counts as a miss.
    let checks = [
        (
            "force_error_p99_n",
            summary.force_error_p99_n,
            t.force_error_p99_n,
            "N",
        ),
        (
            "force_error_p99_contact_n",
            summary.force_error_p99_contact_n,
            t.force_error_p99_contact_n,
            "N",
        ),
        (
            "force_error_max_n",
            summary.force_error_max_n,
            t.force_error_max_n,
            "N",
        ),
        ("overshoot_pct", summary.overshoot_pct, t.overshoot_pct, "%"),
        ("settling_ms", summary.settling_ms, t.settling_ms, "ms"),
        (
            "contact_lost_ms",
            summary.contact_lost_ms,
            t.contact_lost_ms,
            "ms",
        ),
        (
            "max_force_n",
            summary.max_force_n,
            cfg.controller.force_limit_n,
            "N (controller.force_limit_n)",
        ),
    ];
    if summary.contact_reached {
        for (name, value, limit, unit) in checks {
            #[allow(clippy::neg_cmp_op_on_partial_ord)]
            if !(value <= limit) {
                failures.push(format!("{name} {value:.3} above its target {limit} {unit}"));
            }
        }
    }
    if let (Some(tc), Some(fc)) = (trace.ctrl_contact_ms, trace.first_true_contact)
        && (tc as usize) < fc
    {
        failures.push(format!(
            "false contact: the controller declared contact at {:.3} s, {} ms before the tool \
             touched the surface",
            tc as f64 * 1e-3,
            fc - tc as usize
        ));
    }
    Verdict {
        passed: failures.is_empty(),
        failures,
    }
}

/// Why the run never touched its surface (None if it did).
fn no_contact_reason(cfg: &ExperimentConfig, trace: &Trace) -> Option<String> {
    if trace.first_true_contact.is_some() {
        return None;
    }
    let why = if let Some(tc) = trace.ctrl_contact_ms {
        format!(
            "the controller declared contact at {:.3} s in free space (a false contact) and \
             never came down to the surface",
            tc as f64 * 1e-3
        )
    } else if trace.last_status == Status::Approaching && trace.target_distance_mm < 1e-3 {
        format!(
            "the approach reached its target ({} mm below the contact point) without a force \
             above the contact threshold: no surface there",
            cfg.approach.target_depth_mm
        )
    } else if trace.last_status == Status::Approaching {
        format!(
            "the run ended still approaching, {:.2} mm from its target (approach at {} mm/s, \
             duration_s {} s)",
            trace.target_distance_mm, cfg.controller.approach_speed_mm_per_s, cfg.duration_s
        )
    } else {
        format!(
            "the controller ended in state {:?} without touching",
            trace.last_status
        )
    };
    Some(format!("never touched the surface: {why}"))
}

/// The largest of `v` (NaN if empty).
fn max_of(v: &[f64]) -> f64 {
    v.iter().copied().max_by(f64::total_cmp).unwrap_or(f64::NAN)
}

/// The 99th percentile of `v` by selection (the same element a sort would put there; NaN if
/// empty).
fn p99_of(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let rank = ((v.len() as f64 * 0.99).ceil() as usize).clamp(1, v.len()) - 1;
    *v.select_nth_unstable_by(rank, f64::total_cmp).1
}

/// The events: the first contact, then every step (counted from the controller's contact).
fn events(cfg: &ExperimentConfig, trace: &Trace) -> Vec<Event> {
    let mut events: Vec<Event> = Vec::new();
    if let Some(fc) = trace.first_true_contact {
        events.push((fc, 0.0, cfg.force.setpoint_n));
        if let Some(tc) = trace.ctrl_contact_ms {
            let mut prev = cfg.force.setpoint_n;
            for st in &cfg.force.steps {
                let idx = tc as usize + (st.time_s * 1000.0).round() as usize;
                if idx < trace.fn_true_n.len() {
                    events.push((idx, prev, st.setpoint_n));
                }
                prev = st.setpoint_n;
            }
        }
    }
    events
}

/// The force errors of the steady tracking phases, and the largest while tracking.
struct Phases {
    errors: Vec<f64>,
    /// The errors over the whole contact from each event's first reaching of its band.
    contact_errors: Vec<f64>,
    tracking_max: f64,
}

/// How event `i` went (up to the next event), its steady phase's errors booked in `phases`.
fn judge_event(
    cfg: &ExperimentConfig,
    trace: &Trace,
    events: &[Event],
    i: usize,
    phases: &mut Phases,
) -> EventSummary {
    let f_true = &trace.fn_true_n;
    let n = f_true.len();
    let transient = (cfg.summary.transient_s * 1000.0).round() as usize;
    let (idx, from, to) = events[i];
    let end = events.get(i + 1).map_or(n, |e| e.0).max(idx);
    let step = (to - from).abs().max(1e-9);
    let sign = if to >= from { 1.0 } else { -1.0 };
    let mut peak: f64 = 0.0;
    let band = (cfg.summary.settle_band_fraction * step).max(cfg.summary.settle_band_min_n);
    let mut last_out_of_band: Option<usize> = None;
    for (j, f) in f_true.iter().enumerate().take(end).skip(idx) {
        peak = peak.max(sign * (f - to));
        if (f - to).abs() > band {
            last_out_of_band = Some(j);
        }
    }
    let settle_idx = last_out_of_band.map_or(idx, |j| j + 1);
    // The whole contact: from the first cycle the force comes within
    // `settle_band_min_n` of the new set-point (or settles, if it never does).
    let near = cfg.summary.settle_band_min_n;
    let reached = f_true
        .iter()
        .enumerate()
        .take(end)
        .skip(idx)
        .find(|(_, f)| sign * (*f - to) >= -near)
        .map_or(settle_idx, |(j, _)| j);
    for f in f_true.iter().take(end).skip(reached) {
        phases.contact_errors.push((f - to).abs());
    }
    let settled = settle_idx < end;
    // Steady tracking: 'transient_s' after the event and after the tracking starts.
    let steady_from = (idx + transient).max(trace.track_start.map_or(n, |t| t + transient));
    for f in f_true.iter().take(end).skip(steady_from) {
        phases.errors.push((f - to).abs());
    }
    // Everything while tracking (the start of the motion included), for the record.
    let tracking_from = (idx + transient).max(trace.track_start.unwrap_or(n));
    for f in f_true.iter().take(end).skip(tracking_from) {
        phases.tracking_max = phases.tracking_max.max((f - to).abs());
    }
    EventSummary {
        time_s: idx as f64 * 1e-3,
        from_n: from,
        to_n: to,
        overshoot_pct: 100.0 * peak / step,
        settling_ms: (settle_idx - idx) as f64,
        settled,
    }
}
