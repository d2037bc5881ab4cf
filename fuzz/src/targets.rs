//! The fuzz targets' bodies: shared by the coverage-guided fuzzer (`fuzz/`, libFuzzer,
//! `fuzz/run.sh`) and the CI run over the kept corpus and its mutations
//! (`tests/fuzz_targets.rs`). Each takes arbitrary bytes, must never panic or hang, and
//! checks the invariants named in its comment (a failed check is a crash).

use h4_shared::config::{ArmConfig, parse};
use h4_shared::kinematics::{ActuatorStiffness, H4Params, WorkspaceLimits};
use h4_shared::wire::{Command, CommandLimits, Feedback, WireMessage};
use h4_slave_sim::experiment::ExperimentConfig;
use h4_transport::Link;
use h4_transport::gate::{EnergyBound, Gate};
use h4_transport::inproc;

/// A target: its name (its folder under `fuzz/corpus/`) and its body.
pub type Target = (&'static str, fn(&[u8]));

/// Every target.
pub const TARGETS: [Target; 6] = [
    ("wire_decode", wire_decode),
    ("gate", gate),
    ("gate_bytes", gate_bytes),
    ("arm_config", arm_config),
    ("experiment_config", experiment_config),
    ("kin_tool", kin_tool),
];

/// The decoder: whatever the bytes, an error or a message that encodes back to the very same
/// bytes (the encoding is canonical).
pub fn wire_decode(data: &[u8]) {
    if let Ok(c) = Command::decode(data) {
        let mut b = [0u8; Command::WIRE_SIZE];
        c.encode(&mut b);
        assert_eq!(&b[..], data, "command does not round-trip");
        assert!(c.validate().is_ok());
    }
    if let Ok(f) = Feedback::decode(data) {
        let mut b = [0u8; Feedback::WIRE_SIZE];
        f.encode(&mut b);
        assert_eq!(&b[..], data, "feedback does not round-trip");
        // Protocol 3's surface estimate passed its checks: a unit normal in contact.
        assert!(f.validate().is_ok());
        if f.contact_state == h4_shared::wire::ContactState::Contact as u8 {
            let n = f.contact_normal;
            assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() <= 1e-6);
        }
    }
    if let Err(e) = Command::decode(data) {
        let _ = e.reason();
    }
}

fn limits() -> CommandLimits {
    CommandLimits {
        workspace: ArmConfig::default().workspace(),
        max_speed_mm_per_s: 100.0,
        force_limit_n: 80.0,
    }
}

fn new_gate() -> Gate<Command> {
    Gate::new(0, 100_000_000)
        .with_limits(limits())
        .with_energy_bound(EnergyBound::from_limits(80.0, 100.0, 4.0))
}

fn i16_at(d: &[u8], at: usize) -> f64 {
    f64::from(i16::from_le_bytes([d[at], d[at + 1]]))
}

/// One 16-byte record as a command near the workspace (so that the gate's later checks are
/// reached): time step, session, sequence step, mode, pose, speed, set-point, energy, arm.
fn record(d: &[u8], seq: &mut u64) -> (u64, Command) {
    let dt_ns = u64::from(d[0]) * 250_000;
    let step = match d[2] {
        0xFF => u64::MAX - *seq,
        0xFE => 1 << 40,
        s => u64::from(s % 8),
    };
    *seq = seq.wrapping_add(step);
    let cmd = Command {
        session_id: u64::from(d[1] % 3),
        seq: *seq,
        send_time_ns: *seq,
        pose: [
            i16_at(d, 4) * 0.01,
            i16_at(d, 6) * 0.01,
            -250.0 + i16_at(d, 8) * 0.01,
            0.0,
        ],
        velocity: [i16_at(d, 10) * 0.01, 0.0, 0.0, 0.0],
        force_setpoint_n: f64::from(d[12]) - 20.0,
        energy_in_j: f64::from(d[13]) * 0.01 * f64::from(d[14] % 4),
        energy_out_j: 0.0,
        arm_id: u16::from(d[15] % 2),
        mode: d[3] % 4,
        flags: u16::from(d[3] >> 6),
        ..Command::default()
    };
    (dt_ns, cmd)
}

