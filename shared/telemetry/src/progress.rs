//! Progress of the long runs (`sim`, `experiment`, `matrix`, `run`, `loopback`) on stderr:
//! an indicatif bar on a terminal, a plain line every few seconds otherwise (CI logs, pipes),
//! nothing when switched off.
//!
//! The work (a simulation loop, a 1 kHz real-time loop, the matrix's workers) only stores its
//! position in an atomic ([`ProgressHandle::set`]) and, now and then, copies a short detail
//! text into a buffer allocated once ([`ProgressHandle::set_detail`], a `try_lock`: never
//! blocks, never allocates). A reporter thread of its own, at normal scheduling, draws the bar
//! or prints the lines: nothing is formatted for stderr on the worker's thread.
//!
//! The mode: `H4_PROGRESS=bar|plain|off` if set, else a bar when stderr is a terminal and
//! plain lines when it is not. Plain mode prints a first line when the run starts, then one
//! every [`PLAIN_INTERVAL_S`] seconds, or `H4_PROGRESS_INTERVAL_S` (a positive number of
//! seconds) if set.

use std::io::{IsTerminal, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Seconds between two plain progress lines (stderr not a terminal).
pub const PLAIN_INTERVAL_S: f64 = 2.0;
/// How often the bar is redrawn and the detail text is asked for on a terminal, s.
const BAR_INTERVAL_S: f64 = 0.25;
/// Capacity of the detail text, bytes (longer texts are cut at a character boundary).
const DETAIL_CAPACITY: usize = 480;

/// How progress is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// An indicatif bar (or spinner, when the end is unknown), redrawn in place.
    Bar,
    /// One plain line every interval.
    Plain,
    /// Nothing.
    Off,
}

/// How a command shows its progress: the mode, the interval of plain lines and the label
/// that starts each line (the command, e.g. `h4-master sim`).
#[derive(Clone, Debug, PartialEq)]
pub struct ProgressConfig {
    /// The mode.
    pub mode: Mode,
    /// Seconds between plain lines.
    pub plain_interval_s: f64,
    /// What each line starts with.
    pub label: String,
}

impl ProgressConfig {
    /// From the environment (see the module doc), with `label`.
    pub fn from_env(label: &str) -> Self {
        let mode = match std::env::var("H4_PROGRESS").ok().as_deref().map(str::trim) {
            Some("bar") => Mode::Bar,
            Some("plain") => Mode::Plain,
            Some("off") => Mode::Off,
            _ if std::io::stderr().is_terminal() => Mode::Bar,
            _ => Mode::Plain,
        };
        let plain_interval_s = std::env::var("H4_PROGRESS_INTERVAL_S")
            .ok()
            .and_then(|v| v.trim().parse::<f64>().ok())
            .filter(|v| v.is_finite() && *v > 0.0)
            .unwrap_or(PLAIN_INTERVAL_S);
        ProgressConfig {
            mode,
            plain_interval_s,
            label: label.to_string(),
        }
    }

    /// No progress at all (library callers and tests that do not want it).
    pub fn off() -> Self {
        ProgressConfig {
            mode: Mode::Off,
            plain_interval_s: PLAIN_INTERVAL_S,
            label: String::new(),
        }
    }

    /// How often the work should refresh its detail text: a few times a second for a bar,
    /// four times per plain line (so a line shows a fresh one), never when off.
    pub fn detail_interval_ns(&self) -> Option<u64> {
        match self.mode {
            Mode::Bar => Some((BAR_INTERVAL_S * 1e9) as u64),
            Mode::Plain => Some((self.plain_interval_s * 0.25e9) as u64),
            Mode::Off => None,
        }
    }
}

impl Default for ProgressConfig {
    fn default() -> Self {
        Self::off()
    }
}

/// What a position counts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Unit {
    /// Cycles of this many seconds each, shown as seconds (`5.2 s of 14.0 s`); `what` says
    /// which seconds (`simulated`, or empty for real time).
    Seconds {
        /// Seconds per position step (1 ms cycles: 0.001).
        per_step_s: f64,
        /// A word after the seconds, e.g. `simulated` (empty: none).
        what: &'static str,
    },
    /// Whole items (`37 of 64 cells`).
    Items(&'static str),
}

