//! The simulated session's link in its recording and its report: `/master/cycle` carries the
//! round trip the master measured each cycle (`round_trip_us`), read back from the MCAP it
//! matches the configured delay, and `report` draws the link (round trip and losses) for every
//! session recording, a link that neither delays nor loses included.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use h4_master_sim::session::{self, Summary};
use h4_slave_sim::report::{ReportOptions, report};
use h4_telemetry::recording::Recorder;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("h4-session-report-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Records `wall-push.toml` with `overrides` into `dir/session.mcap`.
fn record(dir: &Path, overrides: &[&str]) -> (PathBuf, Summary) {
    let file = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/wall-push.toml");
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let cfg = session::load(&file, &o).unwrap();
    let path = dir.join("session.mcap");
    let mut rec = Recorder::create(&path).unwrap();
    let summary = session::run(&cfg, Some(&mut rec)).unwrap();
    rec.finish().unwrap();
    (path, summary)
}

/// `(log time s, round_trip_us)` of every `/master/cycle` message (None: null), and the
/// schema of the channel.
fn round_trips(path: &Path) -> (Vec<(f64, Option<f64>)>, serde_json::Value) {
    let bytes = std::fs::read(path).unwrap();
    let mut out = Vec::new();
    let mut schema = serde_json::Value::Null;
    for msg in mcap::MessageStream::new(&bytes).unwrap() {
        let msg = msg.unwrap();
        if msg.channel.topic != "/master/cycle" {
            continue;
        }
        if schema.is_null() {
            let s = msg.channel.schema.as_ref().unwrap();
            assert_eq!(s.name, "h4.MasterCycle");
            schema = serde_json::from_slice(&s.data).unwrap();
        }
        let v: serde_json::Value = serde_json::from_slice(&msg.data).unwrap();
        let r = &v["round_trip_us"];
        assert!(
            r.is_null() || r.is_f64(),
            "round_trip_us is neither a number nor null: {v}"
        );
        out.push((msg.log_time as f64 * 1e-9, r.as_f64()));
    }
    (out, schema)
}

fn report_of(rec: &Path, dir: &Path) -> (Vec<String>, serde_json::Value) {
    let out_dir = dir.join("report");
    let out = report(
        rec,
        &ReportOptions {
            out_dir: out_dir.clone(),
            tolerance_n: 1.0,
            part_dir: None,
        },
    )
    .unwrap();
    for f in &out.figures {
        let png = std::fs::read(out_dir.join(f)).unwrap();
        assert!(
            png.len() > 10_000 && png.starts_with(b"\x89PNG\r\n\x1a\n"),
            "{f} is not a drawn PNG"
        );
    }
    let metrics =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("metrics.json")).unwrap())
            .unwrap();
    (out.figures, metrics)
}

/// 50 ms one way in each direction: from the first echo on, every cycle's round trip is the
/// two delays plus the one-cycle phase of the lockstep (the slave answers a command in the
/// cycle it arrives, the master reads the answer one cycle later), within two cycles; and the
/// report draws it.
#[test]
fn a_delayed_session_records_its_round_trip_and_reports_the_link() {
    let dir = tmp("delay50");
    let (rec, summary) = record(&dir, &["duration_s=3", "link.delay_ms=50"]);
    let (rtt, schema) = round_trips(&rec);
    assert_eq!(rtt.len(), 3000);
    // The schema declares the field, a number or null, not required (null before the first
    // echo).
    let decl = &schema["properties"]["round_trip_us"];
    assert!(
        decl["type"].as_array().is_some_and(|t| {
            t.contains(&serde_json::json!("number")) && t.contains(&serde_json::json!("null"))
        }),
        "{decl}"
    );
    assert!(decl["description"].as_str().unwrap().contains("µs"));
    // No round trip before a command has gone and its echo come back (≈ 100 ms), then one
    // every cycle.
    let first = rtt.iter().position(|r| r.1.is_some()).unwrap();
    assert!(
        (99..=104).contains(&first),
        "first round trip at cycle {first}"
    );
    assert!(rtt[first..].iter().all(|r| r.1.is_some()));
    let expected_us = 2.0 * 50_000.0 + 1_000.0;
    for (t, r) in &rtt[first..] {
        let r = r.unwrap();
        assert!(
            (r - expected_us).abs() <= 2_000.0,
            "round trip {r} µs at {t} s, expected {expected_us} ± 2000"
        );
    }
    // The per-cycle figure is the summary's: their means agree.
    let n = (rtt.len() - first) as f64;
    let mean_ms = rtt[first..].iter().map(|r| r.1.unwrap()).sum::<f64>() / n * 1e-3;
    assert!(
        (mean_ms - summary.rtt_mean_ms).abs() < 1.0,
        "{mean_ms} vs {}",
        summary.rtt_mean_ms
    );

    let (figures, m) = report_of(&rec, &dir);
    assert!(figures.contains(&"link.png".to_string()), "{figures:?}");
    let p50 = m["round_trip_p50_ms"].as_f64().unwrap();
    let p99 = m["round_trip_p99_ms"].as_f64().unwrap();
    assert!((p50 - 101.0).abs() <= 2.0, "p50 {p50} ms");
    assert!((p99 - 101.0).abs() <= 2.0, "p99 {p99} ms");
    // A link that loses nothing shows zero losses (the event channel is declared, empty).
    assert_eq!(m["messages_lost"], 0);
}

/// No delay, no loss: the link figure is still drawn, the round trip flat at one cycle.
/// With loss, the report's counts are the link's own.
#[test]
fn every_session_gets_a_link_figure() {
    let dir = tmp("delay0");
    let (rec, summary) = record(&dir, &["duration_s=2"]);
    let (rtt, _) = round_trips(&rec);
    let first = rtt.iter().position(|r| r.1.is_some()).unwrap();
    assert!(first <= 3, "first round trip at cycle {first}");
    assert!(rtt[first..].iter().all(|r| r.1 == Some(1_000.0)));
    assert_eq!(summary.packets_lost, 0);
    let (figures, m) = report_of(&rec, &dir);
    assert!(figures.contains(&"link.png".to_string()), "{figures:?}");
    assert_eq!(m["round_trip_p50_ms"], 1.0);
    assert_eq!(m["round_trip_max_ms"], 1.0);
    assert_eq!(m["messages_lost"], 0);

    let dir = tmp("lossy");
    let (rec, summary) = record(
        &dir,
        &["duration_s=2", "link.delay_ms=10", "link.loss=0.05"],
    );
    assert!(summary.packets_lost > 50, "{}", summary.packets_lost);
    let (figures, m) = report_of(&rec, &dir);
    assert!(figures.contains(&"link.png".to_string()), "{figures:?}");
    assert_eq!(m["messages_lost"], summary.packets_lost);
    assert_eq!(
        m["commands_lost"].as_u64().unwrap() + m["feedback_lost"].as_u64().unwrap(),
        summary.packets_lost
    );
    assert!(m["commands_lost"].as_u64().unwrap() > 0);
    assert!(m["feedback_lost"].as_u64().unwrap() > 0);
}
