//! The delay matrix: one session file (`config/sessions/wall-push.toml` by default) run over
//! wall × round trip × jitter × loss × `scale.force` on the simulated clock, each cell judged
//! by the session's stability detector ([`crate::session::Summary`]) and by the matrix's own
//! criteria: the guarantees ([`safety_misses`]) and issue 12's targets ([`misses`]).
//!
//! `h4-master matrix` runs it as a command (progress, tables, a heat map per wall);
//! `tests/delay_matrix.rs` asserts on it. Both build their cells with [`Case`] and run them
//! with [`Matrix::run_all`].

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use serde::Serialize;

use crate::session::{self, SessionConfig, SessionError, Summary};

/// The shipped matrix's round trips, ms.
pub const RTT_MS: [f64; 8] = [0.0, 10.0, 50.0, 100.0, 250.0, 500.0, 1000.0, 2000.0];
/// The round trips of the shipped matrix's `scale.force` 1.0 rows, ms.
pub const RTT_SCALE_1_MS: [f64; 4] = [0.0, 10.0, 50.0, 100.0];
/// Jitter as a share of the one-way delay.
pub const JITTER: [f64; 2] = [0.0, 0.2];
/// The losses of the shipped matrix.
pub const LOSS: [Loss; 4] = [Loss::None, Loss::P5, Loss::P20, Loss::Blackout];
/// The walls of the shipped matrix.
pub const WALLS: [Wall; 4] = [Wall::SOFT, Wall::RESIN, Wall::ALUMINIUM, Wall::STEEL];

/// The link's losses in a cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Loss {
    /// None.
    None,
    /// 5 % of the messages, independently.
    P5,
    /// 20 % of the messages, independently.
    P20,
    /// 200 ms blackouts every 2 s.
    Blackout,
}

impl Loss {
    /// The name `--losses` takes and the tables print: `none`, `5%`, `20%`, `blackout`.
    pub fn name(self) -> &'static str {
        match self {
            Loss::None => "none",
            Loss::P5 => "5%",
            Loss::P20 => "20%",
            Loss::Blackout => "blackout",
        }
    }

    /// Parses [`Loss::name`] (`5` and `20` without `%` too).
    pub fn parse(text: &str) -> Result<Self, String> {
        match text.trim() {
            "none" | "0" | "0%" => Ok(Loss::None),
            "5%" | "5" => Ok(Loss::P5),
            "20%" | "20" => Ok(Loss::P20),
            "blackout" | "blackouts" => Ok(Loss::Blackout),
            other => Err(format!(
                "loss {other:?}: expected none, 5%, 20% or blackout"
            )),
        }
    }
}

/// A wall, by its stiffness.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Wall {
    /// Stiffness, N/mm.
    pub stiffness_n_per_mm: f64,
}

impl Wall {
    /// A soft wall, 1 N/mm.
    pub const SOFT: Wall = Wall {
        stiffness_n_per_mm: 1.0,
    };
    /// Resin, 200 N/mm.
    pub const RESIN: Wall = Wall {
        stiffness_n_per_mm: 200.0,
    };
    /// Aluminium, 1000 N/mm.
    pub const ALUMINIUM: Wall = Wall {
        stiffness_n_per_mm: 1000.0,
    };
    /// Steel, 2000 N/mm.
    pub const STEEL: Wall = Wall {
        stiffness_n_per_mm: 2000.0,
    };

    /// `soft`, `resin`, `aluminium`, `steel` for the named walls, else `<k> N/mm`.
    pub fn name(self) -> String {
        for (w, n) in [
            (Wall::SOFT, "soft"),
            (Wall::RESIN, "resin"),
            (Wall::ALUMINIUM, "aluminium"),
            (Wall::STEEL, "steel"),
        ] {
            if w == self {
                return n.to_string();
            }
        }
        format!("{} N/mm", self.stiffness_n_per_mm)
    }

