//! Cutting in the real processes: `h4-master loopback --config config/sessions/cut-pocket.toml
//! --out DIR --record FILE` runs the slave's 1 kHz loop over a cutting world (the session's
//! `[cutting]`, `[fixtures]`, `cut_target` and controller keys passed on in its world file)
//! and the operator's script on the master, over iceoryx2, for the whole session (51.5 s).
//! The slave cuts the pocket to the targets in real time as the simulation does
//! (surface error p99 ≤ 0.2 mm against the target, gouge ≤ 0.05 mm below the floor), the true
//! force stays within the slave's limit, and at the end the slave judges and writes the part:
//! the summary's cutting fields (at the top level as the simulation's, and in `slave`), a PNG
//! height map, the deviation map, and a closed binary STL whose enclosed volume is the block's
//! less what was removed; the merged recording carries `/slave/cut` (the cutting force, the
//! tool in the workpiece frame, the turntable) for every slave cycle. Nothing asserts a
//! wall-clock duration.
//!
//! A host stall that silences the link for the slave's 20 ms watchdog stops the cut (the safe
//! stop retracts the tool) while the operator's script goes on: the part then has an uncut
//! patch (CI, 2026-12-03: one trip inside a 60 ms freeze of both loops, surface error 1.67 mm).
//! The pocket's surface target is judged only on a run without such a trip; every other check
//! (stable, force, gouge, removal, the part's files) on every run, and a trip no stall of
//! either loop explains fails the test.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_tests::procs::*;
use h4_tests::stalls::trips_outside_stalls;

/// At most this many safe stops of a run may be excused by host stalls.
const MAX_EXCUSED: u64 = 2;
/// A missed-deadline span at least this long is a host stall that can silence the link for
/// the watchdog's 20 ms, ms.
const STALL_MS: f64 = 8.0;
/// How long after a stall's end a trip can still be its consequence (the 20 ms watchdog,
/// margin), ms.
const STALL_REACH_MS: f64 = 100.0;

/// The volume a binary STL encloses (divergence theorem over its triangles), mm³.
fn stl_volume_mm3(stl: &[u8]) -> f64 {
    let n = u32::from_le_bytes([stl[80], stl[81], stl[82], stl[83]]) as usize;
    assert_eq!(stl.len(), 84 + 50 * n, "a binary STL of {n} triangles");
    let f = |o: usize| {
        f64::from(f32::from_le_bytes([
            stl[o],
            stl[o + 1],
            stl[o + 2],
            stl[o + 3],
        ]))
    };
    let mut v = 0.0;
    for t in 0..n {
        let b = 84 + 50 * t + 12;
        let p = |k: usize| [f(b + 12 * k), f(b + 12 * k + 4), f(b + 12 * k + 8)];
        let (a, b, c) = (p(0), p(1), p(2));
        v += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))
            / 6.0;
    }
    v.abs()
}

