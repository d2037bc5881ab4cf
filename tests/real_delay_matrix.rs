//! The delay matrix against the real processes (issue 16): `h4-slave run` and `h4-master run`
//! as OS processes, round trip {0, 50, 250, 1000} ms × loss {0, 5 %} × wall {resin
//! (200 N/mm), aluminium (1000 N/mm)}, over two paths:
//!
//! * **iceoryx2 with `--impair`**: both processes impair what they send with the
//!   simulation's impairment layer (`delay_ms` = round trip / 2 each, `loss`).
//! * **Zenoh across two hosts**: the slave in one network namespace, the master in another,
//!   Zenoh over UDP across a veth pair through the test's relay (`h4_tests::relay`), which
//!   delays each direction by round trip / 2 and drops datagrams. Skipped, with a printed
//!   `SKIPPED` line, where network namespaces cannot be made.
//!
//! Each cell is the wall-push session cut to 7 s (approach, push with 6 N, hold, release).
//! Criteria, from physical evidence in both summaries (`h4_tests::remote_procs::judge`): every force
//! finite, the slave's true contact force within 1.05 × the slave's own limit (84 N at its
//! 80 N), the rendered force within `coupling.force_limit_n`, both passivity observers
//! ≥ −1 mJ, round trips completed — the energy floor and force limits of the simulated
//! matrix (`tests/delay_matrix.rs`); its
//! oscillation detector needs the per-cycle trace and is not applied to processes (as in
//! `loopback`). Controls: the measured round trip is at least the cell's (the impairment is
//! really there); loss cells lost messages; and a negative control (passivity, the local
//! model and the local damping off, aluminium, 250 ms) must fail the same criteria.
//!
//! Host stalls: two more cells (Zenoh on resin and iceoryx2 on aluminium, 250 ms, 5 % loss)
//! run the whole 14 s session (both pushes) and stop both processes together
//! (SIGSTOP/SIGCONT) for 40 ms every 500 ms (this VM's host
//! stalls 3–66 ms, a few times a minute: the same kind, more often), under the same
//! criteria; they are not re-run for starvation (they are starved by design). Their
//! control: the iceoryx2 aluminium cell with stalls and without the master's discrete-time
//! damping bound (`passivity.damping_step_fraction = 0` and `damping_hold_memory_ms = 0`)
//! must fail (measured: the handle chatters, the master's observer to −12…−918 mJ, as in
//! CI's failure; the simulated version is `tests/host_stalls.rs`).
//!
//! One Zenoh cell (aluminium, 50 ms, 5 %) has the relay drop from the first datagram on (the
//! handshake and declarations too; the others start dropping once the session is up, see
//! `lossy_once_up`): the session must come up and the cell meet the criteria.
//!
//! Both loops run under `--fifo-priority 10` (as in `tests/processes.rs`). Cells run two at a
//! time (each is two 1 kHz loops at ~15–20 % of a core). Every cell runs once: a cell that
//! fails fails, unless the outside witness of host stalls (`h4_tests::stalls`, one sentinel
//! per CPU under `SCHED_FIFO` 99, running through the whole test) saw the host freeze a CPU
//! for at least [`EXCUSE_STALL_MS`] while the cell ran. The test prints each excused cell
//! with its stall, and at most [`MAX_EXCUSED`] cells may be excused. Nothing asserts a
//! wall-clock duration.
//! ≈ 2.5 min on 2 cores.
//! `cargo test --release -p h4-tests --test real_delay_matrix -- --nocapture` prints the table.
//! For diagnosis: `H4_REAL_MATRIX_ONLY=<part of a cell's name>` runs only the cells whose name
//! holds it (`ZenohRelay-Resin-rtt250-loss0.05`), and `H4_REAL_MATRIX_RECORD=<dir>` has both
//! processes record (`--record`) into that directory; `H4_REAL_MATRIX_SET="key=value;…"`
//! adds `--set` overrides to every cell.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::SocketAddr;
use std::process::Command;
use std::sync::Mutex;

use h4_master::server::MasterRunSummary;
use h4_slave_sim::server::SimRunSummary;
use h4_tests::netns::{Host, TwoHosts};
use h4_tests::relay::{Proto, Relay};
use h4_tests::remote_procs::{self, Running, Scratch};
use h4_tests::stalls::{StallWitness, long_stalls};
use h4_transport::impair::ImpairmentConfig;

