//! What the operator sees of the link in `h4-master run`: the feedback loss measured from
//! the slave's sequence numbers and the link's state, for the status line (over the last
//! status interval) and the summary (over the run). Per cycle it only compares and adds
//! integers: no allocation, no blocking.

use h4_shared::wire::Feedback;
use serde::{Deserialize, Serialize};

/// The link as the master sees it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LinkState {
    /// No feedback yet.
    #[default]
    Waiting,
    /// Feedback arrives; the slave's force is rendered in full (fade 1).
    Up,
    /// Feedback stopped or just returned: the rendered force is fading (0 < fade < 1).
    Fading,
    /// No feedback for longer than the fade: nothing is rendered (fade 0).
    Down,
}

impl LinkState {
    /// The state of a cycle with this fade factor, once feedback has arrived.
    pub fn from_fade(fade: f64) -> Self {
        if fade >= 1.0 {
            LinkState::Up
        } else if fade > 0.0 {
            LinkState::Fading
        } else {
            LinkState::Down
        }
    }

    /// A word for the status line.
    pub fn word(self) -> &'static str {
        match self {
            LinkState::Waiting => "waiting",
            LinkState::Up => "up",
            LinkState::Fading => "fading",
            LinkState::Down => "down",
        }
    }
}

/// Feedback loss from sequence numbers: the slave numbers its feedback +1 per message, so
/// the messages it sent since the first one seen are `newest − first + 1`; the ones the
/// gate accepted are the ones that arrived. A restarted slave (numbers start again) starts
/// a new span.
#[derive(Clone, Copy, Debug, Default)]
pub struct LossMeter {
    first_seq: Option<u64>,
    newest_seq: u64,
    accepted_at_first: u64,
    /// Spans of slaves before a restart: sent and arrived.
    closed_sent: u64,
    closed_arrived: u64,
    /// The status line's window: sent and arrived at its start.
    window_sent: u64,
    window_arrived: u64,
    last_accepted: u64,
    state: LinkState,
    down_cycles: u64,
}

impl LossMeter {
    /// A meter with nothing seen.
    pub fn new() -> Self {
        Self::default()
    }

    /// Books one cycle: the newest valid feedback, the gate's accepted count, the fade.
    pub fn cycle(&mut self, latest: Option<&Feedback>, accepted: u64, fade: f64) {
        if let Some(fb) = latest {
            match self.first_seq {
                Some(_) if fb.seq < self.newest_seq => {
                    // A new slave session: close the old span.
                    let (sent, arrived) = self.span(accepted.saturating_sub(1));
                    self.closed_sent += sent;
                    self.closed_arrived += arrived;
                    self.first_seq = Some(fb.seq);
                    self.accepted_at_first = accepted.saturating_sub(1);
                }
                Some(_) => {}
                None => {
                    self.first_seq = Some(fb.seq);
                    self.accepted_at_first = accepted.saturating_sub(1);
                }
            }
            self.newest_seq = fb.seq;
            self.state = LinkState::from_fade(fade);
        }
        if self.state == LinkState::Down {
            self.down_cycles += 1;
        }
        self.last_accepted = accepted;
    }

    fn span(&self, accepted: u64) -> (u64, u64) {
        match self.first_seq {
            Some(first) => (
                self.newest_seq.saturating_sub(first) + 1,
                accepted.saturating_sub(self.accepted_at_first),
            ),
            None => (0, 0),
        }
    }

    /// Feedback messages the slave sent and the master received, over the run.
    pub fn totals(&self) -> (u64, u64) {
        let (sent, arrived) = self.span(self.last_accepted);
        (self.closed_sent + sent, self.closed_arrived + arrived)
    }

    /// Feedback lost over the run, % of what the slave sent (0 before any feedback).
    pub fn loss_pct(&self) -> f64 {
        pct(self.totals())
    }

    /// Feedback lost since the previous call, % (the status line's window), and starts a
    /// new window.
    pub fn window_loss_pct(&mut self) -> f64 {
        let (sent, arrived) = self.totals();
        let w = (
            sent.saturating_sub(self.window_sent),
            arrived.saturating_sub(self.window_arrived),
        );
        self.window_sent = sent;
        self.window_arrived = arrived;
        pct(w)
    }

    /// The link's state in the newest cycle.
    pub fn state(&self) -> LinkState {
        self.state
    }

    /// Cycles with the link down (nothing rendered).
    pub fn down_cycles(&self) -> u64 {
        self.down_cycles
    }
}

fn pct((sent, arrived): (u64, u64)) -> f64 {
    if sent == 0 {
        0.0
    } else {
        100.0 * sent.saturating_sub(arrived) as f64 / sent as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fb(seq: u64) -> Feedback {
        Feedback {
            seq,
            ..Feedback::default()
        }
    }

    #[test]
    fn counts_gaps_in_the_slaves_numbers_and_restarts() {
        let mut m = LossMeter::new();
        m.cycle(None, 0, 0.0);
        assert_eq!(m.state(), LinkState::Waiting);
        // Seqs 10..=29 sent, every fourth lost: 15 of 20 arrive.
        let mut accepted = 0;
        for seq in 10..30 {
            if seq % 4 != 0 {
                accepted += 1;
                m.cycle(Some(&fb(seq)), accepted, 1.0);
            } else {
                m.cycle(Some(&fb(seq - 1)), accepted, 1.0);
            }
        }
        assert_eq!(m.totals(), (20, 15));
        assert!((m.loss_pct() - 25.0).abs() < 1e-9);
        assert_eq!(m.state(), LinkState::Up);
        assert!((m.window_loss_pct() - 25.0).abs() < 1e-9);
        assert_eq!(m.window_loss_pct(), 0.0, "an empty window");
        // The slave restarts at 1: a new span; 5 of 5 arrive.
        for seq in 1..=5 {
            accepted += 1;
            m.cycle(Some(&fb(seq)), accepted, 0.5);
        }
        assert_eq!(m.totals(), (25, 20));
        assert_eq!(m.state(), LinkState::Fading);
        m.cycle(Some(&fb(5)), accepted, 0.0);
        assert_eq!(m.state(), LinkState::Down);
        assert_eq!(m.down_cycles(), 1);
    }
}