    /// A metal wall (1000 N/mm and stiffer): its first touch may peak higher.
    pub fn metal(self) -> bool {
        self.stiffness_n_per_mm >= 1000.0
    }

    /// Parses a wall name (`soft`, `resin`, `aluminium`/`aluminum`, `steel`) or a stiffness
    /// in N/mm (`500`).
    pub fn parse(text: &str) -> Result<Self, String> {
        let t = text.trim();
        match t {
            "soft" => return Ok(Wall::SOFT),
            "resin" => return Ok(Wall::RESIN),
            "aluminium" | "aluminum" => return Ok(Wall::ALUMINIUM),
            "steel" => return Ok(Wall::STEEL),
            _ => {}
        }
        match t.trim_end_matches("N/mm").trim().parse::<f64>() {
            Ok(k) if k.is_finite() && (0.1..=1e6).contains(&k) => Ok(Wall {
                stiffness_n_per_mm: k,
            }),
            _ => Err(format!(
                "wall {t:?}: expected soft, resin, aluminium, steel or a stiffness in N/mm (0.1 to 1e6)"
            )),
        }
    }
}

/// One cell of the matrix: the link, the wall, the force scale and the layers on or off.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Case {
    /// Round trip, ms (each direction delays half of it).
    pub rtt_ms: f64,
    /// Jitter, share of the one-way delay.
    pub jitter: f64,
    /// Loss.
    pub loss: Loss,
    /// The wall.
    pub wall: Wall,
    /// `scale.force`.
    pub force_scale: f64,
    /// The passivity layer (`passivity.enabled`).
    pub passivity: bool,
    /// The master's local contact model (`coupling.model`, off in wall-push.toml).
    pub model: bool,
    /// The slave's contact hand-over (`slave.contact.enabled`, on by default).
    pub handover: bool,
    /// The session's seed.
    pub seed: u64,
    /// The round trip the slave is told (`slave.contact.round_trip_ms`, its fallback before
    /// it has measured one), as a share of the cell's: 1 the nominal one, 0 not told
    /// (shipped since protocol 3: the slave measures its round trip).
    pub round_trip_told: f64,
    /// The slave measures its round trip from the commands' echo
    /// (`slave.contact.measure_round_trip`, shipped on); off: only the told figure.
    pub measure_round_trip: bool,
}

impl Case {
    /// A cell with the shipped layers (passivity on, model off, hand-over on) and seed 4.
    pub fn shipped(rtt_ms: f64, jitter: f64, loss: Loss, wall: Wall, force_scale: f64) -> Self {
        Case {
            rtt_ms,
            jitter,
            loss,
            wall,
            force_scale,
            passivity: true,
            model: false,
            handover: true,
            seed: 4,
            round_trip_told: 0.0,
            measure_round_trip: true,
        }
    }

    /// The `--set` overrides that make the session file this cell.
    pub fn overrides(&self) -> Vec<String> {
        let one_way = self.rtt_ms / 2.0;
        let mut o = vec![
            format!("link.delay_ms={one_way}"),
            format!("link.jitter_ms={}", one_way * self.jitter),
            format!("passivity.enabled={}", self.passivity),
            format!("coupling.model={}", self.model),
            format!("slave.contact.enabled={}", self.handover),
            // The slave measures its link's round trip (the hand-over spring softens over
            // it); a told one is its fallback before the first echo.
            format!(
                "slave.contact.round_trip_ms={}",
                self.rtt_ms * self.round_trip_told
            ),
            format!(
                "slave.contact.measure_round_trip={}",
                self.measure_round_trip
            ),
            format!("scale.force={}", self.force_scale),
            format!(
                "environment.stiffness_n_per_mm={}",
                self.wall.stiffness_n_per_mm
            ),
            format!("seed={}", self.seed),
        ];
        match self.loss {
            Loss::None => {}
            Loss::P5 => o.push("link.loss=0.05".into()),
            Loss::P20 => o.push("link.loss=0.2".into()),
            Loss::Blackout => {
                o.push("link.blackout_ms=200".into());
                o.push("link.blackout_every_ms=2000".into());
            }
        }
        o
    }

