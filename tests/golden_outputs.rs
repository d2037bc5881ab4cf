//! Refactoring guard: the shipped sessions and experiments (and a few impaired or untuned
//! variants of them) must give the same summary and the same recorded messages as the files in
//! `tests/data/golden/`, recorded before the layout change of issue 11 (commit eee42e9).
//!
//! * Summaries: the JSON text, byte for byte, without the wall-clock fields (`wall_time_s`,
//!   `speedup`).
//! * Recordings: per topic, the number of messages and an FNV-1a digest of every message's log
//!   time and payload bytes. Schemas are not part of the digest: a schema that changes its name
//!   or its declared fields, with the payloads unchanged, is a documented change, not a behaviour
//!   change.
//!
//! `H4_BLESS=1 cargo test --release -p h4-tests --test golden_outputs` rewrites the files; do
//! that only for a change whose effect on the numbers is intended and written in the commit.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use h4_master_sim::session;
use h4_slave_sim::experiment;
use h4_telemetry::recording::Recorder;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn golden_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/golden")
}

fn fnv1a(hash: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *hash ^= u64::from(*b);
        *hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
}

/// Per topic: message count and digest of (log time, payload).
fn recording_digest(bytes: &[u8]) -> BTreeMap<String, (u64, String)> {
    let mut acc: BTreeMap<String, (u64, u64)> = BTreeMap::new();
    for msg in mcap::MessageStream::new(bytes).unwrap() {
        let msg = msg.unwrap();
        let e = acc
            .entry(msg.channel.topic.clone())
            .or_insert((0, 0xcbf2_9ce4_8422_2325));
        e.0 += 1;
        fnv1a(&mut e.1, &msg.log_time.to_le_bytes());
        fnv1a(&mut e.1, &msg.data);
    }
    acc.into_iter()
        .map(|(k, (n, h))| (k, (n, format!("{h:016x}"))))
        .collect()
}

fn summary_text(summary: impl serde::Serialize) -> String {
    let mut v = serde_json::to_value(summary).unwrap();
    let o = v.as_object_mut().unwrap();
    o.remove("wall_time_s");
    o.remove("speedup");
    serde_json::to_string_pretty(&v).unwrap() + "\n"
}

fn digest_text(bytes: &[u8]) -> String {
    serde_json::to_string_pretty(&recording_digest(bytes)).unwrap() + "\n"
}

/// Compares (or, with `H4_BLESS=1`, writes) one golden file; returns a mismatch message.
fn check(name: &str, kind: &str, actual: &str) -> Option<String> {
    let path = golden_dir().join(format!("{name}.{kind}.json"));
    if std::env::var_os("H4_BLESS").is_some() {
        std::fs::create_dir_all(golden_dir()).unwrap();
        std::fs::write(&path, actual).unwrap();
        return None;
    }
    let expected = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (bless with H4_BLESS=1)", path.display()));
    if expected == actual {
        None
    } else {
        let first = expected
            .lines()
            .zip(actual.lines())
            .find(|(a, b)| a != b)
            .map(|(a, b)| format!("expected `{a}`, got `{b}`"))
            .unwrap_or_else(|| "lengths differ".to_string());
        Some(format!("{name} {kind}: {first}"))
    }
}

fn run_session(file: &str, overrides: &[&str]) -> (String, String) {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    // The bare case turns passivity (a safety layer) off: only with the override.
    let bare = overrides.contains(&"passivity.enabled=false");
    let cfg = session::load_with(&repo().join("config/sessions").join(file), &o, bare).unwrap();
    let mut rec = Recorder::in_memory().unwrap();
    let summary = session::run(&cfg, Some(&mut rec)).unwrap();
    (
        summary_text(&summary),
        digest_text(&rec.finish_into_bytes().unwrap()),
    )
}

fn run_experiment(file: &str, overrides: &[&str]) -> (String, String) {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let cfg: experiment::ExperimentConfig =
        h4_shared::config::load(&repo().join("config/experiments").join(file), &o).unwrap();
    let mut rec = Recorder::in_memory().unwrap();
    let summary = experiment::run(&cfg, Some(&mut rec)).unwrap();
    (
        summary_text(&summary),
        digest_text(&rec.finish_into_bytes().unwrap()),
    )
}

fn check_all(cases: Vec<(String, (String, String))>) {
    let mut failures = Vec::new();
    for (name, (summary, digest)) in cases {
        failures.extend(check(&name, "summary", &summary));
        failures.extend(check(&name, "recording", &digest));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn shipped_and_impaired_sessions_are_unchanged() {
    let cases: Vec<(&str, &str, Vec<&str>)> = vec![
        ("session-wall-push", "wall-push.toml", vec![]),
        ("session-cutting-guided", "cutting-guided.toml", vec![]),
        (
            "session-wall-push-aluminium-250ms-jitter-loss",
            "wall-push.toml",
            vec![
                "environment.stiffness_n_per_mm=1000",
                "link.delay_ms=125",
                "link.jitter_ms=25",
                "link.loss=0.05",
                "seed=3",
            ],
        ),
        (
            "session-wall-push-bare-50ms",
            "wall-push.toml",
            vec![
                "link.delay_ms=25",
                "passivity.enabled=false",
                "coupling.model=false",
                "duration_s=8",
            ],
        ),
    ];
    check_all(
        cases
            .into_iter()
            .map(|(name, file, o)| (name.to_string(), run_session(file, &o)))
            .collect(),
    );
}

#[test]
fn shipped_and_untuned_experiments_are_unchanged() {
    let mut cases: Vec<(String, String, Vec<&str>)> =
        ["fig6b", "fig6c", "fig6d", "fig7b", "fig7c", "fig7d"]
            .iter()
            .map(|f| (format!("experiment-{f}"), format!("{f}.toml"), vec![]))
            .collect();
    cases.push((
        "experiment-fig6b-sphere-noisy-soft-plant".into(),
        "fig6b.toml".into(),
        vec![
            "surface.shape=sphere",
            "surface.radius_mm=100",
            "sensor.noise_std_n=0.3",
            "plant.stiffness_scale=0.7",
            "duration_s=6",
        ],
    ));
    cases.push((
        "experiment-fig7c-tilted-friction".into(),
        "fig7c.toml".into(),
        vec![
            "surface.tilt_deg=15",
            "surface.friction_coefficient=0.3",
            "plant.stiffness_scale=1.3",
            "controller.compliance_model=false",
            "duration_s=6",
        ],
    ));
    check_all(
        cases
            .into_iter()
            .map(|(name, file, o)| (name.clone(), run_experiment(&file, &o)))
            .collect(),
    );
}

#[test]
fn the_digest_sees_a_changed_payload() {
    // Negative control: one changed override changes the golden text.
    let (a, ra) = run_experiment("fig6b.toml", &["duration_s=2"]);
    let (b, rb) = run_experiment("fig6b.toml", &["duration_s=2", "sensor.noise_std_n=0.11"]);
    assert_ne!(a, b);
    assert_ne!(ra, rb);
    assert!(Path::new(&golden_dir()).exists() || std::env::var_os("H4_BLESS").is_some());
}
