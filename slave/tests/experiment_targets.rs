//! The targets on the simulated clock: the paper's six experiments and surfaces
//! nobody tuned for, with sensor noise on and the plant's actuator stiffness 30 % below and
//! above what the controller assumes. Every figure comes from a run; nothing is hard-coded.
#![allow(clippy::unwrap_used, clippy::expect_used)]
// `!(x <= limit)` on purpose: a NaN figure must count as a miss.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::path::PathBuf;

use h4_shared::config;
use h4_slave::experiment::{self, ExperimentConfig, Summary};

fn experiment_file(name: &str) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/experiments"
    ))
    .join(name)
}

fn run(name: &str, overrides: &[&str]) -> (ExperimentConfig, Summary) {
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let cfg: ExperimentConfig =
        config::load(&experiment_file(name), &overrides).unwrap_or_else(|e| panic!("{name}: {e}"));
    let summary = experiment::run(&cfg, None).unwrap_or_else(|e| panic!("{name}: {e}"));
    (cfg, summary)
}

/// Checks the targets; returns a description of every miss.
fn misses(label: &str, cfg: &ExperimentConfig, s: &Summary) -> Vec<String> {
    let mut out = Vec::new();
    assert!(cfg.sensor.noise_std_n > 0.0, "{label}: noise must be on");
    if !(s.force_error_p99_n <= 1.0) {
        out.push(format!(
            "{label}: force_error_p99_n {:.3} > 1.0",
            s.force_error_p99_n
        ));
    }
    if !(s.overshoot_pct <= 5.0) {
        out.push(format!("{label}: overshoot_pct {:.2} > 5", s.overshoot_pct));
    }
    if !(s.settling_ms <= 150.0) {
        out.push(format!("{label}: settling_ms {} > 150", s.settling_ms));
    }
    if s.contact_lost_ms > 0.0 {
        out.push(format!(
            "{label}: contact lost for {} ms",
            s.contact_lost_ms
        ));
    }
    if !(s.max_force_n <= cfg.controller.force_limit_n) {
        out.push(format!(
            "{label}: true force {:.1} N above the force limit {} N",
            s.max_force_n, cfg.controller.force_limit_n
        ));
    }
    if s.rejected_cycles > 0 {
        out.push(format!("{label}: {} rejected cycles", s.rejected_cycles));
    }
    // The tracking really happened: at least 80 % of speed × tracking time.
    let track_s = cfg.duration_s - s.first_contact_s - cfg.track.start_delay_s;
    let expected = cfg.track.speed_mm_per_s * track_s;
    if !(s.tracked_distance_mm >= 0.8 * expected) {
        out.push(format!(
            "{label}: tracked {:.1} mm of the expected {expected:.1} mm",
            s.tracked_distance_mm
        ));
    }
    out
}

const PAPER: [&str; 6] = [
    "fig6b.toml",
    "fig6c.toml",
    "fig6d.toml",
    "fig7b.toml",
    "fig7c.toml",
    "fig7d.toml",
];

#[test]
fn paper_experiments_meet_targets_with_stiffness_30_percent_off() {
    let mut all = Vec::new();
    for name in PAPER {
        for scale in ["0.7", "1.3"] {
            let set = format!("plant.stiffness_scale={scale}");
            let (cfg, s) = run(name, &[&set]);
            all.extend(misses(&format!("{name} ×{scale}"), &cfg, &s));
        }
    }
    assert!(all.is_empty(), "targets missed:\n{}", all.join("\n"));
}

#[test]
fn untuned_planes_cylinders_spheres_stiff_soft_and_dry_surfaces_meet_targets() {
    let cases: [&[&str]; 7] = [
        &["surface.tilt_deg=20"],
        &["surface.tilt_deg=-20"],
        &["surface.shape=cylinder", "surface.radius_mm=100"],
        &["surface.shape=sphere", "surface.radius_mm=100"],
        &["surface.stiffness_n_per_mm=2000"],
        &["surface.stiffness_n_per_mm=50"],
        &["surface.friction_coefficient=0.3"],
    ];
    let mut all = Vec::new();
    for base in ["fig6b.toml", "fig7d.toml"] {
        for case in cases {
            for scale in ["0.7", "1.3"] {
                let set = format!("plant.stiffness_scale={scale}");
                let mut overrides = case.to_vec();
                overrides.push(&set);
                overrides.push("duration_s=8");
                let (cfg, s) = run(base, &overrides);
                all.extend(misses(&format!("{base} {case:?} ×{scale}"), &cfg, &s));
            }
        }
    }
    assert!(all.is_empty(), "targets missed:\n{}", all.join("\n"));
}