    /// One line naming the cell.
    pub fn label(&self) -> String {
        format!(
            "{:<9} rtt {:>4} ms, jitter {:>2} %, loss {:<8}, scale {}, seed {}, passivity {}, model {}, hand-over {}",
            self.wall.name(),
            self.rtt_ms,
            self.jitter * 100.0,
            self.loss.name(),
            self.force_scale,
            self.seed,
            on(self.passivity),
            on(self.model),
            on(self.handover),
        ) + &if self.round_trip_told == 0.0 {
            String::new()
        } else {
            format!(", round trip told ×{}", self.round_trip_told)
        } + if self.measure_round_trip {
            ""
        } else {
            ", round trip not measured"
        }
    }
}

fn on(b: bool) -> &'static str {
    if b { "on" } else { "off" }
}

/// The cells of a grid, in table order: scale, wall, loss, jitter, then round trip.
pub fn grid(
    scales: &[f64],
    walls: &[Wall],
    losses: &[Loss],
    jitters: &[f64],
    rtts_ms: &[f64],
    seed: u64,
) -> Vec<Case> {
    let mut cases = Vec::new();
    for &scale in scales {
        for &wall in walls {
            for &loss in losses {
                for &jitter in jitters {
                    for &rtt_ms in rtts_ms {
                        let mut c = Case::shipped(rtt_ms, jitter, loss, wall, scale);
                        c.seed = seed;
                        cases.push(c);
                    }
                }
            }
        }
    }
    cases
}

/// The shipped matrix with `seed`: scale 0.5 at every round trip, and with `with_scale_1`
/// scale 1.0 at 0–100 ms (384 cells with both).
pub fn shipped_cases(seed: u64, with_scale_1: bool) -> Vec<Case> {
    let mut cases = grid(&[0.5], &WALLS, &LOSS, &JITTER, &RTT_MS, seed);
    if with_scale_1 {
        cases.extend(grid(&[1.0], &WALLS, &LOSS, &JITTER, &RTT_SCALE_1_MS, seed));
    }
    cases
}

/// The session file a matrix runs and the overrides every cell shares.
#[derive(Clone, Debug)]
pub struct Matrix {
    /// The session file.
    pub session: PathBuf,
    /// `--set` overrides applied after each cell's own (they win).
    pub extra: Vec<String>,
    /// `--unsafe-test-override`: a cell may turn a safety layer off (the negative controls).
    pub unsafe_test_override: bool,
}

/// The limits the guarantees are judged against, from the session file.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Limits {
    /// The slave controller's force limit (`slave.controller.force_limit_n`), N.
    pub slave_force_limit_n: f64,
    /// The largest force rendered to the operator (`coupling.force_limit_n`), N.
    pub render_limit_n: f64,
}

impl Limits {
    /// The limits of a session.
    pub fn of(cfg: &SessionConfig) -> Self {
        Limits {
            slave_force_limit_n: cfg.slave.controller.force_limit_n,
            render_limit_n: cfg.coupling.force_limit_n,
        }
    }
}

impl Matrix {
    /// A matrix over `session` with `extra` overrides.
    pub fn new(session: &Path, extra: &[String]) -> Self {
        Matrix {
            session: session.to_path_buf(),
            extra: extra.to_vec(),
            unsafe_test_override: false,
        }
    }

    /// The matrix with `--unsafe-test-override` (each cell's summary says so).
    pub fn with_unsafe_test_override(mut self, on: bool) -> Self {
        self.unsafe_test_override = on;
        self
    }

    /// The session of one cell.
    pub fn config(&self, c: &Case) -> Result<SessionConfig, SessionError> {
        let mut o = c.overrides();
        o.extend(self.extra.iter().cloned());
        // A case with passivity off is a negative control (built in code: the command's
        // grid has none): it runs with the override, and its summary says so.
        session::load_with(&self.session, &o, self.unsafe_test_override || !c.passivity)
    }