#[derive(Debug)]
struct Shared {
    position: AtomicU64,
    /// 0: no known end.
    total: AtomicU64,
    detail: Mutex<String>,
    stop: AtomicBool,
}

/// The worker's side of a [`Progress`]: cheap to clone, lock-free to update.
#[derive(Clone, Debug)]
pub struct ProgressHandle {
    shared: Arc<Shared>,
    detail_interval_ns: Option<u64>,
}

impl ProgressHandle {
    /// A handle that shows nothing (no reporter behind it).
    pub fn off() -> Self {
        ProgressHandle {
            shared: Arc::new(Shared {
                position: AtomicU64::new(0),
                total: AtomicU64::new(0),
                detail: Mutex::new(String::new()),
                stop: AtomicBool::new(false),
            }),
            detail_interval_ns: None,
        }
    }

    /// The position now is `pos` (cycles or items).
    pub fn set(&self, pos: u64) {
        self.shared.position.store(pos, Ordering::Relaxed);
    }

    /// Adds `n` to the position.
    pub fn inc(&self, n: u64) {
        self.shared.position.fetch_add(n, Ordering::Relaxed);
    }

    /// The position now.
    pub fn position(&self) -> u64 {
        self.shared.position.load(Ordering::Relaxed)
    }

    /// How often the detail text is wanted (None: never; see
    /// [`ProgressConfig::detail_interval_ns`]).
    pub fn detail_interval_ns(&self) -> Option<u64> {
        self.detail_interval_ns
    }

    /// Replaces the detail text shown after the position. Never blocks (if the reporter is
    /// reading it just now, this text is skipped) and never allocates (the buffer is
    /// allocated once; a longer text is cut at a character boundary).
    pub fn set_detail(&self, text: &str) {
        if self.detail_interval_ns.is_none() {
            return;
        }
        if let Ok(mut d) = self.shared.detail.try_lock() {
            let cap = d.capacity();
            let mut end = text.len().min(cap);
            while !text.is_char_boundary(end) {
                end -= 1;
            }
            d.clear();
            d.push_str(&text[..end]);
        }
    }
}