/// Known miss, kept visible: on 20 and 5 N/mm surfaces the loop is stable and the force
/// limit holds, but the first contact settles too slowly (20 N/mm on resin's base: 160–180
/// ms against 150) and 5 N/mm misses overshoot and p99 (see docs/slave-results.md, "Known
/// limits"). Run with `cargo test -- --ignored`.
#[test]
#[ignore = "known miss: 5–20 N/mm surfaces (docs/slave-results.md)"]
fn very_soft_surface_meets_targets() {
    let mut all = Vec::new();
    for base in ["fig6b.toml", "fig7d.toml"] {
        for k in ["20", "5"] {
            for scale in ["0.7", "1.3"] {
                let set = format!("plant.stiffness_scale={scale}");
                let stiff = format!("surface.stiffness_n_per_mm={k}");
                let (cfg, s) = run(base, &[&stiff, &set]);
                all.extend(misses(&format!("{base} {k} N/mm ×{scale}"), &cfg, &s));
            }
        }
    }
    assert!(all.is_empty(), "targets missed:\n{}", all.join("\n"));
}

/// Tracking along y at 10 mm/s on aluminium, off the arm's centre line (y from −30 to
/// ≈ 150 mm), where Λ couples y and z: this run used to go unstable (true force up to
/// ≈ 200 N, above the force limit; see docs/slave-results.md for what fixed it).
#[test]
fn tracking_along_y_on_aluminium_meets_targets() {
    let mut all = Vec::new();
    for scale in ["0.7", "1.3"] {
        let set = format!("plant.stiffness_scale={scale}");
        let (cfg, s) = run(
            "fig7d.toml",
            &[
                "track.direction=[0.0, 1.0, 0.0]",
                "surface.contact_point_mm=[0.0, -30.0, -250.0]",
                &set,
            ],
        );
        all.extend(misses(&format!("y tracking ×{scale}"), &cfg, &s));
    }
    assert!(all.is_empty(), "targets missed:\n{}", all.join("\n"));
}

/// The force guard keeps the *true* force under the limit even when the force loop itself
/// is far too hot (proportional gain 10× the default: the loop rings and bounces on steel).
/// Negative control: the same run with the limit out of the way (500 N) peaks far above
/// 80 N, so the scenario does threaten the limit and the guard is what holds it.
#[test]
fn force_guard_holds_the_limit_on_the_true_force_with_a_hot_loop() {
    let (cfg, guarded) = run("fig7c.toml", &["controller.kp=3", "duration_s=6"]);
    assert!(
        guarded.max_force_n <= cfg.controller.force_limit_n,
        "guarded: {:.1} N > {} N",
        guarded.max_force_n,
        cfg.controller.force_limit_n
    );
    let (_, unguarded) = run(
        "fig7c.toml",
        &[
            "controller.kp=3",
            "duration_s=6",
            "controller.force_limit_n=500",
        ],
    );
    assert!(
        unguarded.max_force_n > 120.0,
        "the hot loop does not threaten the limit: {:.1} N",
        unguarded.max_force_n
    );
}

/// The targets are not met by accident: a controller whose compliance is badly wrong (no
/// arm model, estimator off, environment assumed 3 N/mm on steel) or whose loop is far too
/// slow visibly misses them, so the checks above can fail.
#[test]
fn a_badly_tuned_controller_misses_the_targets() {
    let (cfg, s) = run(
        "fig7c.toml",
        &[
            "controller.compliance_model=false",
            "controller.estimate_env_stiffness=false",
            "controller.initial_env_stiffness_n_per_mm=3",
            "duration_s=6",
        ],
    );
    assert!(!misses("hot", &cfg, &s).is_empty(), "{s:?}");
    let (cfg, s) = run(
        "fig6b.toml",
        &[
            "controller.ki_per_s=2",
            "controller.feedforward_gain=0.2",
            "duration_s=6",
        ],
    );
    assert!(!misses("sluggish", &cfg, &s).is_empty(), "{s:?}");
}
