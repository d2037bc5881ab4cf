//! `report`: figures, metrics and the HTML page from an experiment's recording; a recording cut
//! short (a killed process) still gives a report that says so; a file that is not a recording
//! is a clear error.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use h4_slave_sim::experiment::{self, ExperimentConfig};
use h4_slave_sim::report::{ReportOptions, report};
use h4_telemetry::recording::Recorder;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("h4-report-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn record_experiment(dir: &Path) -> (PathBuf, experiment::Summary) {
    let file =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../config/experiments/fig6d.toml");
    let cfg: ExperimentConfig =
        h4_shared::config::load(&file, &["duration_s=13".to_string()]).unwrap();
    let path = dir.join("fig6d.mcap");
    let mut rec = Recorder::create(&path).unwrap();
    let summary = experiment::run(&cfg, Some(&mut rec)).unwrap();
    rec.finish().unwrap();
    (path, summary)
}

fn is_png(path: &Path) -> bool {
    std::fs::read(path).is_ok_and(|b| b.len() > 10_000 && b.starts_with(b"\x89PNG\r\n\x1a\n"))
}

#[test]
fn an_experiment_gives_its_figures_and_metrics() {
    let dir = tmp("experiment");
    let (rec, summary) = record_experiment(&dir);
    let out_dir = dir.join("report");
    let out = report(
        &rec,
        &ReportOptions {
            out_dir: out_dir.clone(),
            tolerance_n: 1.0,
            part_dir: None,
        },
    )
    .unwrap();
    assert_eq!(
        out.figures,
        ["force.png", "force_along_path.png", "tracking_error.png"]
    );
    for f in &out.figures {
        assert!(is_png(&out_dir.join(f)), "{f} is not a drawn PNG");
    }
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("metrics.json")).unwrap())
            .unwrap();
    // The report's figures come from the recording, the summary from the run: they agree.
    let max = m["max_force_n"].as_f64().unwrap();
    assert!(
        (max - summary.max_force_n).abs() < 0.05 * summary.max_force_n,
        "{max}"
    );
    assert!((m["first_contact_s"].as_f64().unwrap() - summary.first_contact_s).abs() < 0.05);
    // The 30 → 15 N step's transient is in the whole-contact maximum, not only the p99.
    assert!(m["force_error_max_n"].as_f64().unwrap() > 5.0);
    assert!(m["force_error_p99_n"].as_f64().unwrap() < 1.0);
    assert_eq!(m["truncated"], false);
    let html = std::fs::read_to_string(out_dir.join("index.html")).unwrap();
    for f in &out.figures {
        assert!(html.contains(&format!("src=\"{f}\"")));
    }
    assert!(html.contains("force_error_max_n"));
}

#[test]
fn a_recording_cut_short_still_reports_and_says_so() {
    let dir = tmp("truncated");
    let (rec, _) = record_experiment(&dir);
    let bytes = std::fs::read(&rec).unwrap();
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let out = report(
        &cut,
        &ReportOptions {
            out_dir: dir.join("cut-report"),
            tolerance_n: 1.0,
            part_dir: None,
        },
    )
    .unwrap();
    assert_eq!(out.metrics["truncated"], true);
    assert!(out.figures.contains(&"force.png".to_string()));
    let d = out.metrics["duration_s"].as_f64().unwrap();
    assert!(d > 1.0 && d < 12.0, "{d}");
}

#[test]
fn a_file_that_is_not_a_recording_is_an_error() {
    let dir = tmp("garbage");
    let path = dir.join("x.mcap");
    std::fs::write(&path, b"not an mcap file at all").unwrap();
    let e = report(
        &path,
        &ReportOptions {
            out_dir: dir.join("r"),
            tolerance_n: 1.0,
            part_dir: None,
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("x.mcap"), "{e}");
}
