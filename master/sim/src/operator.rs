//! The simulated operator: a hand holding the master's handle and following a scripted
//! intent (moves, pushes, holds, clutch presses), or replaying a recorded trajectory.
//!
//! The hand is a mass (`hand_mass_kg`) pulled towards the intended point by the arm's
//! spring–damper (`arm_stiffness_n_per_mm`, `arm_damping_n_s_per_mm`), pushing with the
//! intended force (`push_n`), and holding the handle through the grip's spring–damper
//! (`grip_stiffness_n_per_mm`, `grip_damping_n_s_per_mm`). The force on the handle is the
//! grip's force. Intended points are relative to the handle's start pose, master frame, mm.
//!
//! In force-guided mode the operator sets the slave's contact-force set-point by pushing:
//! a set-point change is a change of `push_n`.

use std::path::Path;

use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

/// One segment of a scripted intent.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct IntentSegment {
    /// When the segment starts, s (segments in time order).
    pub at_s: f64,
    /// Where the hand goes, relative to the handle's start, `[x, y, z]` mm (master frame).
    pub target_mm: [f64; 3],
    /// Duration of the (smooth, minimum-jerk) move from the previous target, s.
    #[serde(default = "default_move_s")]
    pub move_s: f64,
    /// Force the hand pushes with, `[Fx, Fy, Fz]` N (ramped from the previous one).
    #[serde(default)]
    pub push_n: [f64; 3],
    /// Time to ramp the push from the previous segment's, s.
    #[serde(default = "default_push_ramp_s")]
    pub push_ramp_s: f64,
    /// The clutch button is held during the segment.
    #[serde(default)]
    pub clutch: bool,
    /// Intended handle angle theta, rad.
    #[serde(default)]
    pub theta_rad: f64,
}

fn default_move_s() -> f64 {
    1.0
}
fn default_push_ramp_s() -> f64 {
    0.3
}

/// A recorded master trajectory point (one JSON object per line of a replay file).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayPoint {
    /// Time, s (increasing).
    pub t_s: f64,
    /// Handle position relative to the start, `[x, y, z]` mm.
    pub position_mm: [f64; 3],
    /// Handle theta, rad.
    #[serde(default)]
    pub theta_rad: f64,
    /// Push force, N.
    #[serde(default)]
    pub push_n: [f64; 3],
    /// Clutch held.
    #[serde(default)]
    pub clutch: bool,
}

/// The hand's parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct HandConfig {
    /// Mass of the hand and forearm that moves with the handle, kg.
    pub hand_mass_kg: f64,
    /// Stiffness of the arm pulling the hand towards the intended point, N/mm.
    pub arm_stiffness_n_per_mm: f64,
    /// Damping of the arm, N·s/mm.
    pub arm_damping_n_s_per_mm: f64,
    /// Stiffness of the grip on the handle, N/mm.
    pub grip_stiffness_n_per_mm: f64,
    /// Damping of the grip, N·s/mm.
    pub grip_damping_n_s_per_mm: f64,
}

impl Default for HandConfig {
    fn default() -> Self {
        HandConfig {
            hand_mass_kg: 0.3,
            arm_stiffness_n_per_mm: 0.4,
            arm_damping_n_s_per_mm: 0.01,
            grip_stiffness_n_per_mm: 2.0,
            grip_damping_n_s_per_mm: 0.01,
        }
    }
}

impl Section for HandConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |name: &str| format!("{prefix}{name}");
        check_range(&f("hand_mass_kg"), self.hand_mass_kg, 0.01, 10.0, "kg")?;
        check_range(
            &f("arm_stiffness_n_per_mm"),
            self.arm_stiffness_n_per_mm,
            0.0,
            100.0,
            "N/mm",
        )?;
        check_range(
            &f("arm_damping_n_s_per_mm"),
            self.arm_damping_n_s_per_mm,
            0.0,
            10.0,
            "N·s/mm",
        )?;
        check_range(
            &f("grip_stiffness_n_per_mm"),
            self.grip_stiffness_n_per_mm,
            0.01,
            20.0,
            "N/mm",
        )?;
        check_range(
            &f("grip_damping_n_s_per_mm"),
            self.grip_damping_n_s_per_mm,
            0.0,
            10.0,
            "N·s/mm",
        )
    }
}

