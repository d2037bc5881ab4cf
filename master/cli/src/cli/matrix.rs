//! `h4-master matrix [--walls …] [--round-trips …] [--out DIR]`: the delay matrix
//! ([`h4_master_sim::matrix`]) as a command: every cell a whole session on the simulated clock,
//! a progress bar (plain lines when stderr is not a terminal), then the per-cell table
//! (`cells.csv`, `cells.json`, `table.md`) and one heat map per wall (`heatmap-<wall>.png`).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};

use h4_master_sim::matrix::{self, Case, Limits, Loss, Matrix, Verdict, Wall};
use h4_master_sim::session::Summary;
use h4_telemetry::process::ExitStatus;
use h4_telemetry::progress::{Progress, ProgressConfig, Unit};
use plotters::prelude::*;
use serde_json::json;

/// Run the delay matrix: a session file over wall × round trip × jitter × loss × force scale
/// on the simulated clock; write the per-cell table and a heat map per wall.
#[derive(Clone, Debug, clap::Args)]
pub struct MatrixArgs {
    /// The session file every cell runs (default: config/sessions/wall-push.toml of the
    /// repository).
    #[arg(long, value_name = "FILE")]
    pub session: Option<PathBuf>,
    /// Override a field of the session file in every cell (repeatable; applied after the
    /// cell's own settings).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Walls: soft (1 N/mm), resin (200), aluminium (1000), steel (2000), or a stiffness in
    /// N/mm; comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = Wall::parse,
          default_value = "soft,resin,aluminium,steel")]
    pub walls: Vec<Wall>,
    /// Round trips, ms (each direction delays half); comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = round_trip_ms,
          default_value = "0,10,50,100,250,500,1000,2000")]
    pub round_trips: Vec<f64>,
    /// Jitter, % of the one-way delay; comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = jitter_pct, default_value = "0,20")]
    pub jitters: Vec<f64>,
    /// Losses: none, 5%, 20%, blackout (200 ms every 2 s); comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = Loss::parse,
          default_value = "none,5%,20%,blackout")]
    pub losses: Vec<Loss>,
    /// `scale.force` values (master force per slave force); comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = force_scale, default_value = "0.5")]
    pub scales: Vec<f64>,
    /// The seed of every cell.
    #[arg(long, default_value_t = 4)]
    pub seed: u64,
    /// Cells run at once (default: the number of cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Where the table and the heat maps go (created if missing).
    #[arg(long, default_value = "out/matrix")]
    pub out: PathBuf,
    /// Accept a safety layer turned off (`passivity.enabled=false`,
    /// `slave.controller.spindle_stall_safe_stop=false`, `slave.safety_monitor=false`) and
    /// controller gains beyond the arm's stable range: for negative controls only. The
    /// summary says so (`unsafe_test_override`). No rating of the arm can be raised.
    #[arg(long)]
    pub unsafe_test_override: bool,
}

fn round_trip_ms(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && (0.0..=20_000.0).contains(&v) => Ok(v),
        _ => Err(format!("{text:?}: a round trip in ms, 0 to 20000")),
    }
}

fn jitter_pct(text: &str) -> Result<f64, String> {
    match text.trim().trim_end_matches('%').parse::<f64>() {
        Ok(v) if v.is_finite() && (0.0..=100.0).contains(&v) => Ok(v / 100.0),
        _ => Err(format!(
            "{text:?}: jitter in % of the one-way delay, 0 to 100"
        )),
    }
}

fn force_scale(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{text:?}: a positive force scale")),
    }
}

const LABEL: &str = "h4-master matrix";

impl MatrixArgs {
    /// Runs the matrix; exit 0 when every cell is stable and keeps the guarantees, 1 when one
    /// does not, 130 when interrupted (the cells run so far are written).
    pub fn run(self) -> Result<ExitCode, String> {
        h4_telemetry::process::install_stop_handlers()
            .map_err(|e| format!("signal handlers: {e}"))?;
        let session =
            h4_shared::paths::default_config(self.session.as_deref(), super::SESSION, "--session")?;
        let cases = matrix::grid(
            &self.scales,
            &self.walls,
            &self.losses,
            &self.jitters,
            &self.round_trips,
            self.seed,
        );
        let m =
            Matrix::new(&session, &self.set).with_unsafe_test_override(self.unsafe_test_override);
        let limits = m.limits(&cases)?;
        std::fs::create_dir_all(&self.out)
            .map_err(|e| format!("--out {}: {e}", self.out.display()))?;
        h4_telemetry::process::check_writable("--out", &self.out.join("cells.json"))?;
        let jobs = self.jobs.unwrap_or_else(|| {
            std::thread::available_parallelism().map_or(2, std::num::NonZeroUsize::get)
        });
        let progress = Progress::start(
            &ProgressConfig::from_env(LABEL),
            Unit::Items("cells"),
            Some(cases.len() as u64),
        );
        let handle = progress.handle();
        let (unstable, unsafe_) = (AtomicU64::new(0), AtomicU64::new(0));
        let sums = m.run_all(
            &cases,
            jobs,
            &h4_telemetry::process::stop_requested,
            &|c, s| {
                match Verdict::of(c, s, &limits) {
                    Verdict::Unsafe => unsafe_.fetch_add(1, Ordering::Relaxed),
                    Verdict::Unstable => unstable.fetch_add(1, Ordering::Relaxed),
                    _ => 0,
                };
                handle.inc(1);
                handle.set_detail(&format!(
                    "{} unstable, {} unsafe",
                    unstable.load(Ordering::Relaxed),
                    unsafe_.load(Ordering::Relaxed)
                ));
            },
        );
        progress.finish();
        let sums = sums?;
        let written = write_outputs(&self, &session, &cases, &sums, &limits)?;
        Ok(verdict(&cases, &sums, &limits, &written))
    }
}

