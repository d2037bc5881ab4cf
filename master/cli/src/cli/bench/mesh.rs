//! `--only mesh` (issue 34): the mesh fixture's per-cycle query time. The fixture of each
//! shipped mesh session (`cut-mesh-dome.toml`, `cut-mesh-pawn.toml` on the turntable, its
//! measured angle turning through the sweep) is asked to limit a sweep of tool poses over
//! and into its part, one call per simulated cycle; each call is timed (a monotonic clock
//! read either side, ≈ 20–40 ns of it in the figure). Target: ≤ 5 µs per cycle.

use std::time::Instant;

use h4_shared::kinematics::Pose;
use h4_slave::controller::Fixtures;
use h4_telemetry::rt::Histogram;

use super::{Row, quantiles_us, repo_file};

/// Poses in the sweep: a raster of the part's neighbourhood at several depths, repeated.
const SWEEP_POSES: usize = 200_000;

/// The target, µs per cycle.
const TARGET_US: f64 = 5.0;

/// One session's fixture timed over the sweep: its histogram (ns), the mean (µs) and the
/// share of calls the fixture moved the pose.
fn time_session(session: &str) -> Result<(Histogram, f64, f64), String> {
    let path = repo_file(&format!("config/sessions/{session}.toml"))?;
    let cfg = h4_master_sim::session::load(&path, &[]).map_err(|e| format!("{session}: {e}"))?;
    let target = cfg
        .cut_target
        .as_ref()
        .ok_or_else(|| format!("{session}: no cut_target"))?;
    let mut f = Fixtures::new(&cfg.fixtures);
    let axis = cfg
        .cutting
        .as_ref()
        .and_then(|c| c.turntable.as_ref())
        .map(|t| t.axis_mm);
    if let Some(a) = axis {
        f.set_turntable_axis(a);
    }
    let top = cfg
        .cutting
        .as_ref()
        .map_or(-250.0, |c| c.stock_centre_top_mm[2]);
    let [cx, cy] = target.centre_mm;
    let half = target.size_mm.map(|s| 0.5 * s + 4.0);
    let mut h = Histogram::new();
    let (mut total_ns, mut moved) = (0u128, 0usize);
    for n in 0..SWEEP_POSES {
        // 41 × 41 points over the judged patch and 4 mm round it, 12 depths from 1 mm above
        // the top to 10 mm into the block; the table turning 1 mrad per cycle.
        let (i, j, k) = (n % 41, (n / 41) % 41, (n / (41 * 41)) % 12);
        let x = cx - half[0] + 2.0 * half[0] * i as f64 / 40.0;
        let y = cy - half[1] + 2.0 * half[1] * j as f64 / 40.0;
        let z = top + 1.0 - k as f64;
        if axis.is_some() {
            f.observe_turntable(Some(1e-3 * n as f64));
        }
        let pose = Pose::new(x, y, z, 0.0);
        let t0 = Instant::now();
        let p = f.limit(std::hint::black_box(pose));
        let ns = t0.elapsed().as_nanos();
        std::hint::black_box(p);
        total_ns += ns;
        h.record(u64::try_from(ns).unwrap_or(u64::MAX));
        moved += usize::from(f.mesh_active());
    }
    let mean_us = total_ns as f64 / SWEEP_POSES as f64 / 1e3;
    Ok((h, mean_us, moved as f64 / SWEEP_POSES as f64))
}

/// The rows: one per shipped mesh session.
pub fn rows(report: &mut super::BenchReport) {
    for session in ["cut-mesh-dome", "cut-mesh-pawn"] {
        match time_session(session) {
            Ok((h, mean_us, moved)) => {
                let mut figures = quantiles_us(&h);
                figures.push(("mean".into(), mean_us));
                figures.push(("moved_share".into(), moved));
                let (p99, max) = (
                    super::figure_of(&figures, "p99"),
                    super::figure_of(&figures, "max"),
                );
                report.rows.push(Row {
                    name: format!("mesh: fixture query per cycle, {session}"),
                    unit: "us",
                    figures,
                    target: format!("<= {TARGET_US} us (mean and p99)"),
                    met: Some(mean_us <= TARGET_US && p99 <= TARGET_US && max.is_finite()),
                });
            }
            Err(e) => report.skipped.push(format!("mesh fixture query: {e}")),
        }
    }
}