#[test]
fn loopback_cuts_the_pocket_and_the_slave_judges_and_writes_the_part() {
    let _g = serial();
    let scratch = Scratch::new("process-cutting-part");
    let out = scratch.path("part");
    let rec = scratch.path("cut.mcap");
    let mut args = s(&["--config", "config/sessions/cut-pocket.toml"]);
    for (k, v) in [("--out", &out), ("--record", &rec)] {
        args.push(k.into());
        args.push(v.display().to_string());
    }
    let (v, log) = loopback_summary("process-cutting", &args, 300.0);
    assert_eq!(v["stable"], true, "{v:#}");
    assert!(
        f(&v, "max_force_n") <= f(&v["slave"], "force_limit_n"),
        "{v:#}"
    );
    // The part, judged by the slave against the session's target: the pocket (2 mm deep,
    // 766 mm³ in the simulation) is cut, to the surface and gouge targets.
    let removed = f(&v, "removed_volume_mm3");
    assert_eq!(removed, f(&v["slave"], "removed_volume_mm3"));
    assert!(removed > 600.0, "removed {removed} mm³\n{v:#}\n{log}");
    let unexplained = trips_outside_stalls(&v, STALL_MS, STALL_REACH_MS);
    assert!(
        unexplained.is_empty(),
        "safe stops no host stall explains at {unexplained:?}: {v:#}"
    );
    // Trips a host stall explains are excused, counted and bounded.
    let excused = u(&v["slave"], "safe_stops") - unexplained.len() as u64;
    println!("safe stops excused by host stalls: {excused} (at most {MAX_EXCUSED})");
    assert!(
        excused <= MAX_EXCUSED,
        "{excused} safe stops excused by host stalls, more than {MAX_EXCUSED}: {v:#}"
    );
    if u(&v["slave"], "safe_stops") == 0 {
        assert!(f(&v, "surface_error_p99_mm") <= 0.2, "{v:#}");
    } else {
        eprintln!(
            "a host stall tripped the watchdog: the surface target is not judged (surface error p99 {} mm)",
            f(&v, "surface_error_p99_mm")
        );
    }
    assert!(f(&v, "gouge_max_mm") <= 0.05, "{v:#}");
    assert!(f(&v, "removal_rate_mm3_per_s") > 0.0, "{v:#}");
    let stl = std::fs::read(out.join("part.stl")).unwrap();
    // The block: 150 × 150 × 30 mm of 0.25 mm cells; the STL's surface runs through the
    // cells' centres (149.75 mm square); the part is that less the removed volume, within
    // 1 % of the removed volume.
    let block = 149.75 * 149.75 * 30.0;
    let vol = stl_volume_mm3(&stl);
    assert!(
        (vol - (block - removed)).abs() < 0.01 * removed,
        "STL encloses {vol} mm³, block less removed {}",
        block - removed
    );
    h4_tests::check_cut_outputs(&out);
    // The recording: one `/slave/cut` record per slave cycle, the last one's removed volume
    // the summary's (the shutdown's cycles included: the tool retracts, nothing more is cut).
    let (cut_records, last) = h4_tests::cut_records(&std::fs::read(&rec).unwrap());
    let cut_records = cut_records as u64;
    // (`cycles` counts the shutdown's cycles too.)
    let slave_cycles = u(&v["slave"], "cycles");
    assert!(
        cut_records <= slave_cycles
            && cut_records + u(&v["slave"], "recording_dropped") >= slave_cycles,
        "{cut_records} /slave/cut records, {slave_cycles} slave cycles"
    );
    let last = last.unwrap();
    let last_removed = last["removed_mm3"].as_f64().unwrap();
    assert!((last_removed - removed).abs() < 1e-6, "{last}");
    assert_eq!(
        last["tool_tip_in_workpiece_mm"].as_array().unwrap().len(),
        3
    );
    assert!(last["turntable_rad"].as_f64().is_some(), "{last}");
}

/// The turntable in the real processes: `cut-profile.toml` cuts a ring contour round the
/// turning part in aluminium (the turntable-synchronous fixture turns the part, the operator
/// guides radius and depth): the target, surface error p99 ≤ 0.3 mm, on the slave
/// process's own judgement, the part's volume, and the table's angle in `/slave/cut` (a
/// revolution and a quarter, ≈ 8.5 rad, measured and commanded).
#[test]
fn loopback_cuts_the_profile_on_the_turning_part() {
    let _g = serial();
    let scratch = Scratch::new("process-cutting-profile-files");
    let rec = scratch.path("profile.mcap");
    let mut args = s(&["--config", "config/sessions/cut-profile.toml"]);
    args.push("--record".into());
    args.push(rec.display().to_string());
    let (v, log) = loopback_summary("process-cutting-profile", &args, 120.0);
    assert_eq!(v["stable"], true, "{v:#}");
    assert!(
        f(&v, "max_force_n") <= f(&v["slave"], "force_limit_n"),
        "{v:#}"
    );
    // The ring: 484 mm³ in the simulation.
    let removed = f(&v, "removed_volume_mm3");
    assert!(
        (removed - 484.0).abs() < 0.1 * 484.0,
        "removed {removed} mm³\n{v:#}\n{log}"
    );
    assert!(f(&v, "surface_error_p99_mm") <= 0.3, "{v:#}");
    assert!(f(&v, "gouge_max_mm") <= 0.05, "{v:#}");
    assert_eq!(u(&v, "spindle_stalls"), 0, "{v:#}");
    let last = h4_tests::cut_records(&std::fs::read(&rec).unwrap())
        .1
        .unwrap();
    let (table, cmd) = (
        last["turntable_rad"].as_f64().unwrap(),
        last["turntable_cmd_rad"].as_f64().unwrap(),
    );
    assert!(table > 7.0 && (table - cmd).abs() < 0.05, "{last}");
}