/// The gate on structured commands: every message is counted once (accepted + every reason
/// = messages), an accepted command is inside the limits, for our arm, from the paired
/// session, with a sequence number above the last accepted one of that session.
pub fn gate(data: &[u8]) {
    let mut g = new_gate();
    let (mut now, mut seq, mut n) = (0u64, 0u64, 0u64);
    let mut last: Option<(u64, u64)> = None;
    for d in data.chunks_exact(16) {
        let (dt, cmd) = record(d, &mut seq);
        now += dt;
        n += 1;
        if let Ok(c) = g.accept(&cmd, now) {
            assert_eq!(c.arm_id, 0);
            assert!(c.out_of_range(&limits()).is_none());
            assert_eq!(g.paired_session(), Some(c.session_id));
            if let Some((s, q)) = last
                && s == c.session_id
            {
                assert!(c.seq > q, "seq went back within a session");
            }
            last = Some((c.session_id, c.seq));
        }
        assert_eq!(g.counters.accepted + g.counters.rejected(), n);
    }
}

/// The receive path on raw payloads: chunks of the command's size (the header forced valid
/// when the chunk's first byte is even) through the byte-level link and [`Gate::drain`]:
/// every payload counted once.
pub fn gate_bytes(data: &[u8]) {
    let mut g = new_gate();
    let (mut client, mut end) = inproc::raw_pair(1024);
    let mut valid = [0u8; Command::WIRE_SIZE];
    Command::default().encode(&mut valid);
    let mut n = 0u64;
    for (i, chunk) in data.chunks(Command::WIRE_SIZE).enumerate() {
        let mut b = chunk.to_vec();
        if chunk.first().is_some_and(|c| c % 2 == 0) && b.len() >= 16 {
            b[..8].copy_from_slice(&valid[..8]);
        }
        client.send(&b);
        n += 1;
        g.drain(&mut end, i as u64 * 1_000_000, 4096, |_| {});
        let _ = end.publish(&Feedback::default());
    }
    assert_eq!(g.counters.accepted + g.counters.rejected(), n);
}

fn text_and_overrides(data: &[u8]) -> (String, Vec<String>) {
    let mut parts = data.split(|b| *b == 0);
    let text = String::from_utf8_lossy(parts.next().unwrap_or(&[])).into_owned();
    let overrides = parts
        .take(4)
        .map(|p| String::from_utf8_lossy(p).into_owned())
        .collect();
    (text, overrides)
}

/// The arm configuration parser (TOML text, `--set` overrides after NUL bytes): an error or a
/// validated configuration whose workspace can be built.
pub fn arm_config(data: &[u8]) {
    let (text, overrides) = text_and_overrides(data);
    if let Ok(cfg) = parse::<ArmConfig>(&text, "fuzz", &overrides) {
        let _ = cfg.workspace();
    }
}

/// The experiment configuration parser (the slave's world files are experiment files).
pub fn experiment_config(data: &[u8]) {
    let (text, overrides) = text_and_overrides(data);
    let _ = parse::<ExperimentConfig>(&text, "fuzz", &overrides);
}

/// `h4-slave kin`'s input line, with and without the workspace check: always exactly one
/// JSON object answer, with `error` or `pose`.
pub fn kin_tool(data: &[u8]) {
    let line = String::from_utf8_lossy(data);
    let Ok(k) = ActuatorStiffness::uniform(100.0) else {
        return;
    };
    let limits = WorkspaceLimits::default();
    for l in [Some(&limits), None] {
        let v = h4_slave_sim::kin_tool::answer(&line, &H4Params::PROTOTYPE, &k, l);
        assert!(v.is_object(), "{v}");
        assert!(v.get("error").is_some() || v.get("pose").is_some() || v.get("l").is_some());
    }
}
