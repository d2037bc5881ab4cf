//! The targets on the simulated clock: the paper's six experiments and surfaces
//! nobody tuned for, with sensor noise on and the plant's actuator stiffness 30 % below and
//! above what the controller assumes. Every figure comes from a run; nothing is hard-coded.
#![allow(clippy::unwrap_used, clippy::expect_used)]
// `!(x <= limit)` on purpose: a NaN figure must count as a miss.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::path::PathBuf;

use h4_shared::config;
use h4_slave_sim::experiment::{self, ExperimentConfig, Summary};

fn experiment_file(name: &str) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/experiments"
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

/// The ideal sensor of the first landing (the README's ideal-sensor column): no payload on
/// the sensor, no weight, no read-to-command latency, no bias drift (and so nothing to
/// compensate).
const IDEAL: [&str; 7] = [
    "plant.payload_mass_kg=0",
    "plant.gravity_mm_per_s2=[0,0,0]",
    "plant.command_latency_s=0",
    "controller.command_latency_cycles=0",
    "sensor.bias_drift_n_per_sqrt_s=0",
    "sensor.bias_drift_n_mm_per_sqrt_s=0",
    "controller.gravity_compensation=false",
];

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

/// Soft (20 N/mm) and very soft (5 N/mm) surfaces on both bases, 20 s, at both plant
/// stiffnesses. Needs millimetres of travel into the surface and has the contact mode (the
/// tool between the arm's and the surface's stiffness) right at the sensor filter's
/// cut-off: what the gain schedule and the normal acceleration limit are for.
/// With the ideal sensor (no payload on it, no latency; issue 13's realistic sensor misses
/// here: slave/tests/realistic_sensor.rs, `very_soft_surface_with_a_real_sensor_known_limit`).
fn soft_surface_misses(k: &str) -> Vec<String> {
    let mut all = Vec::new();
    for base in ["fig6b.toml", "fig7d.toml"] {
        for scale in ["0.7", "1.3"] {
            let set = format!("plant.stiffness_scale={scale}");
            let stiff = format!("surface.stiffness_n_per_mm={k}");
            let (cfg, s) = run(
                base,
                &[&stiff, &set, IDEAL[0], IDEAL[1], IDEAL[2], IDEAL[3]],
            );
            all.extend(misses(&format!("{base} {k} N/mm ×{scale}"), &cfg, &s));
        }
    }
    all
}

#[test]
fn soft_surface_meets_targets() {
    let all = soft_surface_misses("20");
    assert!(all.is_empty(), "targets missed:\n{}", all.join("\n"));
}

/// Very soft (5 N/mm): 6–8 mm of travel into the surface, and the contact mode is the
/// arm's own, lightly damped one, right at the sensor filter's cut-off. What made it settle
/// within 150 ms: contact detected from a sustained force at half the threshold, the
/// environment's compliance measured during the approach, and the motion into the surface
/// shaped (ZVD) at the contact mode (docs/slave-results.md).
#[test]
fn very_soft_surface_meets_targets() {
    let all = soft_surface_misses("5");
    assert!(all.is_empty(), "targets missed:\n{}", all.join("\n"));
}

/// Soft surfaces with dry friction (5 N/mm, μ = 0.3) miss the accuracy targets (a known
/// limit, docs/slave-results.md), but the force limit holds: the friction-tilted normal
/// estimate let the true force drift past it over seconds (89–90 N on the resin base at
/// ×0.7 with these seeds) until the force-guided loop also checked the measured force's
/// magnitude.
#[test]
fn soft_surface_with_dry_friction_keeps_the_force_limit() {
    let mut all = Vec::new();
    for seed in ["2", "3"] {
        for base in ["fig6b.toml", "fig7d.toml"] {
            for scale in ["0.7", "1.3"] {
                let set = format!("plant.stiffness_scale={scale}");
                let seed_set = format!("seed={seed}");
                let (cfg, s) = run(
                    base,
                    &[
                        "surface.stiffness_n_per_mm=5",
                        "surface.friction_coefficient=0.3",
                        &set,
                        &seed_set,
                    ],
                );
                if !(s.max_force_n <= cfg.controller.force_limit_n) {
                    all.push(format!(
                        "{base} seed {seed} ×{scale}: true force {:.1} N above {} N",
                        s.max_force_n, cfg.controller.force_limit_n
                    ));
                }
            }
        }
    }
    assert!(all.is_empty(), "force limit exceeded:\n{}", all.join("\n"));
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

/// The force guard keeps the *true* force under the limit when the force loop itself is far
/// too hot (proportional gain 10× the default; on the softer arm, ×0.7, the integral gain
/// doubled as well, without which that arm barely rings), at both plant stiffnesses and over
/// eight seeds. The loop's other protections are mistuned so they let the hot gains through:
/// the tool mass is told 100× too light (the gain schedule then sees the contact mode far
/// above the sensor filter and keeps kp) and the normal acceleration limit is out of the
/// way. Negative control: the same runs with the limit out of the way (500 N) go well past
/// the 80 N limit, above 1.5× it in every one (measured 2026-12-02: 122–157 N at ×0.7,
/// 193–221 N at ×1.3; guarded 31–45 N and 67–78 N), so the scenario does threaten the limit
/// and the guard is what holds it. Until then the control asserted only 1.05× (the ×0.7
/// runs with kp alone peak at 85–129 N unguarded). Not a proof for every mistuning: a
/// hotter loop defeats it (kp 4 at ×0.7: guarded peaks 83–128 N; ki doubled at ×1.3: up
/// to 89 N; docs/slave-results.md, "Known limits").
const HOT_KP: &str = "controller.kp=3";
const HOT_MASS: &str = "controller.tool_mass_kg=0.01";
const HOT_ACCEL: &str = "controller.force_accel_mm_per_s2=1e6";

#[test]
fn force_guard_holds_the_limit_on_the_true_force_with_a_hot_loop() {
    for (scale, hot_ki) in [
        ("0.7", "controller.ki_per_s=160"),
        ("1.3", "controller.ki_per_s=80"),
    ] {
        for seed in 1..=8 {
            let set = format!("plant.stiffness_scale={scale}");
            let seed_set = format!("seed={seed}");
            // On the ideal sensor: with issue 13's (payload on the sensor, latency) the
            // unguarded hot loop no longer rings past the limit (30 N at ×0.7, seed 1),
            // and the control would prove nothing.
            let hot = [
                HOT_KP,
                hot_ki,
                HOT_MASS,
                HOT_ACCEL,
                "duration_s=6",
                &set,
                &seed_set,
                IDEAL[0],
                IDEAL[1],
                IDEAL[2],
                IDEAL[3],
            ];
            let (cfg, guarded) = run("fig7c.toml", &hot);
            let limit_n = cfg.controller.force_limit_n;
            assert!(
                guarded.max_force_n <= limit_n,
                "×{scale} seed {seed} guarded: {:.1} N > {limit_n} N",
                guarded.max_force_n,
            );
            let mut unguarded_set = hot.to_vec();
            unguarded_set.push("controller.force_limit_n=500");
            let (_, unguarded) = run("fig7c.toml", &unguarded_set);
            assert!(
                unguarded.max_force_n > 1.5 * limit_n,
                "×{scale} seed {seed}: the hot loop does not threaten the limit: {:.1} N",
                unguarded.max_force_n
            );
        }
    }
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