const SESSION: &str = "config/sessions/wall-push.toml";
const DURATION_S: f64 = 7.0;
/// The stalled cells run the whole wall-push session (both pushes): twice the contact time
/// under stalls, so that the control's chatter is not left to the chance of the stalls that
/// fall in one push (with one push, 6 of 7 runs chattered; measured 2026-12-02).
const STALLED_DURATION_S: f64 = 14.0;
const RTT_MS: [f64; 4] = [0.0, 50.0, 250.0, 1000.0];
const LOSS: [f64; 2] = [0.0, 0.05];
const CONCURRENT: usize = 2;
/// A failing cell is excused only by a host stall at least this long, seen by the witness
/// while it ran, ms (the stalls that starve a 1 kHz loop; this VM's are 2–66 ms).
const EXCUSE_STALL_MS: f64 = 5.0;
/// At most this many cells may be excused by host stalls.
const MAX_EXCUSED: usize = 2;
/// The witness's sentinels wake every this, µs (every millisecond they see stalls of
/// ≥ 1.5 ms, `tests/src/stalls.rs`).
const WITNESS_PERIOD_US: u64 = 1000;
/// A stalled cell's stalls: length, ms, and the time from one stall's start to the next's.
/// 40 ms is within the 3–66 ms this VM's host stalls for; every 500 ms (about 13 stalls in
/// a cell, several in the contact) is harsher than its few a minute, so that the control's
/// chatter is not left to the chance of one or two stalls.
const STALL_MS: u64 = 40;
const STALL_EVERY_MS: u64 = 500;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Wall {
    Resin,
    Aluminium,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Via {
    Iceoryx2Impair,
    ZenohRelay,
}

#[derive(Clone, Copy, Debug)]
struct Cell {
    rtt_ms: f64,
    loss: f64,
    wall: Wall,
    via: Via,
    /// Passivity control and the master's local model (off only in the negative control).
    protected: bool,
    /// Both processes are stopped together (SIGSTOP/SIGCONT) for [`STALL_MS`] every
    /// [`STALL_EVERY_MS`], as this VM's host stalls them (`tests/host_stalls.rs` on the
    /// simulated clock).
    stalls: bool,
    /// Zenoh cells: the relay drops from the first datagram on (the session's handshake and
    /// declarations included), not only once the session is up.
    lossy_from_start: bool,
    /// The master's discrete-time damping bound (`passivity.damping_step_fraction` and
    /// `passivity.damping_hold_memory_ms`; off only in the stall control).
    damping_bound: bool,
}

impl Cell {
    fn name(&self) -> String {
        format!(
            "{:?}-{:?}-rtt{}-loss{}{}{}{}{}",
            self.via,
            self.wall,
            self.rtt_ms,
            self.loss,
            if self.protected { "" } else { "-bare" },
            if self.stalls { "-stalled" } else { "" },
            if self.lossy_from_start {
                "-lossy-from-start"
            } else {
                ""
            },
            if self.damping_bound { "" } else { "-unbounded" }
        )
    }

    fn overrides(&self) -> Vec<String> {
        let material = match self.wall {
            Wall::Resin => "resin",
            Wall::Aluminium => "aluminium",
        };
        let mut o = vec![
            format!("environment.material={material}"),
            "environment.stiffness_n_per_mm=0".into(),
            format!("duration_s={}", self.duration_s()),
            format!("passivity.enabled={}", self.protected),
            format!("coupling.model={}", self.protected),
        ];
        if !self.protected {
            // Unprotected: no local damping either. With it (0.3 + 0.7 N·s/mm in contact,
            // bounded per direction since 2026-12-02) the bare coupling only reached −3.7 mJ,
            // too near the criterion for a control; without, −1 222…−1 287 mJ and 46–48 N.
            o.push("coupling.master_damping_n_s_per_mm=0".into());
            o.push("coupling.contact_damping_n_s_per_mm=0".into());
        }
        if !self.damping_bound {
            // Neither the per-direction bound nor the hold it counts (the master as CI
            // first saw it chatter).
            o.push("passivity.damping_step_fraction=0".into());
            o.push("passivity.damping_hold_memory_ms=0".into());
        }
        // Experiments: `H4_REAL_MATRIX_SET="key=value;key=value"` appended to every cell.
        if let Ok(extra) = std::env::var("H4_REAL_MATRIX_SET") {
            o.extend(
                extra
                    .split(';')
                    .filter(|kv| !kv.trim().is_empty())
                    .map(|kv| kv.trim().to_string()),
            );
        }
        o
    }

    /// The cell's session length, s.
    fn duration_s(&self) -> f64 {
        if self.stalls {
            STALLED_DURATION_S
        } else {
            DURATION_S
        }
    }

    /// A negative control: it must fail the criteria.
    fn is_control(&self) -> bool {
        !self.protected || !self.damping_bound
    }

    fn impairment(&self, seed: u64) -> ImpairmentConfig {
        ImpairmentConfig {
            delay_ms: self.rtt_ms / 2.0,
            loss: self.loss,
            seed,
            ..ImpairmentConfig::default()
        }
    }
}

struct Outcome {
    cell: Cell,
    reasons: Vec<String>,
    master: MasterRunSummary,
    slave: SimRunSummary,
    /// Messages lost on the way (impairment counters or the relay's), both directions.
    lost: u64,
    /// Either loop missed more than 1 % of its deadlines.
    starved: bool,
    /// When it ran, `[from_ns, to_ns]` on `CLOCK_MONOTONIC` (for the stall witness).
    window_ns: [u64; 2],
    /// The session's `coupling.force_limit_n`, N.
    coupling_limit_n: f64,
}

/// `impair (…): sent N, delivered N, lost L, blacked out B, …` lines of a process's stderr:
/// the lost + blacked-out count.
fn impair_lost(log: &str) -> u64 {
    let field = |line: &str, key: &str| -> u64 {
        line.split(", ")
            .find_map(|p| p.trim().strip_prefix(key))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(0)
    };
    log.lines()
        .filter(|l| l.starts_with("impair ("))
        .map(|l| field(l, "lost ") + field(l, "blacked out "))
        .sum()
}

fn run_cell(cell: Cell, scratch: &Scratch) -> Result<Outcome, String> {
    let started_ns = h4_telemetry::rt::monotonic_ns();
    let (master_bin, slave_bin) = remote_procs::binaries()?;
    let tag = cell.name();
    let (world, passivity) = remote_procs::slave_config(scratch, &tag, SESSION, &cell.overrides())?;
    let slave_summary = scratch.path(&format!("{tag}-slave.json"));
    let master_summary = scratch.path(&format!("{tag}-master.json"));
    let seed = 11;
    let hosts = match cell.via {
        Via::ZenohRelay => Some(TwoHosts::new()?),
        Via::Iceoryx2Impair => None,
    };
    let mut slave_cmd = match &hosts {
        Some(h) => h.command(Host::Slave, slave_bin),
        None => Command::new(slave_bin),
    };
    slave_cmd
        .arg("run")
        .arg("--config")
        .arg(&world)
        .arg("--passivity-config")
        .arg(&passivity)
        .arg("--summary")
        .arg(&slave_summary)
        .args(["--fifo-priority", "10"]);
    // A handshake that lost a datagram is retried after Zenoh's 10 s open timeout.
    let wait_s = if cell.lossy_from_start { 60.0 } else { 30.0 };
    let mut master_cmd = match &hosts {
        Some(h) => h.command(Host::Master, master_bin),
        None => Command::new(master_bin),
    };
    master_cmd.arg("run").arg("--config").arg(SESSION);
    if let Some(dir) = std::env::var_os("H4_REAL_MATRIX_RECORD") {
        let dir = std::path::PathBuf::from(dir);
        master_cmd
            .arg("--record")
            .arg(dir.join(format!("{tag}-master.mcap")));
        slave_cmd
            .arg("--record")
            .arg(dir.join(format!("{tag}-slave.mcap")));
    }
    for o in cell.overrides() {
        master_cmd.arg("--set").arg(o);
    }
    if remote_procs::is_control(&cell.overrides()) {
        // The bare cells turn passivity (a safety layer) off.
        master_cmd.arg("--unsafe-test-override");
        slave_cmd.arg("--unsafe-test-override");
    }
    master_cmd
        .args(["--duration-s", &cell.duration_s().to_string()])
        .args(["--wait-for-slave-s", &wait_s.to_string()])
        .arg("--summary")
        .arg(&master_summary)
        .args(["--fifo-priority", "10"]);
    let prefix = format!("{}-{}", scratch.prefix, tag);
    let slave_port = 7447;
    let relay = match &hosts {
        Some(h) => {
            let target = SocketAddr::new(h.ip(Host::Slave).into(), slave_port);
            slave_cmd.args(["--transport", "zenoh", "--zenoh-listen"]);
            slave_cmd.arg(format!("udp/{target}"));
            // Loss starts once the session is up (see `lossy_once_up`), or at once.
            let relay = Relay::start(
                h,
                Proto::Udp,
                target,
                ImpairmentConfig {
                    loss: if cell.lossy_from_start {
                        cell.loss
                    } else {
                        0.0
                    },
                    ..cell.impairment(seed)
                },
            )?;
            master_cmd.args(["--transport", "zenoh", "--zenoh-connect"]);
            master_cmd.arg(format!("udp/{}", relay.listen_addr()));
            Some(relay)
        }
        None => {
            let impair = format!(
                "delay_ms={},loss={},seed={seed}",
                cell.rtt_ms / 2.0,
                cell.loss
            );
            for c in [&mut slave_cmd, &mut master_cmd] {
                c.args(["--iceoryx2-prefix", &prefix, "--impair", &impair]);
            }
            None
        }
    };
    let mut slave = Running::spawn(&format!("{tag}-slave"), slave_cmd, scratch)?;
    let mut master = Running::spawn(&format!("{tag}-master"), master_cmd, scratch)?;
    if let Some(r) = relay.as_ref().filter(|_| !cell.lossy_from_start) {
        lossy_once_up(r, &mut master, cell.impairment(seed));
    }
    let pids = [master.pid(), slave.pid()];
    let done = std::sync::atomic::AtomicBool::new(false);
    let master_ok = std::thread::scope(|s| {
        if cell.stalls {
            s.spawn(|| stall_until(&pids, &done));
        }
        let r = master.wait(cell.duration_s() + wait_s + 30.0);
        done.store(true, std::sync::atomic::Ordering::SeqCst);
        r
    })?;
    slave.stop()?;
    if !master_ok {
        return Err(format!(
            "{tag}: the master failed:\n{}\nslave:\n{}",
            master.log(),
            slave.log()
        ));
    }
    let m: MasterRunSummary = remote_procs::read_summary(&master_summary)?;
    let s: SimRunSummary = remote_procs::read_summary(&slave_summary)?;
    let lost = match &relay {
        Some(r) => r.counters().dropped,
        None => impair_lost(&slave.log()) + impair_lost(&master.log()),
    };
    drop(relay);
    drop(hosts);
    Ok(Outcome {
        cell,
        reasons: remote_procs::judge(&m, &s, &remote_procs::session(SESSION, &cell.overrides())?),
        starved: remote_procs::starved(&m, &s),
        master: m,
        slave: s,
        lost,
        window_ns: [started_ns, h4_telemetry::rt::monotonic_ns()],
        coupling_limit_n: remote_procs::session(SESSION, &cell.overrides())?
            .coupling
            .force_limit_n,
    })
}

/// The relay forwards losslessly until the session carries traffic (1000 datagrams, about
/// half a second of both directions, or the master gave up), then drops with the cell's
/// probability for the rest of the run: Zenoh retries a UDP handshake that lost a datagram
/// only after its 10 s open timeout, which would put 10–20 s of waiting into every loss
/// cell. One cell (`lossy_from_start`) drops from the first datagram on. (Until
/// 2026-12-02 the relay sent every client's datagrams from one socket, unlike a NAT, and
/// the slave's Zenoh never accepted a retry from the failed handshake's address: no cell
/// lossy from the start ever came up, which was blamed on Zenoh.)
fn lossy_once_up(relay: &Relay, master: &mut Running, cfg: ImpairmentConfig) {
    let t = std::time::Instant::now();
    while relay.counters().forwarded < 1000 && !master.exited() && t.elapsed().as_secs() < 60 {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    relay.set(cfg);
}

/// Stops both processes together for [`STALL_MS`] every [`STALL_EVERY_MS`] (the first after
/// 1.5 s, in the approach or the push) until `done`.
fn stall_until(pids: &[i32; 2], done: &std::sync::atomic::AtomicBool) {
    use std::sync::atomic::Ordering;
    use std::time::Duration;
    let signal = |sig: i32| {
        for &pid in pids {
            if pid > 0 && !done.load(Ordering::SeqCst) {
                // SAFETY: plain syscall on the test's own children, not yet reaped (the
                // master is reaped only after `done` is set; the slave after the scope).
                unsafe {
                    libc::kill(pid, sig);
                }
            }
        }
    };
    std::thread::sleep(Duration::from_millis(1500));
    while !done.load(Ordering::SeqCst) {
        signal(libc::SIGSTOP);
        std::thread::sleep(Duration::from_millis(STALL_MS));
        // Always continued, even once done (a stopped process would never finish).
        for &pid in pids {
            if pid > 0 {
                // SAFETY: as above.
                unsafe {
                    libc::kill(pid, libc::SIGCONT);
                }
            }
        }
        std::thread::sleep(Duration::from_millis(STALL_EVERY_MS - STALL_MS));
    }
}

/// Runs `cells`, `CONCURRENT` at a time.
fn run_all(cells: Vec<Cell>, scratch: &Scratch) -> Vec<Result<Outcome, String>> {
    let queue = Mutex::new(cells.into_iter().enumerate().collect::<Vec<_>>());
    let results = Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..CONCURRENT {
            s.spawn(|| {
                loop {
                    let next = queue.lock().unwrap().pop();
                    let Some((i, cell)) = next else { break };
                    let r = run_cell(cell, scratch);
                    results.lock().unwrap().push((i, r));
                }
            });
        }
    });
    let mut r = results.into_inner().unwrap();
    r.sort_by_key(|(i, _)| *i);
    r.into_iter().map(|(_, r)| r).collect()
}