    /// Runs one cell.
    pub fn run_case(&self, c: &Case) -> Result<Summary, String> {
        let cfg = self.config(c).map_err(|e| format!("{}: {e}", c.label()))?;
        session::run(&cfg, None).map_err(|e| format!("{}: {e}", c.label()))
    }

    /// The limits of the first cell's session (the cells differ only in the link, the wall
    /// and the layers, not in the limits).
    pub fn limits(&self, cases: &[Case]) -> Result<Limits, String> {
        let first =
            cases
                .first()
                .copied()
                .unwrap_or(Case::shipped(0.0, 0.0, Loss::None, Wall::RESIN, 0.5));
        let cfg = self
            .config(&first)
            .map_err(|e| format!("{}: {e}", self.session.display()))?;
        Ok(Limits::of(&cfg))
    }

    /// Runs `cases` on `jobs` threads (at least one), in order; `on_done` is called after each
    /// cell with its summary (from the worker's thread). Stops handing out cells when
    /// `stop()` says so (or a cell fails to run: its error is returned): the cells not run
    /// are `None`.
    pub fn run_all(
        &self,
        cases: &[Case],
        jobs: usize,
        stop: &(dyn Fn() -> bool + Sync),
        on_done: &(dyn Fn(&Case, &Summary) + Sync),
    ) -> Result<Vec<Option<Summary>>, String> {
        let failed_flag = AtomicBool::new(false);
        let stop = || stop() || failed_flag.load(Ordering::SeqCst);
        let next = Mutex::new(0usize);
        let out: Mutex<Vec<Option<Result<Summary, String>>>> = Mutex::new(vec![None; cases.len()]);
        std::thread::scope(|s| {
            for _ in 0..jobs.max(1) {
                s.spawn(|| {
                    loop {
                        if stop() {
                            break;
                        }
                        let i = {
                            let Ok(mut n) = next.lock() else { break };
                            let i = *n;
                            *n += 1;
                            i
                        };
                        let Some(case) = cases.get(i) else { break };
                        let r = self.run_case(case);
                        if let Ok(sum) = &r {
                            on_done(case, sum);
                        }
                        let failed = r.is_err();
                        if let Ok(mut o) = out.lock() {
                            o[i] = Some(r);
                        }
                        if failed {
                            failed_flag.store(true, Ordering::SeqCst);
                        }
                    }
                });
            }
        });
        let out = out.into_inner().map_err(|_| "a matrix worker panicked")?;
        out.into_iter().map(|r| r.transpose()).collect()
    }
}

/// The guarantees that should hold by construction in every cell; empty when all hold: the
/// true force within the slave's limit, the rendered force within the coupling's, both
/// observers ≥ −1 mJ.
pub fn safety_misses(s: &Summary, l: &Limits) -> Vec<String> {
    let mut m = Vec::new();
    // A NaN fails every check.
    if s.diverged {
        m.push("diverged (a state went non-finite)".to_string());
    }
    if s.max_force_n.is_nan() || s.max_force_n > l.slave_force_limit_n {
        m.push(format!(
            "true force {:.1} N > {}",
            s.max_force_n, l.slave_force_limit_n
        ));
    }
    if s.max_master_force_n.is_nan() || s.max_master_force_n > l.render_limit_n + 1e-9 {
        m.push(format!(
            "rendered {:.1} N > {}",
            s.max_master_force_n, l.render_limit_n
        ));
    }
    if s.energy_min_j.is_nan() || s.energy_min_j < -1e-3 {
        m.push(format!("observer {:.2} mJ < -1", s.energy_min_j * 1e3));
    }
    m
}