/// Why an intent could not be read.
#[derive(Debug, thiserror::Error)]
pub enum IntentError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// A line of a replay file is not a trajectory point.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file.
        path: String,
        /// Line number, from 1.
        line: usize,
        /// The parser's message.
        message: String,
    },
    /// The script is empty or out of order.
    #[error("{0}")]
    Invalid(String),
}

/// What the operator intends at one instant.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Intent {
    /// Intended point relative to the start, mm.
    pub target_mm: [f64; 3],
    /// Intended theta, rad.
    pub theta_rad: f64,
    /// Push force, N.
    pub push_n: [f64; 3],
    /// Clutch held.
    pub clutch: bool,
    /// The intent is at rest (no move or push ramp in progress).
    pub steady: bool,
}

/// A scripted intent or a replayed trajectory.
#[derive(Clone, Debug, PartialEq)]
pub enum Script {
    /// Scripted segments.
    Segments(Vec<IntentSegment>),
    /// A recorded trajectory, linearly interpolated.
    Replay(Vec<ReplayPoint>),
}

fn lerp3(a: &[f64; 3], b: &[f64; 3], s: f64) -> [f64; 3] {
    [
        a[0] + (b[0] - a[0]) * s,
        a[1] + (b[1] - a[1]) * s,
        a[2] + (b[2] - a[2]) * s,
    ]
}

fn min_jerk(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)
}

impl Script {
    /// Checks order and finiteness.
    pub fn validate(&self) -> Result<(), IntentError> {
        match self {
            Script::Segments(segs) => {
                if segs.is_empty() {
                    return Err(IntentError::Invalid(
                        "operator.intent: at least one segment is needed".into(),
                    ));
                }
                let mut prev = f64::NEG_INFINITY;
                for (i, s) in segs.iter().enumerate() {
                    let finite = s.at_s.is_finite()
                        && s.move_s.is_finite()
                        && s.push_ramp_s.is_finite()
                        && s.theta_rad.is_finite()
                        && s.target_mm
                            .iter()
                            .chain(s.push_n.iter())
                            .all(|v| v.is_finite());
                    if !finite || s.at_s < prev || s.move_s < 0.0 || s.push_ramp_s < 0.0 {
                        return Err(IntentError::Invalid(format!(
                            "operator.intent[{i}]: at_s must not decrease, move_s and push_ramp_s must be >= 0, all numbers finite"
                        )));
                    }
                    if s.theta_rad.abs() > 1.0 || s.target_mm.iter().any(|v| v.abs() > 200.0) {
                        return Err(IntentError::Invalid(format!(
                            "operator.intent[{i}]: target_mm within ±200 mm and |theta_rad| <= 1"
                        )));
                    }
                    if s.push_n.iter().any(|v| v.abs() > 100.0) {
                        return Err(IntentError::Invalid(format!(
                            "operator.intent[{i}].push_n: each component within ±100 N"
                        )));
                    }
                    prev = s.at_s;
                }
                Ok(())
            }
            Script::Replay(points) => {
                if points.is_empty() {
                    return Err(IntentError::Invalid("replay file: no points".into()));
                }
                let mut prev = f64::NEG_INFINITY;
                for (i, p) in points.iter().enumerate() {
                    let finite = p.t_s.is_finite()
                        && p.position_mm
                            .iter()
                            .chain(p.push_n.iter())
                            .all(|v| v.is_finite());
                    if !finite || p.t_s <= prev {
                        return Err(IntentError::Invalid(format!(
                            "replay point {i}: t_s must increase and all numbers be finite"
                        )));
                    }
                    prev = p.t_s;
                }
                Ok(())
            }
        }
    }

