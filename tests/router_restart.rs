//! A Zenoh router restart under two clients, against the real processes (issue 16): the
//! slave and the master run in client mode on two hosts (network namespaces), both connected
//! to a router on the slave's host (`h4-zenoh-router`, built from the project's zenoh crate,
//! `tests/src/bin/`). In the middle of a contact the router is killed (SIGKILL) and started
//! again 2 s later. The criteria of a link cut (`tests/link_cut.rs`): the slave safe within
//! 20 ms of silence plus its own lateness and the force released, the master faded out; once
//! the router is back, re-paired within 1 s with no position or force jump. Skipped with a
//! printed `SKIPPED` line where namespaces cannot be made.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use h4_tests::netns::{Host, TwoHosts};
use h4_tests::record::{self, SafeEpisode};
use h4_tests::remote_procs::{self, Pair, PairSpec, Scratch};

const SESSION: &str = "config/sessions/wall-push.toml";

/// Starts the router on the slave's host; returns once it says `ready`.
fn router(hosts: &TwoHosts, endpoint: &str) -> Child {
    let bin = Path::new(env!("CARGO_BIN_EXE_h4-zenoh-router"));
    let mut child = hosts
        .command(Host::Slave, bin)
        .arg(endpoint)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start h4-zenoh-router");
    let out = child.stdout.take().expect("router stdout");
    let mut line = String::new();
    BufReader::new(out)
        .read_line(&mut line)
        .expect("router output");
    assert_eq!(line.trim(), "ready", "router did not start");
    child
}

/// Kills a child when dropped.
struct Kill(Option<Child>);
impl Drop for Kill {
    fn drop(&mut self) {
        if let Some(mut c) = self.0.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

#[test]
fn a_router_restart_under_clients_safe_stops_fades_and_repairs() {
    let Some(hosts) = TwoHosts::new_or_skip("router_restart") else {
        return;
    };
    let scratch = Scratch::new("router-restart").unwrap();
    let endpoint = format!("tcp/{}:7447", hosts.ip(Host::Slave));
    let mut r = Kill(Some(router(&hosts, &endpoint)));
    let client = |extra: &[&str]| {
        let mut a: Vec<String> = ["--transport", "zenoh", "--zenoh-mode", "client"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        a.extend(["--zenoh-connect".to_string(), endpoint.clone()]);
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let spec = PairSpec {
        tag: "router",
        session: SESSION,
        overrides: vec![
            "environment.stiffness_n_per_mm=0".into(),
            "duration_s=5.8".into(),
        ],
        duration_s: 5.8,
        slave_args: client(&[]),
        master_args: client(&[]),
    };
    let mut pair = Pair::start_on(&hosts, &spec, &scratch).unwrap();
    std::thread::sleep(Duration::from_millis(2500));
    if let Some(mut c) = r.0.take() {
        let _ = c.kill();
        let _ = c.wait();
    }
    let t = Instant::now();
    std::thread::sleep(Duration::from_millis(2000));
    r.0 = Some(router(&hosts, &endpoint));
    let down_s = t.elapsed().as_secs_f64();
    let (m, s) = pair.finish().unwrap();
    let why = remote_procs::judge(
        &m,
        &s,
        &remote_procs::session(SESSION, &spec.overrides).unwrap(),
    );
    assert!(why.is_empty(), "{why:?}");
    let cycles = record::slave_cycles(&pair.slave_record).unwrap();
    let episodes = record::safe_episodes(&cycles);
    let outage = |e: &SafeEpisode| e.repaired_s.map(|r| r - e.last_command_s);
    let cut = episodes
        .iter()
        .filter(|e| outage(e).is_some())
        .max_by(|a, b| outage(a).partial_cmp(&outage(b)).unwrap())
        .unwrap_or_else(|| panic!("no safe stop that re-paired: {episodes:#?}\n{s:#?}"));
    println!("router down {down_s:.3} s; episode {cut:#?}");
    assert!(cut.force_at_entry_n > 2.0, "not in contact: {cut:#?}");
    assert!(
        s.safe_stop_entry_silence_ms <= 20.0 + s.safe_stop_entry_lateness_ms + 0.1,
        "{s:#?}"
    );
    assert!(cut.force_at_end_n < 1.0, "{cut:#?}");
    let late_s = outage(cut).unwrap() - down_s;
    println!("re-paired {late_s:.3} s after the router was back");
    assert!(
        late_s <= 1.0,
        "re-paired {late_s:.3} s after the router was back"
    );
    assert!(cut.max_step_after_mm < 0.15, "{cut:#?}");
    assert!(cut.max_force_after_n <= s.force_limit_n, "{cut:#?}");
    assert!(m.feedback_losses >= 1 && m.faded_out >= 1, "{m:#?}");
    // The fade is exponential: "nothing" is below a micronewton.
    assert!(m.max_force_while_faded_out_n < 1e-6, "{m:#?}");
    assert!(m.feedback_restored >= 1, "{m:#?}");
}
