//! The slave's playout (jitter) buffer in the real processes: `h4-master loopback` over
//! iceoryx2 with both sides impaired by 60 ± 30 ms each way (a jittery network link), the
//! wall-push session. Without the buffer the newest-wins receive gate leaves the slave's
//! 20 ms watchdog gaps of up to ~60 ms: it trips again and again (measured: 6 safe stops in
//! 8 s). With `slave.playout.enabled` (`h4-slave run --playout`, passed on by `loopback`)
//! the commands come out in order and evenly spaced: no trip (one allowed for a host stall
//! of this VM). Both runs are judged on physical evidence too: stable, forces within
//! limits, the observers above −1 mJ. Nothing asserts a wall-clock duration.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_tests::procs::*;
use serde_json::Value;

fn loopback(tag: &str, playout: bool) -> Value {
    let mut args = s(&[
        "--duration-s",
        "8",
        "--impair",
        "delay_ms=60,jitter_ms=30,seed=3",
        "--set",
    ]);
    args.push(format!("slave.playout.enabled={playout}"));
    let (v, log) = loopback_summary(tag, &args, 90.0);
    assert!(
        f(&v, "max_force_n") <= f(&v["slave"], "force_limit_n"),
        "{v:#}\n{log}"
    );
    assert!(f(&v, "energy_min_j") >= -1e-3, "{v:#}");
    assert!(u(&v["slave"]["gate"], "accepted") > 1000, "{v:#}");
    v
}

#[test]
fn the_playout_buffer_keeps_a_jittery_link_from_tripping_the_watchdog() {
    let _g = serial();
    let with = loopback("playout-on", true);
    let without = loopback("playout-off", false);
    let stops = |v: &Value| u(&v["slave"], "safe_stops");
    assert!(stops(&with) <= 1, "with the buffer: {:#}", with["slave"]);
    assert!(
        stops(&without) >= 3,
        "without the buffer (control): {:#}",
        without["slave"]
    );
    assert_eq!(with["stable"], true, "{with:#}");
    assert!(f(&with, "contact_time_s") > 1.0, "{with:#}");
}
