//! The replay driver: an [`ArmDriver`] that plays a recorded arm back from an MCAP file,
//! for offline debugging of the controller and the endpoint against what a real (or
//! simulated) arm once read (`h4-slave run --arm replay --replay FILE`).
//!
//! The recording is a slave process's (`h4-slave run --record`): every `/slave/cycle`
//! message (schema `h4.SlaveProcessCycle`) carries the arm's reading of that cycle
//! (`actuators_mm`, `wrench_sensor`) and the loop's time (`time_ns`). The driver's clock
//! starts at the first record and moves with [`ArmDriver::advance`]; [`ArmDriver::read`]
//! gives the newest record at or before it. Commands are taken and counted but move
//! nothing: the arm does what the recorded one did. After the last record the reading's
//! time stops moving: the endpoint sees a driver that stopped answering.
//!
//! Also the example of docs/drivers.md: a driver is a type with `read` and `command`.

use std::path::Path;

use h4_slave::arm::{ArmDriver, ArmReading};

/// The topic the driver plays back.
pub const REPLAY_TOPIC: &str = "/slave/cycle";

/// Why a recording cannot be played back.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What failed.
        source: std::io::Error,
    },
    /// Not an MCAP file (or unreadable from its start).
    #[error("{path}: not a readable MCAP file: {reason}")]
    Mcap {
        /// The file.
        path: String,
        /// What the reader said.
        reason: String,
    },
    /// A `/slave/cycle` message is not a slave process's cycle with the arm's reading.
    #[error(
        "{path}: message {index} on {REPLAY_TOPIC} has no arm reading ({reason}); record it with `h4-slave run --record` of this version"
    )]
    Record {
        /// The file.
        path: String,
        /// The message's index on the topic.
        index: usize,
        /// What is missing or malformed.
        reason: String,
    },
    /// No message on the topic.
    #[error("{path}: no {REPLAY_TOPIC} messages to play back")]
    Empty {
        /// The file.
        path: String,
    },
}

/// The fields of a recorded cycle the driver needs (the others are ignored).
#[derive(serde::Deserialize)]
struct Recorded {
    time_ns: u64,
    actuators_mm: [f64; 4],
    wrench_sensor: [f64; 4],
}

/// An arm played back from a recording.
#[derive(Clone, Debug)]
pub struct ReplayArm {
    readings: Vec<ArmReading>,
    next: usize,
    clock_ns: u64,
    commands: u64,
    last_command_mm: Option<[f64; 4]>,
}

impl ReplayArm {
    /// Loads every `/slave/cycle` reading of the MCAP file at `path` (read whole before the
    /// loop: playing back allocates nothing). A torn tail (a recording cut by a crash) ends
    /// the playback where it becomes unreadable.
    pub fn open(path: &Path) -> Result<Self, ReplayError> {
        let name = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| ReplayError::Io {
            path: name.clone(),
            source,
        })?;
        let stream = mcap::MessageStream::new(&bytes).map_err(|e| ReplayError::Mcap {
            path: name.clone(),
            reason: e.to_string(),
        })?;
        let mut readings = Vec::new();
        for (seen, m) in stream.enumerate() {
            let m = match m {
                Ok(m) => m,
                Err(e) if seen == 0 => {
                    return Err(ReplayError::Mcap {
                        path: name,
                        reason: e.to_string(),
                    });
                }
                Err(_) => break,
            };
            if m.channel.topic != REPLAY_TOPIC {
                continue;
            }
            let record = |reason: String| ReplayError::Record {
                path: name.clone(),
                index: readings.len(),
                reason,
            };
            let r: Recorded = serde_json::from_slice(&m.data).map_err(|e| record(e.to_string()))?;
            if !r
                .actuators_mm
                .iter()
                .chain(&r.wrench_sensor)
                .all(|v| v.is_finite())
            {
                return Err(record("a non-finite value".to_string()));
            }
            readings.push(ArmReading {
                time_ns: r.time_ns,
                actuators_mm: r.actuators_mm,
                wrench: r.wrench_sensor,
            });
        }
        Self::from_readings(readings).ok_or(ReplayError::Empty { path: name })
    }

    /// A driver playing `readings` back (in order of their `time_ns`); None without any.
    pub fn from_readings(mut readings: Vec<ArmReading>) -> Option<Self> {
        readings.sort_by_key(|r| r.time_ns);
        let first = readings.first()?.time_ns;
        Some(ReplayArm {
            readings,
            next: 0,
            clock_ns: first,
            commands: 0,
            last_command_mm: None,
        })
    }

    /// The readings played back.
    pub fn len(&self) -> usize {
        self.readings.len()
    }

    /// Never true (a driver holds at least one reading).
    pub fn is_empty(&self) -> bool {
        self.readings.is_empty()
    }

    /// The first reading (where the recorded arm started).
    pub fn first(&self) -> ArmReading {
        self.readings.first().copied().unwrap_or_default()
    }

    /// Every reading has been played.
    pub fn finished(&self) -> bool {
        self.next >= self.readings.len()
    }

    /// Commands taken so far, and the newest.
    pub fn commands(&self) -> (u64, Option<[f64; 4]>) {
        (self.commands, self.last_command_mm)
    }
}

impl ArmDriver for ReplayArm {
    fn read(&mut self) -> ArmReading {
        while self
            .readings
            .get(self.next)
            .is_some_and(|r| r.time_ns <= self.clock_ns)
        {
            self.next += 1;
        }
        self.readings
            .get(self.next.saturating_sub(1))
            .copied()
            .unwrap_or_default()
    }

    fn command(&mut self, actuators_mm: &[f64; 4]) {
        self.commands += 1;
        self.last_command_mm = Some(*actuators_mm);
    }

    fn advance(&mut self, dt_ns: u64) {
        self.clock_ns = self.clock_ns.saturating_add(dt_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(t: u64, z: f64) -> ArmReading {
        ArmReading {
            time_ns: t,
            actuators_mm: [z; 4],
            wrench: [0.0, 0.0, z, 0.0],
        }
    }

    /// The driver gives the newest reading at or before its clock, and its time stops
    /// moving after the last one.
    #[test]
    fn plays_in_time_and_stops_at_the_end() {
        let mut arm = ReplayArm::from_readings(vec![
            reading(2_000_000, 2.0),
            reading(0, 0.0),
            reading(1_000_000, 1.0),
        ])
        .unwrap();
        assert_eq!(arm.read().actuators_mm[0], 0.0);
        assert_eq!(arm.read().time_ns, 0);
        arm.advance(1_500_000);
        assert_eq!(arm.read().actuators_mm[0], 1.0);
        arm.advance(500_000);
        assert_eq!(arm.read().actuators_mm[0], 2.0);
        assert!(arm.finished());
        arm.advance(5_000_000);
        assert_eq!(arm.read().time_ns, 2_000_000, "the last reading is held");
        arm.command(&[1.0; 4]);
        assert_eq!(arm.commands(), (1, Some([1.0; 4])));
        assert!(ReplayArm::from_readings(Vec::new()).is_none());
    }

    /// A file that is not MCAP is refused with its reason.
    #[test]
    fn a_file_that_is_not_mcap_is_refused() {
        let dir = std::env::temp_dir().join(format!("h4-replay-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("not.mcap");
        std::fs::write(&p, b"hello").unwrap();
        let e = ReplayArm::open(&p).unwrap_err().to_string();
        assert!(e.contains("not a readable MCAP file"), "{e}");
        let e = ReplayArm::open(&dir.join("missing.mcap"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing.mcap"), "{e}");
    }
}