/// A progress display running on its own thread until [`Progress::finish`] (or drop).
#[derive(Debug)]
pub struct Progress {
    handle: ProgressHandle,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Progress {
    /// The progress of a run on the simulated clock of `duration_s` seconds in 1 ms cycles
    /// (`sim`, `experiment`), labelled `label`, configured from the environment.
    pub fn simulated(label: &str, duration_s: f64) -> Self {
        Progress::start(
            &ProgressConfig::from_env(label),
            Unit::Seconds {
                per_step_s: 1e-3,
                what: "simulated",
            },
            Some((duration_s * 1000.0).round() as u64),
        )
    }

    /// Starts showing the progress of work that counts `unit` up to `total` (None: no known
    /// end: a spinner, and lines without a share). With [`Mode::Off`] no thread is started.
    pub fn start(cfg: &ProgressConfig, unit: Unit, total: Option<u64>) -> Self {
        let handle = ProgressHandle {
            shared: Arc::new(Shared {
                position: AtomicU64::new(0),
                total: AtomicU64::new(total.unwrap_or(0)),
                detail: Mutex::new(String::with_capacity(DETAIL_CAPACITY)),
                stop: AtomicBool::new(false),
            }),
            detail_interval_ns: cfg.detail_interval_ns(),
        };
        if cfg.mode == Mode::Plain {
            // The first line at once: a run shorter than the interval still says what it is.
            let total = total.unwrap_or(0);
            verdict_line(&cfg.label, &text(unit, 0, total, 0.0, ""));
        }
        let thread = if cfg.mode == Mode::Off {
            None
        } else {
            let shared = Arc::clone(&handle.shared);
            let cfg = cfg.clone();
            std::thread::Builder::new()
                .name("progress".into())
                .spawn(move || report(&cfg, unit, &shared))
                .ok()
        };
        Progress { handle, thread }
    }

    /// The worker's handle.
    pub fn handle(&self) -> ProgressHandle {
        self.handle.clone()
    }

    /// Stops the display: the bar is cleared (the command's verdict line follows), plain
    /// lines simply stop.
    pub fn finish(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        self.handle.shared.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The reporter thread: draws the bar or prints the plain lines until stopped.
fn report(cfg: &ProgressConfig, unit: Unit, shared: &Shared) {
    // A thread started by a loop already under SCHED_FIFO inherits it: printing has no
    // business at real-time priority.
    set_normal_scheduling();
    let started = Instant::now();
    let bar = (cfg.mode == Mode::Bar && cfg!(feature = "bars"))
        .then(|| new_bar(cfg, shared.total.load(Ordering::Relaxed)));
    let tick = Duration::from_secs_f64(if bar.is_some() {
        BAR_INTERVAL_S / 2.0
    } else {
        (cfg.plain_interval_s / 10.0).clamp(0.01, 0.1)
    });
    let interval = Duration::from_secs_f64(cfg.plain_interval_s);
    let mut next_line = started + interval;
    let mut detail = String::with_capacity(DETAIL_CAPACITY);
    while !shared.stop.load(Ordering::SeqCst) {
        std::thread::sleep(tick);
        let pos = shared.position.load(Ordering::Relaxed);
        let total = shared.total.load(Ordering::Relaxed);
        if let Ok(d) = shared.detail.lock() {
            detail.clear();
            detail.push_str(&d);
        }
        let elapsed_s = started.elapsed().as_secs_f64();
        if let Some(bar) = &bar {
            if total > 0 {
                bar.set_length(total);
            }
            bar.set_position(pos);
            bar.set_message(text(unit, pos, total, elapsed_s, &detail));
        } else if Instant::now() >= next_line {
            next_line += interval;
            let line = format!(
                "{}: {}",
                cfg.label,
                text(unit, pos, total, elapsed_s, &detail)
            );
            let mut err = std::io::stderr().lock();
            let _ = writeln!(err, "{line}");
            let _ = err.flush();
        }
    }
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
}

#[cfg(feature = "bars")]
fn new_bar(cfg: &ProgressConfig, total: u64) -> indicatif::ProgressBar {
    use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
    let target = ProgressDrawTarget::stderr_with_hz(8);
    let (len, template) = if total > 0 {
        (Some(total), "{prefix} [{bar:30}] {msg}")
    } else {
        (None, "{prefix} {spinner} {msg}")
    };
    let bar = ProgressBar::with_draw_target(len, target);
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_prefix(cfg.label.clone());
    bar
}

/// Without the `bars` feature (a product crate built alone): no bar, plain lines instead.
#[cfg(not(feature = "bars"))]
fn new_bar(_cfg: &ProgressConfig, _total: u64) -> NoBar {
    NoBar
}

/// The bar's place when the crate is built without indicatif (never constructed: a bar
/// request falls back to plain lines).
#[cfg(not(feature = "bars"))]
struct NoBar;

#[cfg(not(feature = "bars"))]
impl NoBar {
    fn set_length(&self, _: u64) {}
    fn set_position(&self, _: u64) {}
    fn set_message(&self, _: String) {}
    fn finish_and_clear(&self) {}
}

/// One progress text: position (and share of the total), elapsed time, a time-left estimate
/// for known ends, then the detail.
pub fn text(unit: Unit, pos: u64, total: u64, elapsed_s: f64, detail: &str) -> String {
    // Work after the planned end (a slave bringing its arm to rest) shows as the end.
    let pos = if total > 0 { pos.min(total) } else { pos };
    let mut t = match unit {
        Unit::Seconds { per_step_s, what } => {
            let sp = if what.is_empty() { "" } else { " " };
            if total > 0 {
                format!(
                    "{:.1} s of {:.1} s{sp}{what} ({:.0} %)",
                    pos as f64 * per_step_s,
                    total as f64 * per_step_s,
                    100.0 * pos as f64 / total as f64
                )
            } else {
                format!("{:.1} s{sp}{what}", pos as f64 * per_step_s)
            }
        }
        Unit::Items(what) => {
            if total > 0 {
                format!(
                    "{pos} of {total} {what} ({:.0} %)",
                    100.0 * pos as f64 / total as f64
                )
            } else {
                format!("{pos} {what}")
            }
        }
    };
    t.push_str(&format!(", {elapsed_s:.0} s elapsed"));
    if total > 0 && pos > 0 && pos < total && elapsed_s > 0.5 {
        let left = elapsed_s * (total - pos) as f64 / pos as f64;
        t.push_str(&format!(", about {left:.0} s left"));
    }
    if !detail.is_empty() {
        t.push_str(" | ");
        t.push_str(detail);
    }
    t
}

/// `n` with its thousands grouped by spaces, as the verdict lines print counts
/// (`14 000 cycles`).
pub fn grouped(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::with_capacity(digits.len() + digits.len() / 3);
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(' ');
        }
        out.push(c);
    }
    out
}

/// Prints one line on stderr: `label: text` (a run's verdict line, a note).
pub fn verdict_line(label: &str, verdict: &str) {
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "{label}: {verdict}");
    let _ = err.flush();
}