    /// Reads a replay file: one [`ReplayPoint`] JSON object per line.
    pub fn load_replay(path: &Path) -> Result<Self, IntentError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| IntentError::Io {
            path: name.clone(),
            source,
        })?;
        let mut points = Vec::new();
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let p: ReplayPoint = serde_json::from_str(line).map_err(|e| IntentError::Parse {
                path: name.clone(),
                line: i + 1,
                message: e.to_string(),
            })?;
            points.push(p);
        }
        let s = Script::Replay(points);
        s.validate()?;
        Ok(s)
    }

    /// The intent at `t_s`; `cursor` remembers where the last lookup ended (allocation-free,
    /// amortised O(1) for increasing times).
    pub fn at(&self, t_s: f64, cursor: &mut usize) -> Intent {
        match self {
            Script::Segments(segs) => {
                while *cursor + 1 < segs.len() && segs[*cursor + 1].at_s <= t_s {
                    *cursor += 1;
                }
                let Some(cur) = segs.get(*cursor) else {
                    return Intent::default();
                };
                if t_s < cur.at_s {
                    // Before the first segment: rest at the start.
                    return Intent {
                        steady: true,
                        ..Intent::default()
                    };
                }
                let (prev_target, prev_push, prev_theta) = match cursor.checked_sub(1) {
                    Some(i) => segs.get(i).map_or(([0.0; 3], [0.0; 3], 0.0), |p| {
                        (p.target_mm, p.push_n, p.theta_rad)
                    }),
                    None => ([0.0; 3], [0.0; 3], 0.0),
                };
                let since = t_s - cur.at_s;
                let sm = if cur.move_s > 0.0 {
                    since / cur.move_s
                } else {
                    1.0
                };
                let sp = if cur.push_ramp_s > 0.0 {
                    since / cur.push_ramp_s
                } else {
                    1.0
                };
                let m = min_jerk(sm);
                Intent {
                    target_mm: lerp3(&prev_target, &cur.target_mm, m),
                    theta_rad: prev_theta + (cur.theta_rad - prev_theta) * m,
                    push_n: lerp3(&prev_push, &cur.push_n, sp.clamp(0.0, 1.0)),
                    clutch: cur.clutch,
                    steady: sm >= 1.0 && sp >= 1.0,
                }
            }
            Script::Replay(points) => {
                while *cursor + 1 < points.len() && points[*cursor + 1].t_s <= t_s {
                    *cursor += 1;
                }
                let Some(a) = points.get(*cursor) else {
                    return Intent::default();
                };
                match points.get(*cursor + 1) {
                    Some(b) if t_s > a.t_s => {
                        let s = ((t_s - a.t_s) / (b.t_s - a.t_s)).clamp(0.0, 1.0);
                        Intent {
                            target_mm: lerp3(&a.position_mm, &b.position_mm, s),
                            theta_rad: a.theta_rad + (b.theta_rad - a.theta_rad) * s,
                            push_n: lerp3(&a.push_n, &b.push_n, s),
                            clutch: a.clutch,
                            steady: false,
                        }
                    }
                    _ => Intent {
                        target_mm: a.position_mm,
                        theta_rad: a.theta_rad,
                        push_n: a.push_n,
                        clutch: a.clutch,
                        steady: true,
                    },
                }
            }
        }
    }

    /// When the script ends (its last segment starts plus its move), s.
    pub fn end_s(&self) -> f64 {
        match self {
            Script::Segments(segs) => segs
                .last()
                .map_or(0.0, |s| s.at_s + s.move_s.max(s.push_ramp_s)),
            Script::Replay(points) => points.last().map_or(0.0, |p| p.t_s),
        }
    }
}

/// The simulated hand.
#[derive(Clone, Debug)]
pub struct Operator {
    cfg: HandConfig,
    script: Script,
    cursor: usize,
    origin: [f64; 4],
    hand: [f64; 4],
    hand_vel: [f64; 4],
    last_intent: Intent,
}

/// What the hand does this cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct HandOutput {
    /// Wrench the grip applies to the handle `[Fx, Fy, Fz, My]`, N and N·mm.
    pub wrench: [f64; 4],
    /// The clutch button is held.
    pub clutch: bool,
    /// The intent of this cycle.
    pub intent: Intent,
}

/// Rotational stiffness of the wrist per N/mm of grip stiffness, N·mm/rad.
const WRIST_PER_GRIP: f64 = 500.0;

impl Operator {
    /// A hand holding the handle at `handle_start` (device pose), following `script`.
    pub fn new(cfg: HandConfig, script: Script, handle_start: [f64; 4]) -> Self {
        Operator {
            cfg,
            script,
            cursor: 0,
            origin: handle_start,
            hand: handle_start,
            hand_vel: [0.0; 4],
            last_intent: Intent::default(),
        }
    }

    /// The script.
    pub fn script(&self) -> &Script {
        &self.script
    }

