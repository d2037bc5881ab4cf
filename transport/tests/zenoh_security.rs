//! Zenoh security with the shipped configurations (`config/zenoh/*.json5`): only the
//! authorised master's commands reach the slave.
//!
//! Certificates are generated at test time with `rcgen` (a test CA, the slave, the master, a
//! monitor, and a rogue CA with a rogue "h4-master"); the shipped json5 files are installed
//! into a temporary directory with their `/etc/h4-teleop/zenoh/` paths rewritten, so the test
//! exercises exactly what ships. In each scenario the authorised master's commands must arrive
//! (the positive control) while every other party is either refused at connection or, if it
//! is an authenticated monitor, proven connected (it receives feedback) and still never gets a
//! command through. Every wait is bounded by the watchdog.
#![cfg(feature = "zenoh")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use h4_shared::wire::{Command, Feedback, PROTOCOL_VERSION};
use h4_transport::Link;
use h4_transport::zenoh::{MasterZenohLink, SlaveZenohLink, ZenohConfig, ZenohMode};

/// The shipped configuration files.
const SHIPPED_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/zenoh");
/// The directory the shipped files name for certificates and credentials.
const SHIPPED_PREFIX: &str = "/etc/h4-teleop/zenoh/";
/// The arm every scenario drives.
const ARM: u16 = 3;
/// Commands from anyone but the authorised master carry sequence numbers from here up.
const INTRUDER_SEQ: u64 = 1_000_000;
/// Rounds (2 ms apart) every party keeps publishing after all of them are known to be
/// connected, so a command that the access control failed to stop would have arrived.
const ROUNDS_AFTER_CONNECTED: u64 = 250;

/// Longest any wait may take before the test fails (a watchdog, not a timing assertion).
const WATCHDOG: Duration = Duration::from_secs(20);

/// A TCP port on 127.0.0.1 that was free a moment ago.
fn free_port() -> u16 {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    listener.local_addr().unwrap().port()
}

fn command(arm_id: u16, seq: u64) -> Command {
    Command {
        seq,
        send_time_ns: seq,
        protocol_version: PROTOCOL_VERSION,
        arm_id,
        ..Command::default()
    }
}

fn feedback(arm_id: u16, seq: u64) -> Feedback {
    Feedback {
        seq,
        send_time_ns: seq,
        protocol_version: PROTOCOL_VERSION,
        arm_id,
        ..Feedback::default()
    }
}

/// A directory removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Self {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let name = format!(
            "h4_zenoh_security_{}_{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let dir = std::env::temp_dir().join(name);
        fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

mod pki;
use pki::write_pki;

/// Installs shipped file `shipped` as `installed` in `dir`: paths point into `dir`, then each
/// `(from, to)` replacement is applied. Returns the installed file's path.
fn install(dir: &Path, shipped: &str, installed: &str, replacements: &[(&str, &str)]) -> String {
    let text = fs::read_to_string(Path::new(SHIPPED_DIR).join(shipped)).unwrap();
    let prefix = format!("{}/", dir.display());
    let mut text = text.replace(SHIPPED_PREFIX, &prefix);
    for (from, to) in replacements {
        assert!(text.contains(from), "{shipped} has no {from:?}");
        text = text.replace(from, to);
    }
    let path = dir.join(installed);
    fs::write(&path, text).unwrap();
    path.display().to_string()
}

fn slave_settings(port: u16, file: &str) -> ZenohConfig {
    ZenohConfig {
        mode: ZenohMode::Peer,
        listen: vec![format!("quic/127.0.0.1:{port}")],
        config_file: Some(file.to_string()),
        ..ZenohConfig::default()
    }
}

fn client_settings(endpoint: String, file: Option<String>) -> ZenohConfig {
    ZenohConfig {
        mode: ZenohMode::Client,
        connect: vec![endpoint],
        config_file: file,
        ..ZenohConfig::default()
    }
}

