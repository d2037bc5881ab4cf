//! Settings a session file may hold but the coupling cannot render as meant: checked by
//! `h4-master sim`, `run` and `loopback` before they start ([`check`]). Every bound comes
//! from the session's own parameters, never from a number tuned to a case:
//!
//! * **Force range** (refused): the smallest contact force the slave holds — the hand-over's
//!   `slave.contact.hold_min_n`, or without it the controller's
//!   `slave.controller.contact_threshold_n` — times `scale.force` must fit under
//!   `coupling.force_limit_n`. Beyond it every held contact renders saturated: the operator
//!   cannot balance the force of any contact, pushes through or is pushed off, and the tool
//!   bounces (`scale.force = 100` on wall-push: 84 bounces).
//! * **Rendered stiffness** (refused): the operator feels the slave's contact as a spring of
//!   `K = scale.force · scale.motion · k`, `k` the stiffness the slave's contact presents to
//!   the master's commands: the hand-over's virtual spring (`slave.contact.stiffness_n_per_mm`)
//!   when it is on, else the wall in series with the arm's own stiffness along the wall's
//!   normal (`1 / Λ_zz` at the start pose, from the actuator stiffness); with the local model
//!   on, at most `coupling.model_stiffness_max_n_per_mm`. A spring sampled every `T` (the 1 ms
//!   cycle) on the handle is passive only with a damping `b > K T / 2` (Colgate and Schenkel),
//!   and the handle takes at most `b = m / T` in one cycle (`m` its smallest effective mass:
//!   the passivity controller's own discrete-time bound): `K ≤ 2 m / T²`.
//! * **The operator's push** (a warning): the script's largest push divided by `scale.force`
//!   above the slave controller's force limit asks the slave for more than its force guard
//!   lets it press.

use h4_shared::Pose;

use crate::arm::SimMasterArm;
use crate::session::SessionConfig;
use h4_master::device::HapticDevice;

/// The cycle of the coupling, s.
const CYCLE_S: f64 = 1e-3;

/// What [`check`] found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plausibility {
    /// Settings the coupling cannot render stably: the run is refused, each with its reason.
    pub refused: Vec<String>,
    /// Settings that work but not as the file may mean: each a sentence.
    pub warnings: Vec<String>,
}

/// The stiffness the slave's contact presents to the master's position commands, N/mm at the
/// slave (see the module doc), and what it is.
pub fn slave_contact_stiffness_n_per_mm(cfg: &SessionConfig) -> (f64, String) {
    if cfg.slave.contact.enabled {
        return (
            cfg.slave.contact.effective_stiffness_n_per_mm(),
            "the slave's hand-over spring, slave.contact.stiffness_n_per_mm (softened over \
             slave.contact.round_trip_ms)"
                .into(),
        );
    }
    let wall = cfg
        .environment
        .surface_config()
        .surface()
        .material
        .stiffness_n_per_mm;
    let arm = cfg
        .slave
        .arm
        .stiffness()
        .ok()
        .and_then(|k| {
            cfg.slave
                .arm
                .workspace()
                .params
                .compliance(&Pose::from(cfg.environment.slave_start_pose()), &k)
                .ok()
        })
        .map(|c| c[(2, 2)])
        .filter(|c| c.is_finite() && *c > 0.0)
        .map_or(f64::INFINITY, |c| 1.0 / c);
    let k = 1.0 / (1.0 / wall + 1.0 / arm);
    (
        k,
        format!("the wall ({wall} N/mm) in series with the arm ({arm:.0} N/mm along z)"),
    )
}

/// The largest stiffness the master can render passively, N/mm: `2 m / T²` (module doc).
pub fn max_stable_stiffness_n_per_mm(cfg: &SessionConfig) -> Option<f64> {
    let m_kg = SimMasterArm::new(cfg.master).ok()?.read().effective_mass_kg;
    (m_kg > 0.0).then(|| 2.0 * m_kg / (CYCLE_S * CYCLE_S) * 1e-3)
}

