//! The link conformance suite, written once and run for every transport.
//!
//! A transport provides a [`Transport`] (how to open an isolated network with one master and
//! one slave end per arm) and invokes [`conformance_suite!`], which expands to one `#[test]`
//! per behaviour. Every wait is a deadline loop ([`WATCHDOG`]): a hung transport fails the test
//! instead of hanging it, and no test asserts how long anything took.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)]

use std::thread;
use std::time::{Duration, Instant};

use h4_shared::wire::{Command, Feedback, PROTOCOL_VERSION, SlaveState, WireMessage};
use h4_transport::Link;
use h4_transport::gate::Gate;

/// Longest any single wait may take before the test fails (the host stalls for up to ~70 ms
/// at times; Zenoh's first round trip takes ~50 ms).
pub const WATCHDOG: Duration = Duration::from_secs(10);

/// How a transport under test is set up.
pub trait Transport {
    /// The master's end.
    type Master: Link<Command, Feedback>;
    /// The slave's end.
    type Slave: Link<Feedback, Command>;

    /// A fresh network, isolated from every other test, with a connected (master, slave) pair
    /// for each arm in `arms`, all on the same transport instance.
    fn open(arms: &[u16]) -> Vec<(Self::Master, Self::Slave)>;
}

/// A valid command.
pub fn command(arm_id: u16, seq: u64) -> Command {
    Command {
        session_id: 0x51,
        seq,
        send_time_ns: 1_000 + seq,
        pose: [1.5, -2.25, 40.0 + seq as f64, 0.125],
        velocity: [0.5, 0.0, -1.0, 0.01],
        force_setpoint_n: 3.5,
        energy_in_j: 0.25,
        energy_out_j: 0.125,
        protocol_version: PROTOCOL_VERSION,
        arm_id,
        mode: 0,
        reserved: 0,
        flags: 0,
        echo_seq: 0,
        echo_send_time_ns: 0,
    }
}

/// A valid feedback message.
pub fn feedback(arm_id: u16, seq: u64) -> Feedback {
    Feedback {
        session_id: 0x52,
        seq,
        send_time_ns: 2_000 + seq,
        echo_seq: seq.saturating_sub(1),
        echo_send_time_ns: 999,
        pose: [1.0, 2.0, 3.0 + seq as f64, 0.5],
        wrench_measured: [0.1, -0.2, 5.0, 0.0],
        wrench_desired: [0.0, 0.0, 5.0, 0.0],
        energy_in_j: 1.0,
        energy_out_j: 0.5,
        protocol_version: PROTOCOL_VERSION,
        arm_id,
        state: SlaveState::Idle as u8,
        contact_state: 0,
        fault_flags: 0,
        rejected_reasons: 0,
        rejected_count: 0,
        contact_point_mm: [0.0; 3],
        contact_normal: [0.0; 3],
        contact_stiffness_n_per_mm: 0.0,
    }
}

/// Publishes one message with `publish` and polls `seen` until it holds, publishing again after
/// each second without it; fails at the watchdog. Zenoh publishes with congestion control
/// `Drop`, so on a loaded host a sample may be lost before it leaves: a live loop would send its
/// next cycle, a test that counts messages sends the lost one again. A copy that only came late
/// shows as one delivery too many, which the counting tests then report.
pub fn deliver(what: &str, mut publish: impl FnMut(), mut seen: impl FnMut() -> bool) {
    let deadline = Instant::now() + WATCHDOG;
    let mut resend_at = Instant::now();
    loop {
        if Instant::now() >= resend_at {
            publish();
            resend_at = Instant::now() + Duration::from_secs(1);
        }
        if seen() {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "watchdog: {what} never delivered"
        );
        thread::sleep(Duration::from_micros(200));
    }
}

/// [`deliver`] of a message that `link` receives: returns the first received message for which
/// `done` holds.
pub fn deliver_to<Out: WireMessage, In: WireMessage>(
    what: &str,
    publish: impl FnMut(),
    link: &mut impl Link<Out, In>,
    mut done: impl FnMut(&In) -> bool,
) -> In {
    let mut got = None;
    deliver(what, publish, || {
        while let Some(msg) = link.try_recv().expect("try_recv") {
            if got.is_none() && done(&msg) {
                got = Some(msg);
            }
        }
        got.is_some()
    });
    got.expect("delivered")
}

