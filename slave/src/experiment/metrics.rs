//! The summary of a run: how well the force was held over the steady tracking phases, how
//! each contact and set-point step went.

use serde::Serialize;

use super::config::ExperimentConfig;
use super::run::Trace;

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
    /// Largest |F_n − F_d| over the steady tracking phases, N.
    pub force_error_max_n: f64,
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
    /// Wall-clock time of the simulation, s (the only field that is not deterministic).
    pub wall_time_s: f64,
    /// sim_time_s / wall_time_s (not deterministic).
    pub speedup: f64,
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
    let error_max = errors
        .iter()
        .copied()
        .max_by(f64::total_cmp)
        .unwrap_or(f64::NAN);
    // The 99th percentile by selection (the same element a sort would put there).
    let p99 = if errors.is_empty() {
        f64::NAN
    } else {
        let rank = ((errors.len() as f64 * 0.99).ceil() as usize).clamp(1, errors.len()) - 1;
        *errors.select_nth_unstable_by(rank, f64::total_cmp).1
    };
    let cycles = trace.fn_true_n.len() as u64;
    let sim_time_s = cycles as f64 * 1e-3;
    Summary {
        name: cfg.name.clone(),
        force_error_rms_n: rms,
        force_error_p99_n: p99,
        force_error_max_n: error_max,
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
        wall_time_s,
        speedup: sim_time_s / wall_time_s.max(1e-9),
    }
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