fn row(o: &Outcome) -> String {
    format!(
        "| {:?} | {:?} | {} | {:.0} % | {} | {:.2} ({:.0}) | {:.1} / {:.0} | {:.3} / {:.3} | {:.0} | {} | {} | {} + {} | {} |",
        o.cell.via,
        o.cell.wall,
        o.cell.rtt_ms,
        o.cell.loss * 100.0,
        if o.reasons.is_empty() { "yes" } else { "NO" },
        o.slave.max_force_n,
        o.slave.force_limit_n,
        o.master.max_rendered_force_n,
        o.coupling_limit_n,
        o.master.energy_min_j * 1e3,
        o.slave.energy_min_j * 1e3,
        o.master.round_trip_p50_us / 1e3,
        o.lost,
        o.slave.safe_stops,
        o.master.run.deadline_misses,
        o.slave.run.deadline_misses,
        if o.starved { "yes" } else { "no" },
    )
}

#[test]
fn real_processes_meet_the_matrix_criteria_over_iceoryx2_and_zenoh() {
    let scratch = Scratch::new("real-matrix").unwrap();
    let zenoh = match TwoHosts::new_or_skip("real_delay_matrix (the Zenoh-over-relay cells)") {
        Some(h) => {
            drop(h);
            true
        }
        None => false,
    };
    let mut cells = Vec::new();
    for via in [Via::Iceoryx2Impair, Via::ZenohRelay] {
        if via == Via::ZenohRelay && !zenoh {
            continue;
        }
        for wall in [Wall::Resin, Wall::Aluminium] {
            for rtt_ms in RTT_MS {
                for loss in LOSS {
                    cells.push(Cell {
                        rtt_ms,
                        loss,
                        wall,
                        via,
                        protected: true,
                        stalls: false,
                        damping_bound: true,
                        lossy_from_start: false,
                    });
                }
            }
        }
    }
    // Negative control: no passivity control, no local model, the stiff wall, 250 ms.
    let control = Cell {
        rtt_ms: 250.0,
        loss: 0.0,
        wall: Wall::Aluminium,
        via: Via::Iceoryx2Impair,
        protected: false,
        stalls: false,
        damping_bound: true,
        lossy_from_start: false,
    };
    cells.push(control);
    // Host stalls on the paths and walls CI found them on (2026-12-02: the Zenoh resin cell
    // at 250 ms and 5 % loss chattered at 125 Hz after a stall; docs/processes.md).
    for (via, wall) in [
        (Via::ZenohRelay, Wall::Resin),
        (Via::Iceoryx2Impair, Wall::Aluminium),
    ] {
        if via == Via::ZenohRelay && !zenoh {
            continue;
        }
        cells.push(Cell {
            rtt_ms: 250.0,
            loss: 0.05,
            wall,
            via,
            protected: true,
            stalls: true,
            damping_bound: true,
            lossy_from_start: false,
        });
    }
    // Its control: without the master's damping bound the stalls start the chatter.
    cells.push(Cell {
        rtt_ms: 250.0,
        loss: 0.05,
        wall: Wall::Aluminium,
        via: Via::Iceoryx2Impair,
        protected: true,
        stalls: true,
        damping_bound: false,
        lossy_from_start: false,
    });
    // Zenoh over UDP lossy from the first datagram (handshake and declarations too): the
    // session comes up (Zenoh retries the handshake) and the cell meets the criteria.
    if zenoh {
        cells.push(Cell {
            rtt_ms: 50.0,
            loss: 0.05,
            wall: Wall::Aluminium,
            via: Via::ZenohRelay,
            protected: true,
            stalls: false,
            damping_bound: true,
            lossy_from_start: true,
        });
    }
    if let Ok(only) = std::env::var("H4_REAL_MATRIX_ONLY") {
        cells.retain(|c| c.name().contains(&only));
    }
    let witness = StallWitness::start(std::time::Duration::from_micros(WITNESS_PERIOD_US));
    let results = run_all(cells, &scratch);
    let stalls = witness.stop();
    println!(
        "stall witness: {} stalls seen (longest {:.1} ms), trustworthy {}",
        stalls.count(),
        stalls.longest_ms(),
        stalls.trustworthy()
    );
    println!(
        "| path | wall | round trip ms | loss | meets the criteria | max true force N (slave's limit) | max rendered N / limit | observers min master / slave mJ | measured rtt p50 ms | lost msgs | safe stops | deadline misses master + slave | starved |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut failures = Vec::new();
    let mut excused = Vec::new();
    for r in &results {
        let o = match r {
            Ok(o) => o,
            Err(e) => {
                failures.push(e.clone());
                continue;
            }
        };
        println!("{}", row(o));
        let name = o.cell.name();
        if o.cell.is_control() {
            if o.reasons.is_empty() {
                failures.push(format!(
                    "{name}: the negative control passed the criteria (they cannot fail?)"
                ));
            }
            continue;
        }
        if !o.reasons.is_empty() {
            // A stalled cell's stalls are its own (SIGSTOP), not the host's: never excused.
            let stall = long_stalls(Some(&stalls), &[], EXCUSE_STALL_MS)
                .into_iter()
                .find(|g| g[0] < o.window_ns[1] && g[1] > o.window_ns[0])
                .filter(|_| !o.cell.stalls && stalls.trustworthy());
            match stall {
                Some(g) => excused.push(format!(
                    "{name}: {} — excused: the host froze a CPU for {:.1} ms while it ran",
                    o.reasons.join("; "),
                    (g[1] - g[0]) as f64 / 1e6
                )),
                None => failures.push(format!(
                    "{name}: {}{}",
                    o.reasons.join("; "),
                    if o.starved {
                        " (a loop was starved, and the witness saw no host stall)"
                    } else {
                        ""
                    }
                )),
            }
        }
        // The impairment was really there: the measured round trip includes it.
        if o.master.round_trip_p50_us < o.cell.rtt_ms * 1e3 {
            failures.push(format!(
                "{name}: measured round trip p50 {:.1} ms < the cell's {} ms",
                o.master.round_trip_p50_us / 1e3,
                o.cell.rtt_ms
            ));
        }
        if o.cell.loss > 0.0 && o.lost == 0 {
            failures.push(format!("{name}: a loss cell lost nothing"));
        }
        // The session made contact (the wall was touched).
        if o.slave.max_force_n < 2.0 {
            failures.push(format!("{name}: no contact ({:.1} N)", o.slave.max_force_n));
        }
    }
    println!(
        "excused by host stalls: {} of {} cells (at most {MAX_EXCUSED})",
        excused.len(),
        results.len()
    );
    for e in &excused {
        println!("  {e}");
    }
    if excused.len() > MAX_EXCUSED {
        failures.push(format!(
            "{} cells excused by host stalls, more than {MAX_EXCUSED}: {excused:#?}",
            excused.len()
        ));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