/// Exchanges warm-up messages (seq numbers below 10) until both directions deliver, then
/// drains both ends. Transports that connect asynchronously lose what is sent before.
pub fn connect<M: Link<Command, Feedback>, S: Link<Feedback, Command>>(
    master: &mut M,
    slave: &mut S,
    arm_id: u16,
) {
    let deadline = Instant::now() + WATCHDOG;
    let (mut to_slave, mut to_master) = (false, false);
    let mut seq = 0;
    while !(to_slave && to_master) {
        assert!(
            Instant::now() < deadline,
            "watchdog: the link never connected"
        );
        seq = (seq % 9) + 1;
        master.publish(&command(arm_id, seq)).expect("publish");
        slave.publish(&feedback(arm_id, seq)).expect("publish");
        thread::sleep(Duration::from_millis(2));
        to_slave |= slave.recv_latest().expect("recv").is_some();
        to_master |= master.recv_latest().expect("recv").is_some();
    }
    // Whatever was in flight arrives in order before the next message; settle, then drain.
    thread::sleep(Duration::from_millis(20));
    while slave.try_recv().expect("recv").is_some() {}
    while master.try_recv().expect("recv").is_some() {}
}

/// One connected (master, slave) pair for `arm_id`.
pub fn connected_pair<T: Transport>(arm_id: u16) -> (T::Master, T::Slave) {
    let mut pairs = T::open(&[arm_id]);
    let (mut master, mut slave) = pairs.pop().expect("one pair");
    connect(&mut master, &mut slave, arm_id);
    (master, slave)
}

/// Both message kinds arrive unchanged.
pub fn round_trip_both_kinds<T: Transport>() {
    let (mut master, mut slave) = connected_pair::<T>(3);
    let sent = command(3, 42);
    let got = deliver_to(
        "command 42",
        || master.publish(&sent).expect("publish"),
        &mut slave,
        |c| c.seq == 42,
    );
    assert_eq!(got, sent);
    let mut reply = feedback(3, 7);
    reply.echo_seq = got.seq;
    reply.echo_send_time_ns = got.send_time_ns;
    let back = deliver_to(
        "feedback 7",
        || slave.publish(&reply).expect("publish"),
        &mut master,
        |f| f.seq == 7,
    );
    assert_eq!(back, reply);
}

/// `recv_latest` drains what arrived and returns the newest.
pub fn newest_wins<T: Transport>() {
    let (mut master, mut slave) = connected_pair::<T>(3);
    for seq in 10..=20 {
        master.publish(&command(3, seq)).expect("publish");
    }
    let deadline = Instant::now() + WATCHDOG;
    let mut newest = 0;
    // Congestion control `Drop` may lose the end of a burst: after 200 ms without seq 20 the
    // master publishes its next cycle, as a live loop would.
    let (mut next_seq, mut resend_at) = (21, Instant::now() + Duration::from_millis(200));
    while newest < 20 {
        assert!(Instant::now() < deadline, "watchdog: seq 20 never arrived");
        if Instant::now() > resend_at {
            master.publish(&command(3, next_seq)).expect("publish");
            next_seq += 1;
            resend_at = Instant::now() + Duration::from_millis(200);
        }
        if let Some(c) = slave.recv_latest().expect("recv") {
            assert!(
                c.seq > newest,
                "recv_latest went back: {} after {newest}",
                c.seq
            );
            newest = c.seq;
        }
        thread::sleep(Duration::from_micros(200));
    }
    assert_eq!(
        slave.try_recv().expect("recv"),
        None,
        "recv_latest left messages behind"
    );
    assert_eq!(slave.recv_latest().expect("recv"), None);
}

/// Receiving from an end with nothing pending returns `None` at once.
pub fn empty_receive_is_non_blocking<T: Transport>() {
    let (mut master, mut slave) = connected_pair::<T>(3);
    for _ in 0..100 {
        assert_eq!(slave.try_recv().expect("recv"), None);
        assert_eq!(slave.recv_latest().expect("recv"), None);
        assert_eq!(master.try_recv().expect("recv"), None);
        assert_eq!(master.recv_latest().expect("recv"), None);
    }
}

