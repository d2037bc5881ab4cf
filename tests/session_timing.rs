//! The lockstep session's slave timing (`slave.timing`, issue 33): by default the slave is
//! phase-locked, as `h4-slave run` now is (its feedback answers the master's command of the
//! same period, which the master reads at its next step); `own-clock` models a slave on its
//! own clock that takes each command one period later. Checked on what the two sides echo,
//! on the simulated clock; each timing is the other's negative control.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session::{self, Session, SessionConfig, SlaveTiming};

fn wall_push(overrides: &[&str]) -> Result<SessionConfig, session::SessionError> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/wall-push.toml");
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    session::load(&path, &o)
}

/// Per cycle of a lockstep run on an ideal link: (the master's commands published so far,
/// i.e. the sequence number of this period's command; the newest command the slave took;
/// the command the feedback the master read this period echoes).
fn echoes(timing: &str, cycles: usize) -> Vec<(u64, u64, u64)> {
    let cfg = wall_push(&["duration_s=1", &format!("slave.timing=\"{timing}\"")]).unwrap();
    let mut s = Session::new(&cfg).unwrap();
    (0..cycles)
        .map(|_| {
            let (_, slave) = s.cycle().unwrap();
            let sent = s.master.counters().commands_published;
            let read = s.master.latest_feedback().map_or(0, |f| f.echo_seq);
            (sent, slave.command_seq, read)
        })
        .collect()
}

#[test]
fn the_default_is_phase_locked() {
    assert_eq!(
        wall_push(&[]).unwrap().slave.timing,
        SlaveTiming::PhaseLocked
    );
}

/// Phase-locked: the slave's feedback of period k echoes command k, and the master reads it
/// at period k + 1. Own clock: it echoes command k − 1, the master reads it at k + 1.
#[test]
fn the_slave_answers_the_command_of_the_same_period_unless_on_its_own_clock() {
    for (timing, lag) in [("phase-locked", 0), ("own-clock", 1)] {
        let trace = echoes(timing, 300);
        for (k, &(sent, took, read)) in trace.iter().enumerate().skip(5) {
            assert_eq!(sent, k as u64 + 1, "{timing}: one command per period");
            assert_eq!(took, sent - lag, "{timing}: cycle {k}: the slave took");
            assert_eq!(read, sent - 1 - lag, "{timing}: cycle {k}: the master read");
        }
    }
}

/// The round trip the master measures (the summary's `rtt_mean_ms`), on a link of 10 ms
/// each way: 20 ms of link, the period the slave's feedback waits for the master's next
/// step, and own-clock one period more.
#[test]
fn an_own_clock_slave_adds_a_period_to_the_round_trip() {
    let rtt = |timing: &str| {
        let cfg = wall_push(&[
            "duration_s=0.5",
            "link.delay_ms=10",
            &format!("slave.timing=\"{timing}\""),
        ])
        .unwrap();
        session::run(&cfg, None).unwrap().rtt_mean_ms
    };
    let (locked, own) = (rtt("phase-locked"), rtt("own-clock"));
    assert!((locked - 21.0).abs() < 1e-9, "phase-locked: {locked} ms");
    assert!((own - 22.0).abs() < 1e-9, "own-clock: {own} ms");
}

#[test]
fn an_unknown_timing_is_refused_with_the_choices() {
    let e = wall_push(&["slave.timing=\"sometimes\""])
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(e.contains("phase-locked") && e.contains("own-clock"), "{e}");
}