/// Every target of issue 12 for one cell; empty when all are met: the guarantees, the
/// detector's verdict, the first touch within 2× (3× on metal) the held force, each hold
/// within ±20 % (±35 % beyond 250 ms) of push / `scale.force`, two holds, hold ripple ≤ 1 N
/// RMS, drift ≤ 2 mm, force transparency ≤ 10 % up to 100 ms.
pub fn misses(c: &Case, s: &Summary, l: &Limits) -> Vec<String> {
    let mut m = safety_misses(s, l);
    if !s.stable {
        m.push(format!("unstable ({})", s.unstable_reasons.join("; ")));
    }
    let held_first = s.hold_force_n.first().copied().unwrap_or(0.0);
    let ratio = if c.wall.metal() { 3.0 } else { 2.0 };
    if s.first_touch_peak_n > ratio * held_first {
        m.push(format!(
            "first touch {:.1} N > {ratio} x held {:.1} N",
            s.first_touch_peak_n, held_first
        ));
    }
    let tol = if c.rtt_ms <= 250.0 { 0.20 } else { 0.35 };
    for (h, t) in s.hold_force_n.iter().zip(&s.hold_target_n) {
        if (h - t).abs() > tol * t {
            m.push(format!("held {h:.1} N vs {t:.1} N ± {:.0} %", tol * 100.0));
        }
    }
    if s.hold_force_n.len() < 2 {
        m.push(format!("{} holds found (2 expected)", s.hold_force_n.len()));
    }
    if s.hold_ripple_rms_n > 1.0 {
        m.push(format!("hold ripple {:.2} N RMS > 1", s.hold_ripple_rms_n));
    }
    if s.position_drift_mm > 2.0 {
        m.push(format!("drift {:.2} mm > 2", s.position_drift_mm));
    }
    let t = s.force_transparency_err_pct;
    if c.rtt_ms <= 100.0 && (t.is_nan() || t > 10.0) {
        m.push(format!("transparency {t:.1} % > 10"));
    }
    m
}

/// A cell's verdict, worst first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// A guarantee broke ([`safety_misses`]).
    Unsafe,
    /// The detector said unstable.
    Unstable,
    /// Stable, but a target of issue 12 missed.
    Missed,
    /// Every target met.
    Met,
}

impl Verdict {
    /// The cell's verdict.
    pub fn of(c: &Case, s: &Summary, l: &Limits) -> Self {
        if !safety_misses(s, l).is_empty() {
            Verdict::Unsafe
        } else if !s.stable {
            Verdict::Unstable
        } else if !misses(c, s, l).is_empty() {
            Verdict::Missed
        } else {
            Verdict::Met
        }
    }

    /// One word: `unsafe`, `unstable`, `missed`, `met`.
    pub fn word(self) -> &'static str {
        match self {
            Verdict::Unsafe => "unsafe",
            Verdict::Unstable => "unstable",
            Verdict::Missed => "missed",
            Verdict::Met => "met",
        }
    }
}

fn fmt_cell(s: &Summary, ok: bool) -> String {
    format!(
        "{}{} {:.0}/{:.1}/{:.1}/{}",
        if ok { "ok" } else { "**x**" },
        if s.stable { "" } else { " U" },
        s.max_force_n,
        s.hold_ripple_rms_n,
        s.hold_force_n.first().copied().unwrap_or(0.0),
        s.bounces
    )
}

/// Markdown table: one row per (scale, wall, loss, jitter), one column per round trip of
/// `rtts_ms`. Cells: `ok` (every target met) or `**x**`, ` U` when unstable, then true force
/// max N / hold ripple N RMS / first held force N / bounces; `–` for a cell not run.
pub fn table(cases: &[Case], sums: &[Option<Summary>], rtts_ms: &[f64], l: &Limits) -> String {
    let mut t = String::from("| scale | wall | loss | jitter |");
    for r in rtts_ms {
        t.push_str(&format!(" {r} ms |"));
    }
    t.push_str("\n|---|---|---|---|");
    for _ in rtts_ms {
        t.push_str("---|");
    }
    t.push('\n');
    let mut i = 0;
    while i < cases.len() {
        let c0 = cases[i];
        let mut j = i;
        while j < cases.len() && same_row(&cases[j], &c0) {
            j += 1;
        }
        t.push_str(&format!(
            "| {} | {} | {} | {:.0} % |",
            c0.force_scale,
            c0.wall.name(),
            c0.loss.name(),
            c0.jitter * 100.0
        ));
        for r in rtts_ms {
            let cell = (i..j).find(|&k| cases[k].rtt_ms == *r);
            match cell.and_then(|k| sums.get(k).and_then(|s| s.as_ref()).map(|s| (k, s))) {
                Some((k, s)) => t.push_str(&format!(
                    " {} |",
                    fmt_cell(s, misses(&cases[k], s, l).is_empty())
                )),
                None => t.push_str(" – |"),
            }
        }
        t.push('\n');
        i = j;
    }
    t
}