/// A wait for the peer's message whose deadline is less than a microsecond away (or past)
/// returns with nothing when the peer is silent, on both ends; one with a message waiting
/// returns true. A transport that blocks instead (iceoryx2 0.10's listener turns a
/// sub-microsecond timeout into "no timeout") ends the test binary through the watchdog.
pub fn short_waits_on_a_silent_peer_return<T: Transport>() {
    let (mut master, mut slave) = connected_pair::<T>(3);
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let watch = done.clone();
    let watchdog = thread::spawn(move || {
        let deadline = Instant::now() + WATCHDOG;
        while Instant::now() < deadline {
            if watch.load(std::sync::atomic::Ordering::Acquire) {
                return;
            }
            thread::sleep(Duration::from_millis(10));
        }
        eprintln!("watchdog: a short wait_message on a silent peer did not return");
        std::process::exit(101);
    });
    for round in 0..200u32 {
        for offset_ns in [0u64, 1, 50, 200, 500, 900, 999] {
            let deadline = Instant::now() + Duration::from_nanos(offset_ns);
            assert!(
                !slave.wait_message(deadline).expect("wait"),
                "round {round}, {offset_ns} ns: the slave woke with no command sent"
            );
            let deadline = Instant::now() + Duration::from_nanos(offset_ns);
            assert!(
                !master.wait_message(deadline).expect("wait"),
                "round {round}, {offset_ns} ns: the master woke with no feedback sent"
            );
        }
    }
    if slave.can_wake() {
        master.publish(&command(3, 500)).expect("publish");
        let deadline = Instant::now() + WATCHDOG;
        assert!(
            slave.wait_message(deadline).expect("wait"),
            "a waiting command did not wake the slave"
        );
    }
    done.store(true, std::sync::atomic::Ordering::Release);
    watchdog.join().expect("watchdog");
}

/// A NaN, a wrong protocol version, a duplicate and a reordered (older) message never get past
/// the link and the gate; the valid ones do, and every rejection is counted once.
pub fn gate_rejects_bad_duplicate_and_reordered<T: Transport>() {
    let (mut master, mut slave) = connected_pair::<T>(3);
    let mut nan = command(3, 101);
    nan.pose[2] = f64::NAN;
    let mut wrong_version = command(3, 102);
    wrong_version.protocol_version = PROTOCOL_VERSION + 1;
    let sequence = [
        command(3, 100),
        nan,
        wrong_version,
        command(3, 100), // duplicate
        command(3, 99),  // reordered, older
        command(3, 103),
    ];
    // One message at a time, as a live loop publishes (one per cycle, not a burst), each
    // delivered or refused by the link before the next.
    let mut gate = Gate::<Command>::new(3, 1_000_000_000);
    let mut accepted = Vec::new();
    let mut received = 0;
    for c in &sequence {
        let before = received + slave.undecodable();
        deliver(
            &format!("seq {}", c.seq),
            || master.publish(c).expect("publish"),
            || {
                while let Some(got) = slave.try_recv().expect("recv") {
                    received += 1;
                    if let Ok(ok) = gate.accept(&got, 0) {
                        accepted.push(ok.seq);
                    }
                }
                received + slave.undecodable() > before
            },
        );
    }
    assert_eq!(accepted, vec![100, 103]);
    // What the link dropped undecoded reaches the gate's counters.
    gate.note_decode_rejects(slave.decode_rejects());
    let c = gate.counters;
    assert_eq!(
        c.undecodable + c.wrong_version,
        2,
        "NaN and version: link refused {}, gate {c:?}",
        slave.undecodable()
    );
    assert_eq!(c.rejected() - c.wrong_version - c.undecodable, 2, "{c:?}");
    assert_eq!(received + slave.undecodable(), sequence.len() as u64);
}

