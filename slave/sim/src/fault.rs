//! Faults injected into the simulated arm (`h4-slave run --inject-fault KIND@START+DURATION`):
//! the failures of a real arm's sensor and driver that the safety monitor
//! (`h4_slave::safety`) must catch, made to happen on purpose in a running process.
//!
//! * `sensor-freeze`: the force/torque reading repeats the value it had when the fault began
//!   (a sensor whose stream stopped updating while its driver goes on answering);
//! * `sensor-saturate`: the normal (z) force reads the sensor's full range, pressing down
//!   (an amplifier at its rail);
//! * `driver-silent`: the driver stops answering: every reading is the one it gave when the
//!   fault began (its time does not move on) and commands are not taken (the servos hold
//!   their last set-point).
//!
//! The fault lasts from `START` to `START + DURATION` seconds of the arm's own clock (the
//! slave's loop time from its first cycle). Only the simulated arm has this: a real driver's
//! faults are its own.

use std::fmt;
use std::str::FromStr;

use h4_slave::arm::ArmReading;
use serde::{Deserialize, Serialize};

/// What fails.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// The force/torque reading freezes at its value when the fault began.
    SensorFreeze,
    /// The normal force reads the sensor's full range.
    SensorSaturate,
    /// The driver stops answering (stale readings, commands not taken).
    DriverSilent,
}

impl FaultKind {
    /// Every kind, in the order `--inject-fault` documents them.
    pub const ALL: [FaultKind; 3] = [
        FaultKind::SensorFreeze,
        FaultKind::SensorSaturate,
        FaultKind::DriverSilent,
    ];

    /// The name `--inject-fault` takes.
    pub fn name(self) -> &'static str {
        match self {
            FaultKind::SensorFreeze => "sensor-freeze",
            FaultKind::SensorSaturate => "sensor-saturate",
            FaultKind::DriverSilent => "driver-silent",
        }
    }
}

impl fmt::Display for FaultKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One fault: what, from when, for how long.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FaultPlan {
    /// What fails.
    pub kind: FaultKind,
    /// When it begins, s on the arm's clock.
    pub start_s: f64,
    /// How long it lasts, s.
    pub duration_s: f64,
}

/// Why a `--inject-fault` value was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FaultParseError {
    /// Not `KIND@START+DURATION`.
    #[error("expected KIND@START_S+DURATION_S (e.g. sensor-freeze@4+10), got {0:?}")]
    Form(String),
    /// An unknown kind.
    #[error("unknown fault {0:?}: sensor-freeze, sensor-saturate or driver-silent")]
    Kind(String),
    /// A time that is not a finite number in range.
    #[error("{0}: a number of seconds in 0..=86400")]
    Time(String),
}

impl FromStr for FaultPlan {
    type Err = FaultParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (kind, times) = s
            .split_once('@')
            .ok_or_else(|| FaultParseError::Form(s.to_string()))?;
        let (start, duration) = times
            .split_once('+')
            .ok_or_else(|| FaultParseError::Form(s.to_string()))?;
        let kind = FaultKind::ALL
            .into_iter()
            .find(|k| k.name() == kind.trim())
            .ok_or_else(|| FaultParseError::Kind(kind.to_string()))?;
        let secs = |v: &str| -> Result<f64, FaultParseError> {
            v.trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && (0.0..=86_400.0).contains(x))
                .ok_or_else(|| FaultParseError::Time(v.to_string()))
        };
        Ok(FaultPlan {
            kind,
            start_s: secs(start)?,
            duration_s: secs(duration)?,
        })
    }
}

/// A fault planned on an arm: its window on the arm's clock and what it holds.
#[derive(Clone, Debug)]
pub(crate) struct ArmFault {
    pub(crate) plan: FaultPlan,
    start_ns: u64,
    end_ns: u64,
    /// The sensor's full range, N (what a saturated reading shows).
    saturation_n: f64,
    /// The reading when the fault began (frozen or stale faults repeat it).
    held: Option<ArmReading>,
}

impl ArmFault {
    pub(crate) fn new(plan: FaultPlan, saturation_n: f64) -> Self {
        let ns = |s: f64| (s * 1e9).round() as u64;
        ArmFault {
            plan,
            start_ns: ns(plan.start_s),
            end_ns: ns(plan.start_s + plan.duration_s),
            saturation_n,
            held: None,
        }
    }