/// The verdict line of a run on the simulated clock stopped by SIGINT after `done_s` of
/// `planned_s` simulated seconds: no verdict.
pub fn interrupted_simulated_line(label: &str, done_s: f64, planned_s: f64) {
    verdict_line(
        label,
        &format!(
            "interrupted after {done_s:.1} of {planned_s:.1} s simulated: no verdict (the summary covers the cycles run)"
        ),
    );
}

/// Puts the calling thread back under normal scheduling (`SCHED_OTHER`): a helper thread
/// started by a loop that runs under `SCHED_FIFO` inherits that policy. Lowering is always
/// permitted; a failure leaves the thread as it was.
pub fn set_normal_scheduling() {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: plain syscall on the calling thread with a valid, initialised parameter.
    let _ = unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &param) };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_are_grouped_by_thousands() {
        assert_eq!(grouped(0), "0");
        assert_eq!(grouped(999), "999");
        assert_eq!(grouped(14_000), "14 000");
        assert_eq!(grouped(1_234_567), "1 234 567");
    }

    #[test]
    fn texts_say_where_the_run_is() {
        let s = Unit::Seconds {
            per_step_s: 1e-3,
            what: "simulated",
        };
        let t = text(s, 5200, 14_000, 2.0, "");
        assert!(
            t.starts_with("5.2 s of 14.0 s simulated (37 %), 2 s elapsed"),
            "{t}"
        );
        assert!(t.contains("about 3 s left"), "{t}");
        let t = text(Unit::Items("cells"), 37, 64, 4.0, "5 unstable");
        assert!(t.starts_with("37 of 64 cells (58 %)"), "{t}");
        assert!(t.ends_with("| 5 unstable"), "{t}");
        let real = Unit::Seconds {
            per_step_s: 1e-3,
            what: "",
        };
        assert!(text(real, 4000, 0, 4.0, "").starts_with("4.0 s, 4 s elapsed"));
    }

    /// A detail longer than the buffer is cut at a character boundary (the buffer never
    /// grows: the process-loop allocation tests count the hand-off itself).
    #[test]
    fn detail_is_cut_to_the_buffer() {
        let p = Progress::start(
            &ProgressConfig {
                mode: Mode::Off,
                ..ProgressConfig::off()
            },
            Unit::Items("x"),
            Some(3),
        );
        let h = ProgressHandle {
            detail_interval_ns: Some(1),
            ..p.handle()
        };
        let long = "é".repeat(400);
        h.set_detail(&long);
        let d = h.shared.detail.lock().unwrap().clone();
        assert!(d.len() <= DETAIL_CAPACITY && long.starts_with(&d) && !d.is_empty());
        assert_eq!(h.shared.detail.lock().unwrap().capacity(), DETAIL_CAPACITY);
        p.finish();
    }
}