/// Someone other than the authorised master.
struct Other {
    name: &'static str,
    /// `Err` if Zenoh refused to open its session (the handshake or authentication failed).
    link: Result<MasterZenohLink, String>,
    /// Whether it is allowed to receive feedback (then it must, to prove it is connected).
    reads_feedback: bool,
    feedback_seen: u64,
}

impl Other {
    fn open(name: &'static str, settings: &ZenohConfig, reads_feedback: bool) -> Self {
        Other {
            name,
            link: MasterZenohLink::open(ARM, settings).map_err(|e| e.to_string()),
            reads_feedback,
            feedback_seen: 0,
        }
    }
}

/// Runs the slave, the authorised master and the others until the master's commands and the
/// slave's feedback flow and every feedback reader got feedback, then `ROUNDS_AFTER_CONNECTED`
/// more rounds. Asserts that only the master's commands reached the slave.
fn only_the_master_commands(
    slave: &mut SlaveZenohLink,
    master: &mut MasterZenohLink,
    others: &mut [Other],
) {
    for other in others.iter() {
        if let Err(e) = &other.link {
            println!("{}: refused at connection: {e}", other.name);
        }
    }
    let deadline = Instant::now() + WATCHDOG;
    let mut master_commands = 0u64;
    let mut master_feedback = 0u64;
    let mut connected_at_round = None;
    let mut round = 0u64;
    loop {
        round += 1;
        master.publish(&command(ARM, round)).unwrap();
        for (i, other) in others.iter_mut().enumerate() {
            if let Ok(link) = &mut other.link {
                let seq = INTRUDER_SEQ * (i as u64 + 1) + round;
                link.publish(&command(ARM, seq)).unwrap();
            }
        }
        slave.publish(&feedback(ARM, round)).unwrap();
        thread::sleep(Duration::from_millis(2));

        while let Some(c) = slave.try_recv().unwrap() {
            assert!(
                c.seq < INTRUDER_SEQ,
                "a command from {} reached the slave (seq {})",
                others[(c.seq / INTRUDER_SEQ - 1) as usize].name,
                c.seq
            );
            master_commands += 1;
        }
        while let Some(f) = master.try_recv().unwrap() {
            assert_eq!(f.arm_id, ARM);
            master_feedback += 1;
        }
        for other in others.iter_mut() {
            if let Ok(link) = &mut other.link {
                while link.try_recv().unwrap().is_some() {
                    assert!(other.reads_feedback, "{} received feedback", other.name);
                    other.feedback_seen += 1;
                }
            }
        }

        let all_connected = master_commands > 0
            && master_feedback > 0
            && others
                .iter()
                .all(|o| !o.reads_feedback || o.feedback_seen > 0);
        match connected_at_round {
            None if all_connected => connected_at_round = Some(round),
            Some(at) if round >= at + ROUNDS_AFTER_CONNECTED => break,
            _ => {}
        }
        assert!(
            Instant::now() < deadline,
            "watchdog: master commands {master_commands}, master feedback {master_feedback}, \
             others' feedback {:?}",
            others
                .iter()
                .map(|o| (o.name, o.feedback_seen, o.link.is_ok()))
                .collect::<Vec<_>>()
        );
    }
    assert!(
        master_commands > ROUNDS_AFTER_CONNECTED / 2,
        "{master_commands}"
    );
}

#[test]
fn shipped_configs_parse() {
    let mut n = 0;
    for entry in fs::read_dir(SHIPPED_DIR).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "json5") {
            ::zenoh::Config::from_file(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            n += 1;
        }
    }
    assert_eq!(
        n, 5,
        "expected five shipped json5 files (four security files, low-latency.json5)"
    );
}

