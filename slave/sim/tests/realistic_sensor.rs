//! Issue 13: the force loop with a real sensor. The sensor reads the tool's weight and
//! inertia in its own frame, with 0.1 or 0.3 N σ of noise and a drifting bias; commands act
//! one period after the reading they came from; the plant's stiffness is 30 % below and
//! above what the controller assumes; and every other value the controller holds about the
//! plant (platform mass, tool mass and centre of mass, sensor filter, initial environment
//! stiffness) is off by up to ±30 % (a fixed set of combinations and eight random ones by
//! seed). Every figure comes from a run of the simulated arm; nothing is hard-coded.
#![allow(clippy::unwrap_used, clippy::expect_used)]
// `!(x <= limit)` on purpose: a NaN figure must count as a miss.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::path::PathBuf;

use h4_shared::config;
use h4_shared::kinematics::Pose;
use h4_shared::rng::Rng;
use h4_slave_sim::experiment::{self, ExperimentConfig, Summary};
use h4_slave_sim::identify::identify;

fn experiment_file(name: &str) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/experiments"
    ))
    .join(name)
}

fn load(name: &str, overrides: &[String]) -> ExperimentConfig {
    config::load(&experiment_file(name), overrides).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn run(name: &str, overrides: &[String]) -> (ExperimentConfig, Summary) {
    let cfg = load(name, overrides);
    let s = experiment::run(&cfg, None).unwrap_or_else(|e| panic!("{name}: {e}"));
    (cfg, s)
}

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

/// The targets, the verdict's own and the tracking's; every miss described.
fn misses(label: &str, cfg: &ExperimentConfig, s: &Summary) -> Vec<String> {
    let mut out: Vec<String> = s
        .verdict
        .failures
        .iter()
        .map(|f| format!("{label}: {f}"))
        .collect();
    let checks = [
        ("force_error_p99_n", s.force_error_p99_n, 1.0),
        (
            "force_error_p99_contact_n",
            s.force_error_p99_contact_n,
            1.0,
        ),
        ("overshoot_pct", s.overshoot_pct, 5.0),
        ("settling_ms", s.settling_ms, 150.0),
        ("max_force_n", s.max_force_n, cfg.controller.force_limit_n),
    ];
    for (name, v, limit) in checks {
        if !(v <= limit) {
            out.push(format!("{label}: {name} {v:.3} > {limit}"));
        }
    }
    // The motion ramps up at the tracking acceleration, then holds its speed.
    let track_s = cfg.duration_s - s.first_contact_s - cfg.track.start_delay_s;
    let v = cfg.track.speed_mm_per_s;
    let ramp_s = (v / cfg.controller.track_accel_mm_per_s2).min(track_s);
    let expected =
        v * (track_s - ramp_s) + 0.5 * cfg.controller.track_accel_mm_per_s2 * ramp_s * ramp_s;
    if !(s.tracked_distance_mm >= 0.8 * expected) {
        out.push(format!(
            "{label}: tracked {:.1} of {expected:.1} mm",
            s.tracked_distance_mm
        ));
    }
    out
}

/// The controller's values about the plant, as factors on the truth: platform mass, tool
/// mass, tool centre of mass, sensor filter cut-off, initial environment stiffness.
type Mismatch = [f64; 5];

/// The fixed combinations: all low, all high, and two alternating.
const FIXED: [Mismatch; 4] = [
    [0.7; 5],
    [1.3; 5],
    [0.7, 1.3, 0.7, 1.3, 0.7],
    [1.3, 0.7, 1.3, 0.7, 1.3],
];

/// `FIXED` plus eight random combinations (each factor uniform in 0.7–1.3) from `seed`.
fn mismatches(seed: u64) -> Vec<Mismatch> {
    let mut rng = Rng::fork(seed, 0x13);
    let mut out = FIXED.to_vec();
    for _ in 0..8 {
        let mut m = [0.0; 5];
        for f in m.iter_mut() {
            *f = 0.7 + 0.6 * rng.uniform();
        }
        out.push(m);
    }
    out
}

/// The overrides that put the controller's values `m` away from the plant's truth (the
/// defaults: platform 1.0 kg, tool 0.6 kg at [4, 0, −45] mm, 80 Hz filter, 200 N/mm).
fn mismatch_overrides(m: &Mismatch) -> Vec<String> {
    let com = [4.0 * m[2], 0.0, -45.0 * m[2]];
    vec![
        format!("controller.tool_mass_kg={}", 1.0 * m[0]),
        format!("arm.tool.mass_kg={}", 0.6 * m[1]),
        format!("arm.tool.com_mm=[{}, {}, {}]", com[0], com[1], com[2]),
        format!("controller.sensor_filter_cutoff_hz={}", 80.0 * m[3]),
        format!("controller.initial_env_stiffness_n_per_mm={}", 200.0 * m[4]),
    ]
}

/// Runs `cases` (base file, overrides) at noise 0.1 and 0.3 N, plant stiffness ×0.7 and
/// ×1.3 (with a per-actuator spread) and every mismatch of `seed`, on two threads; returns
/// every miss and the worst figures.
fn matrix(cases: &[(&str, Vec<String>)], seed: u64) -> (Vec<String>, usize, [f64; 4]) {
    let mut jobs = Vec::new();
    for (base, case) in cases {
        for noise in ["0.1", "0.3"] {
            for (scale, spread) in [
                ("0.7", "[0.1, -0.1, 0.05, -0.05]"),
                ("1.3", "[-0.1, 0.1, -0.05, 0.05]"),
            ] {
                for m in mismatches(seed) {
                    let mut o = case.clone();
                    o.push(format!("sensor.noise_std_n={noise}"));
                    o.push(format!("plant.stiffness_scale={scale}"));
                    o.push(format!("plant.stiffness_spread={spread}"));
                    o.push("plant.command_latency_s=0.001".into());
                    o.extend(mismatch_overrides(&m));
                    jobs.push((base.to_string(), o));
                }
            }
        }
    }
    let n = jobs.len();
    let results: Vec<(Vec<String>, [f64; 4])> = std::thread::scope(|scope| {
        let halves: Vec<_> = jobs
            .chunks(n.div_ceil(2).max(1))
            .map(|chunk| {
                scope.spawn(move || {
                    chunk
                        .iter()
                        .map(|(base, o)| {
                            let (cfg, s) = run(base, o);
                            let label = format!("{base} {o:?}");
                            let worst = [
                                s.force_error_p99_contact_n,
                                s.overshoot_pct,
                                s.settling_ms,
                                s.max_force_n / cfg.controller.force_limit_n,
                            ];
                            (misses(&label, &cfg, &s), worst)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        halves.into_iter().flat_map(|h| h.join().unwrap()).collect()
    });
    let mut all = Vec::new();
    let mut worst = [0.0f64; 4];
    for (m, w) in results {
        all.extend(m);
        for i in 0..4 {
            worst[i] = worst[i].max(w[i]);
        }
    }
    (all, n, worst)
}

fn paper_cases() -> Vec<(&'static str, Vec<String>)> {
    ["fig6b", "fig6c", "fig6d", "fig7b", "fig7c", "fig7d"]
        .iter()
        .map(|f| {
            let name: &'static str = Box::leak(format!("{f}.toml").into_boxed_str());
            let duration = if *f == "fig6d" {
                "duration_s=12"
            } else {
                "duration_s=8"
            };
            (name, strings(&[duration]))
        })
        .collect()
}

#[test]
fn paper_experiments_meet_targets_with_a_real_sensor_and_a_mismatched_controller() {
    let (all, n, worst) = matrix(&paper_cases(), 13);
    eprintln!(
        "{n} runs; worst p99 (contact) {:.3} N, overshoot {:.2} %, settling {} ms, force/limit {:.3}",
        worst[0], worst[1], worst[2], worst[3]
    );
    assert!(
        all.is_empty(),
        "{} of {n} missed:\n{}",
        all.len(),
        all.join("\n")
    );
}

/// The untuned surfaces (tilted planes, a cylinder, a sphere on both bases; a soft 50 N/mm
/// surface and dry friction on resin) and tracking along x at 50 mm/s.
#[test]
fn untuned_surfaces_and_fast_tracking_meet_targets_with_a_real_sensor() {
    let mut cases: Vec<(&str, Vec<String>)> = Vec::new();
    let surfaces: [&[&str]; 4] = [
        &["surface.tilt_deg=20"],
        &["surface.tilt_deg=-15", "surface.material=steel"],
        &["surface.shape=cylinder", "surface.radius_mm=100"],
        &["surface.shape=sphere", "surface.radius_mm=100"],
    ];
    for base in ["fig6b.toml", "fig7d.toml"] {
        for s in surfaces {
            let mut o = strings(s);
            o.push("duration_s=6".into());
            cases.push((base, o));
        }
    }
    for s in [
        &["surface.stiffness_n_per_mm=50"][..],
        &["surface.friction_coefficient=0.3"][..],
    ] {
        let mut o = strings(s);
        o.push("duration_s=6".into());
        cases.push(("fig6b.toml", o));
    }
    cases.push((
        "fig7d.toml",
        strings(&[
            "surface.contact_point_mm=[-100.0, 0.0, -250.0]",
            "track.speed_mm_per_s=50",
            "controller.track_accel_mm_per_s2=100",
            "duration_s=5",
        ]),
    ));
    let (all, n, worst) = matrix(&cases, 31);
    eprintln!(
        "{n} runs; worst p99 (contact) {:.3} N, overshoot {:.2} %, settling {} ms, force/limit {:.3}",
        worst[0], worst[1], worst[2], worst[3]
    );
    assert!(
        all.is_empty(),
        "{} of {n} missed:\n{}",
        all.len(),
        all.join("\n")
    );
}

/// On aluminium at 40 N: dry friction μ = 0.3 meets every target in all 48 runs since the
/// contact-normal estimate takes the arm's deflection change (Λ ΔF) off the motion it reads
/// (2026-12-03; before, 38 of 48 missed the whole-contact p99, up to 1.85 N): asserted.
/// Known limits (measured, not met; docs/slave-results.md): a 50 N/mm surface (2 of 48 runs,
/// 1.09 N) and tracking along y at 20 mm/s (20 of 48 runs, up to 1.27 N) miss the
/// whole-contact p99 (the normal estimate, tilted by friction at the touch: told the true
/// normal, y tracking meets it). Asserted for all: the true force stays under the limit and
/// the first touch keeps its overshoot and settling targets.
#[test]
fn aluminium_friction_soft_and_fast_y_tracking_known_limits() {
    let cases: Vec<(&str, Vec<String>)> = vec![
        (
            "fig7d.toml",
            strings(&["surface.friction_coefficient=0.3", "duration_s=6"]),
        ),
        (
            "fig7d.toml",
            strings(&["surface.stiffness_n_per_mm=50", "duration_s=6"]),
        ),
        (
            "fig7d.toml",
            strings(&[
                "track.direction=[0.0, 1.0, 0.0]",
                "surface.contact_point_mm=[0.0, -30.0, -250.0]",
                "track.speed_mm_per_s=20",
                "controller.track_accel_mm_per_s2=50",
                "duration_s=6",
            ]),
        ),
    ];
    let (all, n, worst) = matrix(&cases, 31);
    eprintln!(
        "known limits: {} misses in {n} runs; worst p99 (contact) {:.3} N, overshoot {:.2} %, settling {} ms, force/limit {:.3}",
        all.len(),
        worst[0],
        worst[1],
        worst[2],
        worst[3]
    );
    assert!(
        worst[3] <= 1.0,
        "true force above the limit: {:.3} × the limit",
        worst[3]
    );
    assert!(
        worst[1] <= 5.0 && worst[2] <= 150.0,
        "first touch: {worst:?}"
    );
    let friction: Vec<&String> = all
        .iter()
        .filter(|m| m.contains("friction_coefficient=0.3"))
        .collect();
    assert!(friction.is_empty(), "μ = 0.3 missed:\n{friction:?}");
}

/// Negative control of the gravity compensation: the tool turns 20° while approaching
/// (the sensor was tared at 0°), so its weight shows differently in the sensor's frame.
/// With the identified tool compensated the targets hold; with the compensation off the
/// weight's change reads as contact force and the error shows it.
#[test]
fn gravity_compensation_off_shows_in_the_error() {
    for base in ["fig6b.toml", "fig7c.toml"] {
        let tilt = [
            "approach.theta_rad=0.35",
            "approach.gap_mm=4",
            "sensor.noise_std_n=0.3",
            "duration_s=6",
        ];
        let (cfg, on) = run(base, &strings(&tilt));
        let m = misses(&format!("{base} on"), &cfg, &on);
        assert!(m.is_empty(), "{}", m.join("\n"));
        let mut off = strings(&tilt);
        off.push("controller.gravity_compensation=false".into());
        let (_, off) = run(base, &off);
        assert!(
            !off.verdict.passed
                && off.force_error_p99_contact_n > 3.0 * on.force_error_p99_contact_n,
            "{base}: compensation off {:?} vs on {:?}",
            off.verdict,
            on.force_error_p99_contact_n
        );
    }
}

/// Negative control of the read-to-command latency model: with 10 ms between the sensor
/// sample and the command it causes (a slow fieldbus), the controller told the latency (and
/// told it 30 % short: 7 cycles) meets the targets; the same controller assuming no latency
/// misses them (its force loop acts on a force that is no longer there).
#[test]
fn latency_model_off_shows_in_the_error() {
    for base in ["fig6b.toml", "fig7c.toml"] {
        let common = ["plant.command_latency_s=0.010", "duration_s=8"];
        let with = |cycles: u32| {
            let mut o = strings(&common);
            o.push(format!("controller.command_latency_cycles={cycles}"));
            run(base, &o)
        };
        for told in [10, 7] {
            let (cfg, on) = with(told);
            let m = misses(&format!("{base} told {told} cycles"), &cfg, &on);
            assert!(m.is_empty(), "{}", m.join("\n"));
        }
        let (_, on) = with(10);
        let (_, off) = with(0);
        assert!(
            !off.verdict.passed
                && off.force_error_p99_contact_n > 2.0 * on.force_error_p99_contact_n,
            "{base}: latency unmodelled {:?} p99 {} vs modelled p99 {}",
            off.verdict,
            off.force_error_p99_contact_n,
            on.force_error_p99_contact_n
        );
    }
}

/// No false contact in free space at 0.3 N σ: eight seeds hold the tool 1 mm above the
/// surface (the approach's target) for 5 s; each run says it never touched and why. And no
/// late detection on steel: the controller's touch comes within 5 ms of the first
/// micronewton of true contact (one period of latency, the sensor filter's ≈ 3 ms delay).
#[test]
fn contact_detection_is_not_fooled_by_noise() {
    for seed in 1..=8 {
        let seed_set = format!("seed={seed}");
        let (_, s) = run(
            "fig7c.toml",
            &strings(&[
                "sensor.noise_std_n=0.3",
                "approach.target_depth_mm=-1",
                "duration_s=5",
                &seed_set,
            ]),
        );
        assert!(
            !s.contact_reached && !s.verdict.passed,
            "seed {seed}: {:?}",
            s.verdict
        );
        let why = s.verdict.failures.join("; ");
        assert!(
            why.contains("never touched the surface: the approach reached its target"),
            "seed {seed}: {why}"
        );
        let (_, steel) = run(
            "fig7c.toml",
            &strings(&["sensor.noise_std_n=0.3", "duration_s=3", &seed_set]),
        );
        assert!(steel.verdict.passed, "seed {seed}: {:?}", steel.verdict);
        assert!(
            steel.contact_detection_delay_ms <= 5.0,
            "seed {seed}: detected {} ms late",
            steel.contact_detection_delay_ms
        );
    }
}

/// `identify` recovers the tool and the bias at 0.3 N σ for tools it was not built around.
#[test]
fn identify_recovers_mass_centre_of_mass_and_bias_at_0_3_n_noise() {
    let tools = [
        (0.6, [4.0, 0.0, -45.0]),
        (1.2, [-12.0, 0.0, -80.0]),
        (0.3, [20.0, 0.0, -30.0]),
    ];
    for (seed, (mass, com)) in tools.iter().enumerate() {
        let mut cfg = load("fig6b.toml", &strings(&["sensor.noise_std_n=0.3"]));
        cfg.seed = 100 + seed as u64;
        cfg.plant.payload_mass_kg = *mass;
        cfg.plant.payload_com_mm = *com;
        cfg.sensor.bias_n = [0.8, -0.5, 1.1];
        let p = cfg.surface.contact_point_mm;
        let start = Pose::new(p[0], p[1], p[2] + 30.0, 0.0);
        let (mut sim, _) = cfg.world().build(start, cfg.seed).unwrap();
        let ws = cfg.arm.workspace();
        let id = identify(&mut sim, &ws, start, [0.0, 0.0, -9810.0], 1e-3, |a| {
            a.advance(1_000_000)
        })
        .unwrap();
        let t = id.tool;
        assert!(
            (t.mass_kg - mass).abs() <= 0.03 * mass + 0.005,
            "mass {} vs {mass}",
            t.mass_kg
        );
        for i in [0, 2] {
            assert!(
                (t.com_mm[i] - com[i]).abs() <= 3.0,
                "com {:?} vs {com:?}",
                t.com_mm
            );
        }
        for i in 0..3 {
            assert!(
                (t.sensor_bias_n[i] - cfg.sensor.bias_n[i]).abs() <= 0.15,
                "bias {:?}",
                t.sensor_bias_n
            );
        }
    }
}

/// Known limit (measured, not a target met): on a very soft surface (5 N/mm) the contact
/// mode is the arm's own, lightly damped one near the sensor filter's cut-off; with the
/// payload's inertia on the sensor and one period of latency, the first touch settles in
/// more than 150 ms (resin base 205–243 ms at 0.1–0.3 N σ) and the aluminium base at 40 N
/// rings at ≥ 0.2 N σ (diagnosis in docs/slave-results.md: the oscillation guard reads the
/// payload's inertia on the arm's mode as oscillation, and the force limit's back-off puts
/// ≈ 90 N of inertia on the sensor). What still holds, asserted: the true force stays under
/// the limit.
#[test]
fn very_soft_surface_with_a_real_sensor_known_limit() {
    for base in ["fig6b.toml", "fig7d.toml"] {
        for noise in ["0.1", "0.3"] {
            let o = strings(&[
                "surface.stiffness_n_per_mm=5",
                &format!("sensor.noise_std_n={noise}"),
                "duration_s=8",
            ]);
            let (cfg, s) = run(base, &o);
            eprintln!(
                "{base} 5 N/mm σ {noise}: p99 {:.2} N, overshoot {:.1} %, settling {} ms, max {:.1} N",
                s.force_error_p99_contact_n, s.overshoot_pct, s.settling_ms, s.max_force_n
            );
            assert!(
                s.max_force_n <= cfg.controller.force_limit_n,
                "{base} σ {noise}: {:.1} N",
                s.max_force_n
            );
        }
    }
}