    /// One step at time `t_s`, given the handle's pose and velocity.
    pub fn step(
        &mut self,
        t_s: f64,
        handle_pose: &[f64; 4],
        handle_vel: &[f64; 4],
        dt_s: f64,
    ) -> HandOutput {
        let intent = self.script.at(t_s, &mut self.cursor);
        self.last_intent = intent;
        let c = &self.cfg;
        let m = (c.hand_mass_kg * 1e-3).max(1e-9);
        let mut wrench = [0.0; 4];
        for i in 0..3 {
            let target = self.origin[i] + intent.target_mm[i];
            let grip = c.grip_stiffness_n_per_mm * (self.hand[i] - handle_pose[i])
                + c.grip_damping_n_s_per_mm * (self.hand_vel[i] - handle_vel[i]);
            let arm = c.arm_stiffness_n_per_mm * (target - self.hand[i])
                - c.arm_damping_n_s_per_mm * self.hand_vel[i];
            let f = arm + intent.push_n[i] - grip;
            self.hand_vel[i] += f / m * dt_s;
            self.hand[i] += self.hand_vel[i] * dt_s;
            wrench[i] = grip;
        }
        // The wrist holds theta: a stiff rotational spring towards the intended angle.
        let k_rot = WRIST_PER_GRIP * c.arm_stiffness_n_per_mm;
        let b_rot = WRIST_PER_GRIP * c.arm_damping_n_s_per_mm;
        self.hand[3] = self.origin[3] + intent.theta_rad;
        wrench[3] = k_rot * (self.hand[3] - handle_pose[3]) - b_rot * handle_vel[3];
        HandOutput {
            wrench,
            clutch: intent.clutch,
            intent,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(at_s: f64, z: f64, push: f64, clutch: bool) -> IntentSegment {
        IntentSegment {
            at_s,
            target_mm: [0.0, 0.0, z],
            move_s: 1.0,
            push_n: [0.0, 0.0, push],
            push_ramp_s: 0.5,
            clutch,
            theta_rad: 0.0,
        }
    }

    #[test]
    fn script_moves_smoothly_and_holds() {
        let s = Script::Segments(vec![seg(0.0, 0.0, 0.0, false), seg(1.0, -10.0, -5.0, true)]);
        s.validate().unwrap();
        let mut c = 0;
        assert_eq!(s.at(0.5, &mut c).target_mm[2], 0.0);
        let mid = s.at(1.5, &mut c);
        assert!((mid.target_mm[2] + 5.0).abs() < 1e-9, "{mid:?}");
        assert!(mid.clutch && !mid.steady);
        let end = s.at(3.0, &mut c);
        assert_eq!(end.target_mm[2], -10.0);
        assert_eq!(end.push_n[2], -5.0);
        assert!(end.steady);
    }

    #[test]
    fn bad_scripts_are_named() {
        let s = Script::Segments(vec![seg(1.0, 0.0, 0.0, false), seg(0.5, 0.0, 0.0, false)]);
        let e = s.validate().unwrap_err().to_string();
        assert!(e.contains("operator.intent[1]"), "{e}");
        assert!(Script::Segments(vec![]).validate().is_err());
    }

    #[test]
    fn replay_interpolates_and_hand_follows() {
        let s = Script::Replay(vec![
            ReplayPoint {
                t_s: 0.0,
                position_mm: [0.0; 3],
                theta_rad: 0.0,
                push_n: [0.0; 3],
                clutch: false,
            },
            ReplayPoint {
                t_s: 1.0,
                position_mm: [10.0, 0.0, 0.0],
                theta_rad: 0.0,
                push_n: [0.0; 3],
                clutch: false,
            },
        ]);
        s.validate().unwrap();
        let mut c = 0;
        assert!((s.at(0.25, &mut c).target_mm[0] - 2.5).abs() < 1e-12);
        let mut op = Operator::new(HandConfig::default(), s, [0.0; 4]);
        // A free handle that follows the grip exactly: the hand ends near the target.
        let mut pose = [0.0; 4];
        let mut vel = [0.0; 4];
        for k in 0..3000 {
            let out = op.step(k as f64 * 1e-3, &pose, &vel, 1e-3);
            // Handle of 0.2 kg pushed by the grip.
            for i in 0..3 {
                vel[i] += out.wrench[i] / 0.2e-3 * 1e-3 - vel[i] * 0.05;
                pose[i] += vel[i] * 1e-3;
            }
        }
        assert!((pose[0] - 10.0).abs() < 0.5, "{pose:?}");
    }
}