/// Two arms on the same transport instance never see each other's messages.
pub fn arms_do_not_interfere<T: Transport>() {
    let mut pairs = T::open(&[1, 2]);
    for (i, (master, slave)) in pairs.iter_mut().enumerate() {
        connect(master, slave, i as u16 + 1);
    }
    for round in 0..20u64 {
        for (i, (master, slave)) in pairs.iter_mut().enumerate() {
            let arm = i as u16 + 1;
            master.publish(&command(arm, 100 + round)).expect("publish");
            slave.publish(&feedback(arm, 100 + round)).expect("publish");
        }
    }
    // Zenoh publishes with congestion control `Drop` (a late sample is worth less than the next),
    // so a burst may lose any sample, the last one included: the last is re-published, as a live
    // loop would publish its next cycle, until each end has it.
    let deadline = Instant::now() + WATCHDOG;
    let mut have = vec![(false, false); pairs.len()];
    while have.iter().any(|&(c, f)| !(c && f)) {
        assert!(
            Instant::now() < deadline,
            "watchdog: the last command or feedback never arrived ({have:?})"
        );
        for (i, (master, slave)) in pairs.iter_mut().enumerate() {
            let arm = i as u16 + 1;
            while let Some(c) = slave.try_recv().expect("try_recv") {
                assert_eq!(
                    c.arm_id, arm,
                    "arm {arm}'s slave got a command for arm {}",
                    c.arm_id
                );
                have[i].0 |= c.seq == 119;
            }
            while let Some(f) = master.try_recv().expect("try_recv") {
                assert_eq!(
                    f.arm_id, arm,
                    "arm {arm}'s master got feedback of arm {}",
                    f.arm_id
                );
                have[i].1 |= f.seq == 119;
            }
            if !have[i].0 {
                master.publish(&command(arm, 119)).expect("publish");
            }
            if !have[i].1 {
                slave.publish(&feedback(arm, 119)).expect("publish");
            }
        }
        thread::sleep(Duration::from_millis(1));
    }
    // Anything still in flight must also be for the right arm.
    thread::sleep(Duration::from_millis(50));
    for (i, (master, slave)) in pairs.iter_mut().enumerate() {
        let arm = i as u16 + 1;
        while let Some(c) = slave.try_recv().expect("recv") {
            assert_eq!(c.arm_id, arm);
        }
        while let Some(f) = master.try_recv().expect("recv") {
            assert_eq!(f.arm_id, arm);
        }
    }
}

/// While commands flow the slave's gate reports the master alive; once the master's end is
/// dropped it stops being alive (no phantom or replayed deliveries keep it so), and receiving
/// after the drop neither blocks nor fails.
pub fn liveness_lost_after_peer_drop<T: Transport>() {
    const TIMEOUT_NS: u64 = 50_000_000;
    let (mut master, mut slave) = connected_pair::<T>(3);
    let start = Instant::now();
    let now_ns = || start.elapsed().as_nanos() as u64;
    let mut gate = Gate::<Command>::new(3, 1_000_000_000);
    let deadline = Instant::now() + WATCHDOG;
    let mut seq = 100;
    while !gate.alive(now_ns(), TIMEOUT_NS) {
        assert!(
            Instant::now() < deadline,
            "watchdog: the master never became alive"
        );
        seq += 1;
        master.publish(&command(3, seq)).expect("publish");
        thread::sleep(Duration::from_millis(1));
        while let Some(c) = slave.try_recv().expect("recv") {
            let _ = gate.accept(&c, now_ns());
        }
    }
    drop(master);
    let deadline = Instant::now() + WATCHDOG;
    while gate.alive(now_ns(), TIMEOUT_NS) {
        assert!(
            Instant::now() < deadline,
            "watchdog: the master still alive after its end was dropped"
        );
        thread::sleep(Duration::from_millis(1));
        while let Some(c) = slave.try_recv().expect("recv after the peer dropped") {
            let _ = gate.accept(&c, now_ns());
        }
    }
    assert_eq!(gate.counters.stale, 0, "{:?}", gate.counters);
}

/// One `#[test]` per behaviour for the [`Transport`] `$t`.
#[macro_export]
macro_rules! conformance_suite {
    ($t:ty) => {
        #[test]
        fn round_trip_both_kinds() {
            common::suite::round_trip_both_kinds::<$t>();
        }
        #[test]
        fn newest_wins() {
            common::suite::newest_wins::<$t>();
        }
        #[test]
        fn empty_receive_is_non_blocking() {
            common::suite::empty_receive_is_non_blocking::<$t>();
        }
        #[test]
        fn gate_rejects_bad_duplicate_and_reordered() {
            common::suite::gate_rejects_bad_duplicate_and_reordered::<$t>();
        }
        #[test]
        fn arms_do_not_interfere() {
            common::suite::arms_do_not_interfere::<$t>();
        }
        #[test]
        fn short_waits_on_a_silent_peer_return() {
            common::suite::short_waits_on_a_silent_peer_return::<$t>();
        }
        #[test]
        fn liveness_lost_after_peer_drop() {
            common::suite::liveness_lost_after_peer_drop::<$t>();
        }
    };
}
