//! Two hosts on one machine: two Linux network namespaces joined by a veth pair, for tests
//! that run the slave on one "host" and the master on the other with a real network
//! (IP, TCP/UDP, the kernel's stack) between them.
//!
//! * Names are unique per test and process (`h4-<pid>-<n>-s` / `-m`), so tests run in
//!   parallel; the addresses are the same in every pair ([`SLAVE_IP`], [`MASTER_IP`]) because
//!   both ends of each veth live inside its own two namespaces.
//! * [`TwoHosts`] removes what it made when dropped, also when the test fails or panics
//!   (unwinding runs `Drop`); namespaces left by a test process that was killed (its pid is
//!   gone) are removed by the next [`TwoHosts::new`].
//! * Without the permission (not root, no CAP_NET_ADMIN, no `ip`) [`TwoHosts::new_or_skip`]
//!   writes `SKIPPED <test>: <why>` straight to the terminal's stderr (not captured by the
//!   test harness, so a skip is never a silent pass) and returns `None`; with
//!   `H4_REQUIRE_NETNS=1` in the environment a missing permission fails the test instead.

use std::io::Write;
use std::net::Ipv4Addr;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};

/// The slave host's address on the veth pair.
pub const SLAVE_IP: Ipv4Addr = Ipv4Addr::new(10, 77, 0, 1);
/// The master host's address on the veth pair.
pub const MASTER_IP: Ipv4Addr = Ipv4Addr::new(10, 77, 0, 2);

static NEXT: AtomicU32 = AtomicU32::new(0);

/// Which of the two hosts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Host {
    /// Where the slave runs (address [`SLAVE_IP`]).
    Slave,
    /// Where the master runs (address [`MASTER_IP`]).
    Master,
}

/// Two network namespaces joined by a veth pair; removed on drop.
#[derive(Debug)]
pub struct TwoHosts {
    slave_ns: String,
    master_ns: String,
}

/// Runs `ip ARGS`; its stderr on failure.
fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot run `ip`: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "`ip {}` failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Removes namespaces `h4-<pid>-…` whose process is gone (a test run that was killed).
fn remove_stale() {
    let Ok(dir) = std::fs::read_dir("/var/run/netns") else {
        return;
    };
    for entry in dir.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(rest) = name.strip_prefix("h4-") else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if !std::path::Path::new(&format!("/proc/{pid}")).exists() {
            let _ = ip(&["netns", "del", &name]);
        }
    }
}

impl TwoHosts {
    /// Builds the two hosts: namespaces, loopback up in each, a veth pair with
    /// [`SLAVE_IP`]/24 and [`MASTER_IP`]/24. Whatever was made is removed on failure.
    pub fn new() -> Result<Self, String> {
        remove_stale();
        let pid = std::process::id();
        let n = NEXT.fetch_add(1, Ordering::SeqCst);
        let hosts = TwoHosts {
            slave_ns: format!("h4-{pid}-{n}-s"),
            master_ns: format!("h4-{pid}-{n}-m"),
        };
        // Interface names: at most 15 characters.
        let (vs, vm) = (format!("h4{pid:x}x{n}s"), format!("h4{pid:x}x{n}m"));
        ip(&["netns", "add", &hosts.slave_ns])?;
        // From here on, dropping `hosts` removes what exists.
        ip(&["netns", "add", &hosts.master_ns])?;
        ip(&[
            "link",
            "add",
            &vs,
            "netns",
            &hosts.slave_ns,
            "type",
            "veth",
            "peer",
            "name",
            &vm,
            "netns",
            &hosts.master_ns,
        ])?;
        for (ns, dev, addr) in [
            (&hosts.slave_ns, &vs, SLAVE_IP),
            (&hosts.master_ns, &vm, MASTER_IP),
        ] {
            ip(&["-n", ns, "link", "set", "lo", "up"])?;
            ip(&["-n", ns, "addr", "add", &format!("{addr}/24"), "dev", dev])?;
            ip(&["-n", ns, "link", "set", dev, "up"])?;
        }
        Ok(hosts)
    }

    /// [`TwoHosts::new`], or `None` after writing `SKIPPED <test>: <why>` to stderr (not
    /// captured) when this machine does not allow it. With `H4_REQUIRE_NETNS=1` it panics
    /// instead of skipping.
    pub fn new_or_skip(test: &str) -> Option<Self> {
        match Self::new() {
            Ok(h) => Some(h),
            Err(why) => {
                let msg = format!(
                    "SKIPPED {test}: two network namespaces could not be made (needs root or CAP_NET_ADMIN and iproute2): {why}"
                );
                assert!(
                    std::env::var_os("H4_REQUIRE_NETNS").is_none(),
                    "{msg} (H4_REQUIRE_NETNS is set)"
                );
                let _ = writeln!(std::io::stderr().lock(), "{msg}");
                None
            }
        }
    }

    /// The namespace's name of `host`.
    pub fn namespace(&self, host: Host) -> &str {
        match host {
            Host::Slave => &self.slave_ns,
            Host::Master => &self.master_ns,
        }
    }

    /// The address of `host` on the veth pair.
    pub fn ip(&self, host: Host) -> Ipv4Addr {
        match host {
            Host::Slave => SLAVE_IP,
            Host::Master => MASTER_IP,
        }
    }

    /// A command that runs `program` on `host` (`ip netns exec NS program`; `ip` execs it,
    /// so the child's pid is the program's and signals reach it).
    pub fn command(&self, host: Host, program: &std::path::Path) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", self.namespace(host)]).arg(program);
        c
    }

    /// Moves the calling thread into `host`'s network namespace (sockets it creates from
    /// now on live there). For helper threads such as the relay.
    pub fn enter(&self, host: Host) -> Result<(), String> {
        enter_namespace(self.namespace(host))
    }
}

/// Moves the calling thread into the named network namespace (`/var/run/netns/NAME`).
pub fn enter_namespace(name: &str) -> Result<(), String> {
    use std::os::fd::AsRawFd;
    let path = format!("/var/run/netns/{name}");
    let f = std::fs::File::open(&path).map_err(|e| format!("{path}: {e}"))?;
    // SAFETY: setns on a valid, open namespace file descriptor; affects only this thread.
    let rc = unsafe { libc::setns(f.as_raw_fd(), libc::CLONE_NEWNET) };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!("setns {path}: {}", std::io::Error::last_os_error()))
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        // Deleting a namespace destroys the veth end inside it, and with it the pair.
        for ns in [&self.master_ns, &self.slave_ns] {
            if std::path::Path::new(&format!("/var/run/netns/{ns}")).exists()
                && let Err(e) = ip(&["netns", "del", ns])
            {
                let _ = writeln!(std::io::stderr().lock(), "warning: {e}");
            }
        }
    }
}