/// Prints the verdict line and returns the exit code.
fn verdict(cases: &[Case], sums: &[Option<Summary>], l: &Limits, out: &Path) -> ExitCode {
    let mut count = [0usize; 4];
    for (c, s) in cases.iter().zip(sums) {
        if let Some(s) = s {
            count[Verdict::of(c, s, l) as usize] += 1;
        }
    }
    let [unsafe_, unstable, missed, met] = count;
    let run = unsafe_ + unstable + missed + met;
    let figures = format!(
        "{run} of {} cells run: {met} met every target, {missed} stable but missed one, \
         {unstable} unstable, {unsafe_} broke a guarantee; table in {}",
        cases.len(),
        out.display()
    );
    let (word, code) = if h4_telemetry::process::signal_received() {
        ("interrupted", ExitStatus::Interrupted)
    } else if unsafe_ + unstable > 0 {
        ("UNSTABLE", ExitStatus::VerdictFailed)
    } else {
        ("stable", ExitStatus::Ok)
    };
    h4_telemetry::progress::verdict_line(LABEL, &format!("{word}, {figures}"));
    code.into()
}

/// Writes `cells.csv`, `cells.json`, `table.md` and the heat maps; returns `table.md`'s path.
fn write_outputs(
    args: &MatrixArgs,
    session: &Path,
    cases: &[Case],
    sums: &[Option<Summary>],
    l: &Limits,
) -> Result<PathBuf, String> {
    let write = |name: &str, text: &str| {
        let p = args.out.join(name);
        std::fs::write(&p, text).map_err(|e| format!("{}: {e}", p.display()))
    };
    write("cells.csv", &csv(cases, sums, l))?;
    let cells: Vec<serde_json::Value> = cases
        .iter()
        .zip(sums)
        .filter_map(|(c, s)| s.as_ref().map(|s| (c, s)))
        .map(|(c, s)| {
            json!({
                "wall": c.wall.name(),
                "case": c,
                "verdict": Verdict::of(c, s, l),
                "misses": matrix::misses(c, s, l),
                "summary": s,
            })
        })
        .collect();
    let doc = json!({
        "session": session.display().to_string(),
        "overrides": args.set,
        "limits": l,
        "cells_planned": cases.len(),
        "cells": cells,
    });
    let text = serde_json::to_string_pretty(&doc).map_err(|e| e.to_string())?;
    write("cells.json", &format!("{text}\n"))?;
    let mut md = format!(
        "# Delay matrix: {}\n\nOverrides: {}. Cells: `ok` (every target met) or `**x**`, ` U` \
         unstable; true force max N / hold ripple N RMS / first held force N / bounces.\n\n",
        session.display(),
        if args.set.is_empty() {
            "none".to_string()
        } else {
            format!("`{}`", args.set.join("`, `"))
        }
    );
    md.push_str(&matrix::table(cases, sums, &args.round_trips, l));
    md.push('\n');
    md.push_str(&matrix::worst_report(cases, sums));
    write("table.md", &md)?;
    h4_slave_sim::report::register_fonts();
    for wall in &args.walls {
        heat_map(args, *wall, cases, sums, l)?;
    }
    Ok(args.out.join("table.md"))
}

fn csv(cases: &[Case], sums: &[Option<Summary>], l: &Limits) -> String {
    let mut t = String::from(
        "wall,stiffness_n_per_mm,round_trip_ms,jitter_pct,loss,scale_force,seed,verdict,stable,\
         max_force_n,max_master_force_n,energy_min_mj,hold_ripple_rms_n,bounces,\
         first_touch_peak_n,hold_force_1_n,hold_force_2_n,position_drift_mm,\
         force_transparency_err_pct,rtt_mean_ms,packets_lost,misses\n",
    );
    for (c, s) in cases.iter().zip(sums) {
        let Some(s) = s else { continue };
        let hold = |i: usize| {
            s.hold_force_n
                .get(i)
                .map_or(String::new(), |v| format!("{v:.3}"))
        };
        t.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{:.3},{:.3},{:.4},{:.4},{},{:.3},{},{},{:.4},{:.2},{:.3},{},\"{}\"\n",
            c.wall.name(),
            c.wall.stiffness_n_per_mm,
            c.rtt_ms,
            c.jitter * 100.0,
            c.loss.name(),
            c.force_scale,
            c.seed,
            Verdict::of(c, s, l).word(),
            s.stable,
            s.max_force_n,
            s.max_master_force_n,
            s.energy_min_j * 1e3,
            s.hold_ripple_rms_n,
            s.bounces,
            s.first_touch_peak_n,
            hold(0),
            hold(1),
            s.position_drift_mm,
            s.force_transparency_err_pct,
            s.rtt_mean_ms,
            s.packets_lost,
            matrix::misses(c, s, l).join("; ").replace('"', "'"),
        ));
    }
    t
}

