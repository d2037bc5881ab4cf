//! The same seed gives the same summary and a byte-identical MCAP recording; another seed
//! does not. The recording holds the per-cycle channels Foxglove plots.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_shared::config;
use h4_slave_sim::experiment::{self, ExperimentConfig};
use h4_telemetry::recording::Recorder;

fn cfg(overrides: &[&str]) -> ExperimentConfig {
    let path = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/experiments/fig6d.toml"
    ));
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    config::load(&path, &overrides).unwrap()
}

fn run(cfg: &ExperimentConfig) -> (serde_json::Value, Vec<u8>) {
    let mut rec = Recorder::in_memory().unwrap();
    let summary = experiment::run(cfg, Some(&mut rec)).unwrap();
    let mut json = serde_json::to_value(&summary).unwrap();
    // The two wall-clock fields are the only ones allowed to differ.
    let obj = json.as_object_mut().unwrap();
    assert!(obj.remove("wall_time_s").is_some());
    assert!(obj.remove("speedup").is_some());
    (json, rec.finish_into_bytes().unwrap())
}

#[test]
fn same_seed_same_summary_and_bytes() {
    let c = cfg(&[
        "duration_s=3",
        "force.steps=[{ time_s = 1.5, setpoint_n = 15.0 }]",
    ]);
    let (a_json, a_bytes) = run(&c);
    let (b_json, b_bytes) = run(&c);
    assert_eq!(a_json, b_json);
    assert!(a_bytes == b_bytes, "recordings differ");
    assert!(a_bytes.len() > 100_000, "{}", a_bytes.len());

    let other = cfg(&[
        "duration_s=3",
        "force.steps=[{ time_s = 1.5, setpoint_n = 15.0 }]",
        "seed=99",
    ]);
    let (c_json, c_bytes) = run(&other);
    assert_ne!(
        a_json, c_json,
        "a different seed must change the noise and the summary"
    );
    assert!(a_bytes != c_bytes);
}

#[test]
fn recording_has_the_plotted_channels_every_cycle() {
    let c = cfg(&["duration_s=2", "force.steps=[]"]);
    let (_, bytes) = run(&c);
    let mut counts = std::collections::BTreeMap::new();
    let mut last_force = None;
    let mut times = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        assert_eq!(m.channel.message_encoding, "json");
        let schema = m.channel.schema.as_ref().unwrap();
        assert_eq!(schema.encoding, "jsonschema");
        serde_json::from_slice::<serde_json::Value>(&schema.data).unwrap();
        *counts.entry(m.channel.topic.clone()).or_insert(0) += 1;
        if m.channel.topic == "/slave/force" {
            times.push(m.log_time);
            last_force = Some(serde_json::from_slice::<serde_json::Value>(&m.data).unwrap());
        }
    }
    for topic in ["/slave/force", "/slave/pose", "/slave/contact"] {
        assert_eq!(counts.get(topic), Some(&2000), "{topic}: {counts:?}");
    }
    // Stamped by the simulated clock, 1 ms apart.
    assert_eq!(times[0], 1_000_000);
    assert!(times.windows(2).all(|w| w[1] - w[0] == 1_000_000));
    let f = last_force.unwrap();
    for key in [
        "fn_measured_n",
        "fn_true_n",
        "fn_desired_n",
        "wrench_measured",
        "wrench_desired",
    ] {
        assert!(f.get(key).is_some(), "{key} missing in {f}");
    }
    assert!(
        (f["fn_desired_n"].as_f64().unwrap() - 30.0).abs() < 0.5,
        "{f}"
    );
}