#[test]
fn mutual_tls_only_the_master_with_its_certificate_commands() {
    let dir = TempDir::new();
    write_pki(dir.path());
    let slave_file = install(dir.path(), "slave-mtls.json5", "slave.json5", &[]);
    let master_file = install(dir.path(), "master-mtls.json5", "master.json5", &[]);
    let monitor_file = install(
        dir.path(),
        "master-mtls.json5",
        "monitor.json5",
        &[
            ("/master.pem", "/monitor.pem"),
            ("/master-key.pem", "/monitor-key.pem"),
        ],
    );
    let rogue_file = install(
        dir.path(),
        "master-mtls.json5",
        "rogue.json5",
        &[
            ("/master.pem", "/rogue-master.pem"),
            ("/master-key.pem", "/rogue-master-key.pem"),
        ],
    );

    let port = free_port();
    let mut slave = SlaveZenohLink::open(ARM, &slave_settings(port, &slave_file)).unwrap();
    let tls = format!("quic/127.0.0.1:{port}");
    let mut master =
        MasterZenohLink::open(ARM, &client_settings(tls.clone(), Some(master_file))).unwrap();
    let mut others = [
        Other::open(
            "monitor (valid certificate, CN h4-monitor)",
            &client_settings(tls.clone(), Some(monitor_file)),
            true,
        ),
        Other::open(
            "rogue (CN h4-master, signed by another CA)",
            &client_settings(tls, Some(rogue_file)),
            false,
        ),
        Other::open(
            "plain TCP peer without TLS",
            &client_settings(format!("tcp/127.0.0.1:{port}"), None),
            false,
        ),
    ];
    only_the_master_commands(&mut slave, &mut master, &mut others);
    assert!(
        others[1].link.is_err(),
        "the rogue certificate passed the TLS handshake"
    );
}

#[test]
fn tls_with_passwords_only_the_master_user_commands() {
    let dir = TempDir::new();
    write_pki(dir.path());
    fs::copy(
        Path::new(SHIPPED_DIR).join("credentials.example.txt"),
        dir.path().join("credentials.txt"),
    )
    .unwrap();
    let slave_file = install(dir.path(), "slave-tls-usrpwd.json5", "slave.json5", &[]);
    let master_file = install(dir.path(), "master-tls-usrpwd.json5", "master.json5", &[]);
    let monitor_file = install(
        dir.path(),
        "master-tls-usrpwd.json5",
        "monitor.json5",
        &[
            ("\"h4-master\"", "\"h4-monitor\""),
            ("\"change-me\"", "\"change-me-too\""),
        ],
    );
    let guesser_file = install(
        dir.path(),
        "master-tls-usrpwd.json5",
        "guesser.json5",
        &[("\"change-me\"", "\"guess\"")],
    );

    let port = free_port();
    let mut slave = SlaveZenohLink::open(ARM, &slave_settings(port, &slave_file)).unwrap();
    let tls = format!("quic/127.0.0.1:{port}");
    let mut master =
        MasterZenohLink::open(ARM, &client_settings(tls.clone(), Some(master_file))).unwrap();
    let mut others = [
        Other::open(
            "monitor (valid user h4-monitor)",
            &client_settings(tls.clone(), Some(monitor_file)),
            true,
        ),
        Other::open(
            "h4-master with a wrong password",
            &client_settings(tls, Some(guesser_file)),
            false,
        ),
    ];
    only_the_master_commands(&mut slave, &mut master, &mut others);
    assert!(others[1].link.is_err(), "a wrong password opened a session");
}

/// The shipped files allow QUIC (TLS 1.3) links only, so an end in peer mode cannot fall back
/// to the Zenoh link's default plain-TCP loopback listener: it must be given a `quic/` listener (or
/// run as a client, as the files recommend for the master).
#[test]
fn tls_only_files_refuse_a_plain_tcp_listener() {
    let dir = TempDir::new();
    write_pki(dir.path());
    let master_file = install(dir.path(), "master-mtls.json5", "master.json5", &[]);
    let peer = ZenohConfig {
        mode: ZenohMode::Peer,
        connect: vec![format!("quic/127.0.0.1:{}", free_port())],
        config_file: Some(master_file),
        ..ZenohConfig::default()
    };
    let err = MasterZenohLink::open(ARM, &peer).expect_err("a plain TCP listener was opened");
    assert!(err.to_string().contains("tcp"), "{err}");
}
