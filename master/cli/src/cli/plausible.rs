//! The commands' side of [`h4_master_sim::plausible`]: warnings on stderr, refusals as errors
//! (exit 2) that give the reason.

use h4_master_sim::session::SessionConfig;

/// Prints each warning as `LABEL: warning: …`; a refused setting is an error naming it.
pub fn check_session(cfg: &SessionConfig, label: &str) -> Result<(), String> {
    let p = h4_master_sim::plausible::check(cfg);
    for w in &p.warnings {
        h4_telemetry::progress::verdict_line(label, &format!("warning: {w}"));
    }
    if p.refused.is_empty() {
        Ok(())
    } else {
        Err(format!("refused: {}", p.refused.join("; ")))
    }
}