/// Whether two cells are in the same table row (all but the round trip equal).
pub fn same_row(a: &Case, b: &Case) -> bool {
    a.force_scale == b.force_scale && a.wall == b.wall && a.loss == b.loss && a.jitter == b.jitter
}

/// The worst value of each criterion over the cells run, with its cell.
pub fn worst_report(cases: &[Case], sums: &[Option<Summary>]) -> String {
    let worst = |f: &dyn Fn(&Summary) -> f64| {
        cases
            .iter()
            .zip(sums)
            .filter_map(|(c, s)| s.as_ref().map(|s| (f(s), c.label())))
            .fold((f64::NEG_INFINITY, String::new()), |a, b| {
                if b.0 > a.0 { b } else { a }
            })
    };
    let mut out = String::new();
    for (name, f) in [
        (
            "true force max, N",
            &(|s: &Summary| s.max_force_n) as &dyn Fn(&Summary) -> f64,
        ),
        ("rendered max, N", &|s: &Summary| s.max_master_force_n),
        ("observer min, -mJ", &|s: &Summary| -s.energy_min_j * 1e3),
        ("hold ripple, N RMS", &|s: &Summary| s.hold_ripple_rms_n),
        ("bounces", &|s: &Summary| s.bounces as f64),
        ("drift, mm", &|s: &Summary| s.position_drift_mm),
    ] {
        let (v, l) = worst(f);
        out.push_str(&format!("worst {name}: {v:.3} ({l})\n"));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cell whose peak force, rendered force or observer is NaN, or that diverged, fails
    /// the guarantees (`f64::max` used to drop a NaN and a diverging cell passed); the
    /// control, the same short run as it came, passes.
    #[test]
    fn a_nan_or_diverged_cell_fails_the_guarantees() {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sessions/wall-push.toml");
        let cfg = session::load(&path, &["duration_s=0.5".to_string()]).expect("session");
        let l = Limits::of(&cfg);
        let s = session::run(&cfg, None).expect("run");
        assert!(
            safety_misses(&s, &l).is_empty(),
            "{:?}",
            safety_misses(&s, &l)
        );
        let bad: [fn(&mut Summary); 4] = [
            |s| s.max_force_n = f64::NAN,
            |s| s.max_master_force_n = f64::NAN,
            |s| s.energy_min_j = f64::NAN,
            |s| s.diverged = true,
        ];
        for (i, f) in bad.iter().enumerate() {
            let mut b = s.clone();
            f(&mut b);
            assert!(!safety_misses(&b, &l).is_empty(), "case {i} passed");
        }
    }

    #[test]
    fn walls_and_losses_parse_by_name_and_number() {
        assert_eq!(Wall::parse("steel"), Ok(Wall::STEEL));
        assert_eq!(Wall::parse("500").map(|w| w.stiffness_n_per_mm), Ok(500.0));
        assert_eq!(Wall::parse("200").map(Wall::name), Ok("resin".into()));
        assert!(Wall::parse("wood").is_err());
        assert!(Wall::parse("0").is_err());
        assert_eq!(Loss::parse("20%"), Ok(Loss::P20));
        assert!(Loss::parse("7%").is_err());
        assert_eq!(shipped_cases(4, true).len(), 384);
    }
}