fn verdict_color(v: Option<Verdict>) -> RGBColor {
    match v {
        Some(Verdict::Met) => RGBColor(120, 200, 120),
        Some(Verdict::Missed) => RGBColor(240, 220, 110),
        Some(Verdict::Unstable) => RGBColor(245, 150, 70),
        Some(Verdict::Unsafe) => RGBColor(215, 50, 50),
        None => RGBColor(225, 225, 225),
    }
}

/// One wall's heat map: a row per (scale, loss, jitter), a column per round trip, each cell
/// coloured by its verdict, with its true force max and hold ripple written in.
fn heat_map(
    args: &MatrixArgs,
    wall: Wall,
    cases: &[Case],
    sums: &[Option<Summary>],
    l: &Limits,
) -> Result<(), String> {
    let name = wall.name().replace([' ', '/'], "");
    let path = args.out.join(format!("heatmap-{name}.png"));
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let mut rows: Vec<Case> = Vec::new();
    for c in cases.iter().filter(|c| c.wall == wall) {
        if !rows.iter().any(|r| matrix::same_row(r, c)) {
            rows.push(*c);
        }
    }
    let cols = &args.round_trips;
    let (left, top, cell_w, cell_h) = (230i32, 90i32, 118i32, 52i32);
    let width = (left + cell_w * cols.len() as i32 + 30).max(820) as u32;
    let height = (top + cell_h * rows.len() as i32 + 110) as u32;
    let root = BitMapBackend::new(&path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let text = |s: &str, x: i32, y: i32, size: i32| {
        root.draw(&Text::new(s.to_string(), (x, y), ("sans-serif", size)))
    };
    text(
        &format!(
            "Delay matrix, {} wall ({} N/mm): verdict per cell",
            wall.name(),
            wall.stiffness_n_per_mm
        ),
        20,
        16,
        24,
    )
    .map_err(|e| err(&e))?;
    text("round trip, ms →", left, top - 48, 16).map_err(|e| err(&e))?;
    text("scale / loss / jitter", 20, top - 24, 16).map_err(|e| err(&e))?;
    for (j, r) in cols.iter().enumerate() {
        text(&format!("{r}"), left + cell_w * j as i32 + 8, top - 24, 16).map_err(|e| err(&e))?;
    }
    for (i, row) in rows.iter().enumerate() {
        let y = top + cell_h * i as i32;
        let label = format!(
            "{} / {} / {:.0} %",
            row.force_scale,
            row.loss.name(),
            row.jitter * 100.0
        );
        text(&label, 20, y + 16, 16).map_err(|e| err(&e))?;
        for (j, r) in cols.iter().enumerate() {
            let x = left + cell_w * j as i32;
            let k = cases
                .iter()
                .position(|c| matrix::same_row(c, row) && c.rtt_ms == *r);
            let s = k.and_then(|k| sums[k].as_ref().map(|s| (k, s)));
            let v = s.map(|(k, s)| Verdict::of(&cases[k], s, l));
            root.draw(&Rectangle::new(
                [(x, y), (x + cell_w - 3, y + cell_h - 3)],
                verdict_color(v).filled(),
            ))
            .map_err(|e| err(&e))?;
            if let Some((_, s)) = s {
                text(&format!("{:.1} N", s.max_force_n), x + 6, y + 6, 15).map_err(|e| err(&e))?;
                text(&format!("r {:.2}", s.hold_ripple_rms_n), x + 6, y + 26, 15)
                    .map_err(|e| err(&e))?;
            }
        }
    }
    let ly = top + cell_h * rows.len() as i32 + 20;
    text("cell: true force max, N; r: hold ripple, N RMS", 20, ly, 15).map_err(|e| err(&e))?;
    let mut x = 20;
    for (v, word) in [
        (Some(Verdict::Met), "every target met"),
        (Some(Verdict::Missed), "stable, a target missed"),
        (Some(Verdict::Unstable), "unstable"),
        (Some(Verdict::Unsafe), "a guarantee broken"),
        (None, "not run"),
    ] {
        root.draw(&Rectangle::new(
            [(x, ly + 30), (x + 22, ly + 50)],
            verdict_color(v).filled(),
        ))
        .map_err(|e| err(&e))?;
        text(word, x + 28, ly + 32, 15).map_err(|e| err(&e))?;
        x += 36 + 8 * word.len() as i32;
    }
    root.present().map_err(|e| err(&e))
}