    /// Whether the fault is on at `time_ns`.
    pub(crate) fn active(&self, time_ns: u64) -> bool {
        (self.start_ns..self.end_ns).contains(&time_ns)
    }

    /// The reading the faulty arm gives instead of `r` (taken at `r.time_ns`).
    pub(crate) fn apply(&mut self, r: ArmReading) -> ArmReading {
        if !self.active(r.time_ns) {
            self.held = None;
            return r;
        }
        let held = *self.held.get_or_insert(r);
        match self.plan.kind {
            FaultKind::SensorFreeze => ArmReading {
                wrench: held.wrench,
                ..r
            },
            FaultKind::SensorSaturate => {
                let mut out = r;
                out.wrench[2] = -self.saturation_n;
                out
            }
            FaultKind::DriverSilent => held,
        }
    }

    /// Whether a command is taken at `time_ns` (not while the driver is silent).
    pub(crate) fn takes_commands(&self, time_ns: u64) -> bool {
        !(self.plan.kind == FaultKind::DriverSilent && self.active(time_ns))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plans_parse_and_bad_ones_are_refused_with_their_reason() {
        let p: FaultPlan = "sensor-freeze@4+10".parse().unwrap();
        assert_eq!(p.kind, FaultKind::SensorFreeze);
        assert_eq!((p.start_s, p.duration_s), (4.0, 10.0));
        for k in FaultKind::ALL {
            let p: FaultPlan = format!("{k}@0.5+1.5").parse().unwrap();
            assert_eq!(p.kind, k);
        }
        assert!(matches!(
            "sensor-freeze".parse::<FaultPlan>(),
            Err(FaultParseError::Form(_))
        ));
        assert!(matches!(
            "sensor-melt@1+2".parse::<FaultPlan>(),
            Err(FaultParseError::Kind(_))
        ));
        for bad in [
            "driver-silent@NaN+2",
            "driver-silent@1+-2",
            "driver-silent@1+x",
        ] {
            assert!(
                matches!(bad.parse::<FaultPlan>(), Err(FaultParseError::Time(_))),
                "{bad}"
            );
        }
    }

    fn reading(t_ns: u64, fz: f64) -> ArmReading {
        ArmReading {
            time_ns: t_ns,
            actuators_mm: [t_ns as f64 * 1e-9; 4],
            wrench: [0.0, 0.0, fz, 0.0],
        }
    }

    #[test]
    fn each_fault_changes_the_reading_only_inside_its_window() {
        let ms = 1_000_000;
        let plan = |kind| FaultPlan {
            kind,
            start_s: 0.002,
            duration_s: 0.002,
        };
        // Outside the window every kind passes the reading through.
        for kind in FaultKind::ALL {
            let mut f = ArmFault::new(plan(kind), 145.0);
            for t in [0, ms, 4 * ms, 5 * ms] {
                assert_eq!(
                    f.apply(reading(t, -3.0 - t as f64)),
                    reading(t, -3.0 - t as f64)
                );
                assert!(f.takes_commands(t));
            }
        }
        let mut freeze = ArmFault::new(plan(FaultKind::SensorFreeze), 145.0);
        let a = freeze.apply(reading(2 * ms, -5.0));
        let b = freeze.apply(reading(3 * ms, -9.0));
        assert_eq!(b.wrench, a.wrench, "frozen");
        assert_eq!(b.time_ns, 3 * ms, "the driver still answers");
        assert_ne!(b.actuators_mm, a.actuators_mm, "the encoders still move");
        let mut sat = ArmFault::new(plan(FaultKind::SensorSaturate), 145.0);
        assert_eq!(sat.apply(reading(3 * ms, -5.0)).wrench[2], -145.0);
        let mut silent = ArmFault::new(plan(FaultKind::DriverSilent), 145.0);
        let a = silent.apply(reading(2 * ms, -5.0));
        let b = silent.apply(reading(3 * ms, -9.0));
        assert_eq!(a, b, "a silent driver's reading does not move on");
        assert!(!silent.takes_commands(3 * ms));
        assert!(silent.takes_commands(4 * ms));
    }
}