/// Checks a session's scaling against what its coupling and device can render.
pub fn check(cfg: &SessionConfig) -> Plausibility {
    let mut p = Plausibility::default();
    let s_f = cfg.scale.force;
    let (f_min, f_min_name) = if cfg.slave.contact.enabled {
        (cfg.slave.contact.hold_min_n, "slave.contact.hold_min_n")
    } else {
        (
            cfg.slave.controller.contact_threshold_n,
            "slave.controller.contact_threshold_n",
        )
    };
    let limit = cfg.coupling.force_limit_n;
    if s_f * f_min > limit {
        p.refused.push(format!(
            "scale.force = {s_f}: the slave's smallest held contact force ({f_min_name} = \
             {f_min} N) would render as {:.1} N, beyond coupling.force_limit_n = {limit} N: \
             every contact would render saturated and bounce; at most {:.3} with these settings",
            s_f * f_min,
            limit / f_min
        ));
    }
    let (k_slave, what) = slave_contact_stiffness_n_per_mm(cfg);
    let mut k_rendered = s_f * cfg.scale.motion * k_slave;
    if cfg.coupling.model {
        k_rendered = k_rendered.min(cfg.coupling.model_stiffness_max_n_per_mm);
    }
    if let Some(k_max) = max_stable_stiffness_n_per_mm(cfg)
        && k_rendered > k_max
    {
        p.refused.push(format!(
            "scale.force = {s_f}: the operator would feel the contact as {k_rendered:.0} N/mm \
             (scale.force × scale.motion × {k_slave:.1} N/mm, {what}), above the {k_max:.0} N/mm \
             the master arm renders passively at 1 kHz (2 m / T², m its effective mass); at \
             most {:.3} with these settings",
            s_f * k_max / k_rendered
        ));
    }
    let push_max = cfg
        .operator
        .intent
        .iter()
        .map(|s| h4_shared::vec3::norm3(&s.push_n))
        .fold(0.0, f64::max);
    let slave_limit = cfg.slave.controller.force_limit_n;
    if push_max / s_f > slave_limit {
        p.warnings.push(format!(
            "scale.force = {s_f}: the operator's largest push ({push_max} N) asks the slave for \
             {:.0} N, above its force limit (slave.controller.force_limit_n = {slave_limit} N): \
             the slave's force guard will cap it",
            push_max / s_f
        ));
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn wall_push(set: &[&str]) -> SessionConfig {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sessions/wall-push.toml");
        let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
        crate::session::load(&path, &set).expect("wall-push")
    }

    #[test]
    fn the_shipped_settings_are_plausible() {
        for set in [&[][..], &["scale.force=1.0"], &["scale.force=0.25"]] {
            let p = check(&wall_push(set));
            assert!(
                p.refused.is_empty() && p.warnings.is_empty(),
                "{set:?}: {p:?}"
            );
        }
    }

    /// The bounds follow the parameters they come from: raising the force limit moves the
    /// force-range bound with it; a heavier handle renders stiffer springs passively.
    #[test]
    fn bounds_move_with_the_parameters() {
        let p = check(&wall_push(&["scale.force=100"]));
        assert_eq!(p.refused.len(), 1, "{p:?}");
        assert!(
            p.refused[0].contains("coupling.force_limit_n = 30"),
            "{p:?}"
        );
        assert!(p.refused[0].contains("at most 30.000"), "{p:?}");
        let p = check(&wall_push(&["scale.force=50", "coupling.force_limit_n=60"]));
        assert!(p.refused.is_empty(), "{p:?}");
        // The stiffness bound: without the hand-over, steel in series with the arm.
        let bare = [
            "slave.contact.enabled=false",
            "environment.stiffness_n_per_mm=2000",
            "coupling.force_limit_n=200",
        ];
        let cfg = wall_push(&bare);
        let k_max = max_stable_stiffness_n_per_mm(&cfg).unwrap();
        let (k, _) = slave_contact_stiffness_n_per_mm(&cfg);
        println!("steel without hand-over: k {k:.1} N/mm, master passive up to {k_max:.0} N/mm");
        assert!(k > 1.0 && k < 2000.0, "{k}");
        let over = format!("scale.force={}", 1.2 * k_max / k);
        let under = format!("scale.force={}", 0.8 * k_max / k);
        let p = check(&wall_push(&[bare[0], bare[1], bare[2], &over]));
        assert!(p.refused.iter().any(|r| r.contains("N/mm")), "{p:?}");
        let p = check(&wall_push(&[bare[0], bare[1], bare[2], &under]));
        assert!(!p.refused.iter().any(|r| r.contains("passively")), "{p:?}");
        let heavy = check(&wall_push(&[
            bare[0],
            bare[1],
            bare[2],
            &over,
            "master.handle_mass_kg=2",
            "master.carriage_mass_kg=2",
        ]));
        assert!(
            !heavy.refused.iter().any(|r| r.contains("passively")),
            "{heavy:?}"
        );
        // A push the slave's force guard must cap is a warning, not a refusal.
        let p = check(&wall_push(&["scale.force=0.05"]));
        assert!(p.refused.is_empty() && p.warnings.len() == 1, "{p:?}");
    }
}
