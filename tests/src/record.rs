//! Reading a slave process's recording (`h4-slave run --record`, topic `/slave/cycle`) for
//! the link-fault tests: the state, true force and pose of every cycle on the slave's own
//! clock, and what happened around a link fault.

use std::path::Path;

use serde::Deserialize;

/// One recorded slave cycle (the fields of `h4.SlaveProcessCycle` these tests use).
#[derive(Clone, Copy, Debug, Deserialize)]
pub struct SlaveCycle {
    /// The loop's clock, ns.
    pub time_ns: u64,
    /// `SlaveState` code: 0 idle, 1 active, 2 safe stop.
    pub state: u8,
    /// True contact force magnitude, N.
    pub force_true_n: f64,
    /// Measured pose [x, y, z, theta], mm, rad.
    pub measured_pose: [f64; 4],
    /// Sequence number of the command acted on.
    pub command_seq: u64,
}

/// Active state code.
pub const ACTIVE: u8 = 1;
/// Safe-stop state code.
pub const SAFE_STOP: u8 = 2;

/// The `/slave/cycle` records of an MCAP file, in order.
pub fn slave_cycles(path: &Path) -> Result<Vec<SlaveCycle>, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let stream = mcap::MessageStream::new(&bytes).map_err(|e| e.to_string())?;
    let mut out = Vec::new();
    for m in stream {
        let m = m.map_err(|e| e.to_string())?;
        if m.channel.topic == "/slave/cycle" {
            out.push(serde_json::from_slice::<SlaveCycle>(&m.data).map_err(|e| e.to_string())?);
        }
    }
    Ok(out)
}

/// One stretch of safe state in a recording and what came around it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SafeEpisode {
    /// Slave clock of the last cycle that acted on a new command before the episode, s.
    pub last_command_s: f64,
    /// Slave clock of the first safe-stop cycle, s.
    pub entry_s: f64,
    /// Slave clock of the first active cycle after it (re-paired), s; `None`: never.
    pub repaired_s: Option<f64>,
    /// True force when the episode began, N.
    pub force_at_entry_n: f64,
    /// Largest true force during the episode, N.
    pub max_force_in_episode_n: f64,
    /// True force in the episode's last safe cycle, N.
    pub force_at_end_n: f64,
    /// Largest pose change from one cycle to the next (x, y, z), mm, over the second after
    /// the re-pairing (divided by the recorded cycles' spacing in ms where records are
    /// missing).
    pub max_step_after_mm: f64,
    /// Largest true force over the second after the re-pairing, N.
    pub max_force_after_n: f64,
}

fn secs(ns: u64) -> f64 {
    ns as f64 * 1e-9
}

/// The safe-state episodes of a recording, in order.
pub fn safe_episodes(c: &[SlaveCycle]) -> Vec<SafeEpisode> {
    let mut out = Vec::new();
    let mut i = 1;
    while i < c.len() {
        if !(c[i].state == SAFE_STOP && c[i - 1].state != SAFE_STOP) {
            i += 1;
            continue;
        }
        let entry = i;
        // The last cycle before the entry whose command differed from its predecessor's.
        let last_cmd = (1..entry)
            .rev()
            .find(|&k| c[k].command_seq != c[k - 1].command_seq)
            .unwrap_or(0);
        let mut j = entry;
        while j < c.len() && c[j].state == SAFE_STOP {
            j += 1;
        }
        let episode = &c[entry..j];
        let repaired = (j < c.len() && c[j].state == ACTIVE).then_some(j);
        let (mut max_step, mut max_force_after) = (0.0_f64, 0.0_f64);
        if let Some(r) = repaired {
            let until = c[r].time_ns + 1_000_000_000;
            for k in (r + 1)..c.len() {
                if c[k].time_ns > until {
                    break;
                }
                let dt_ms = ((c[k].time_ns - c[k - 1].time_ns) as f64 / 1e6).max(1.0);
                let d: f64 = (0..3)
                    .map(|a| (c[k].measured_pose[a] - c[k - 1].measured_pose[a]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                max_step = max_step.max(d / dt_ms);
                max_force_after = max_force_after.max(c[k].force_true_n);
            }
        }
        out.push(SafeEpisode {
            last_command_s: secs(c[last_cmd].time_ns),
            entry_s: secs(c[entry].time_ns),
            repaired_s: repaired.map(|r| secs(c[r].time_ns)),
            force_at_entry_n: c[entry].force_true_n,
            max_force_in_episode_n: episode.iter().map(|x| x.force_true_n).fold(0.0, f64::max),
            force_at_end_n: episode.last().map_or(0.0, |x| x.force_true_n),
            max_step_after_mm: max_step,
            max_force_after_n: max_force_after,
        });
        i = j;
    }
    out
}
