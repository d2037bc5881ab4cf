//! The slave's own round trip (protocol 3): every command echoes the newest feedback the
//! master has accepted (`echo_seq`, `echo_send_time_ns`), and the slave's round trip is its
//! clock now minus the echoed send time. Both stamps are the slave's own clock, so no clock
//! synchronisation is needed; the figure includes the master's hold time (up to one master
//! cycle between the feedback's arrival and the command that echoes it), as the master's own
//! round trip includes the slave's.
//!
//! **The estimator.** A sliding window of the last [`WINDOW`] samples (one per command that
//! brings a new echo; at 1 kHz 256 ms): its median is the round trip the slave uses, and the
//! distance from the median to its 95th percentile is the jitter. Why a windowed median and
//! p95 rather than an exponential average of the round trip and its deviation (TCP's SRTT /
//! RTTVAR, RFC 6298): the samples come at the command rate, so an EWMA with TCP's 1/8 gain
//! follows each jittered sample within 8 ms and the hand-over spring the slave derives from
//! the round trip would wobble with the jitter; a median over a quarter-second moves only
//! when the link's delay does, a lost or late command shifts it by one rank, not by its
//! size, and p95 − p50 is what a playout buffer must add to cover 95 % of the commands
//! (issue 32's jitter item). Per sample: a copy of the window to the stack and two
//! selections (`select_nth_unstable`, O(n)), no allocation. The whole session's samples go
//! to a fixed-size histogram for the summary (`rtt_measured_p50_ms`, `rtt_measured_p99_ms`,
//! `rtt_jitter_ms`).
//!
//! **Which echoes count.** A command brings a new echo when its `(echo_seq,
//! echo_send_time_ns)` differs from the last one taken (a master without new feedback repeats
//! its echo: that age is not a round trip). An echo of a feedback this slave cannot have sent
//! (a `echo_seq` above its own last one, or a send time after now) is refused and counted.

use h4_telemetry::rt::Histogram;

/// Samples in the sliding window.
pub const WINDOW: usize = 256;

/// The slave's measurement of its round trip.
#[derive(Clone, Debug)]
pub struct RoundTripEstimator {
    window: [u64; WINDOW],
    len: usize,
    next: usize,
    last_echo: (u64, u64),
    median_ns: u64,
    jitter_ns: u64,
    histogram: Histogram,
    refused: u64,
}

impl Default for RoundTripEstimator {
    fn default() -> Self {
        Self::new()
    }
}

impl RoundTripEstimator {
    /// No sample yet.
    pub fn new() -> Self {
        RoundTripEstimator {
            window: [0; WINDOW],
            len: 0,
            next: 0,
            last_echo: (0, 0),
            median_ns: 0,
            jitter_ns: 0,
            histogram: Histogram::new(),
            refused: 0,
        }
    }

    /// A command's echo at `now_ns`, the slave having sent feedback up to `own_seq`. Returns
    /// whether it was a new sample.
    pub fn observe(
        &mut self,
        echo_seq: u64,
        echo_send_time_ns: u64,
        own_seq: u64,
        now_ns: u64,
    ) -> bool {
        if echo_seq == 0 || (echo_seq, echo_send_time_ns) == self.last_echo {
            return false;
        }
        if echo_seq > own_seq || echo_send_time_ns > now_ns {
            self.refused += 1;
            return false;
        }
        self.last_echo = (echo_seq, echo_send_time_ns);
        let rtt_ns = now_ns - echo_send_time_ns;
        self.histogram.record(rtt_ns);
        self.window[self.next] = rtt_ns;
        self.next = (self.next + 1) % WINDOW;
        self.len = (self.len + 1).min(WINDOW);
        let mut scratch = self.window;
        let w = &mut scratch[..self.len];
        let mid = self.len / 2;
        let (_, median, _) = w.select_nth_unstable(mid);
        let median = *median;
        let p95 = (self.len * 95 / 100).min(self.len - 1);
        let (_, high, _) = w.select_nth_unstable(p95);
        self.median_ns = median;
        self.jitter_ns = high.saturating_sub(median);
        true
    }

    /// Whether a round trip has been measured.
    pub fn measured(&self) -> bool {
        self.len > 0
    }

    /// The round trip (the window's median), ms; None before the first echo.
    pub fn round_trip_ms(&self) -> Option<f64> {
        self.measured().then_some(self.median_ns as f64 * 1e-6)
    }

    /// The jitter (the window's p95 − p50), ms; None before the first echo.
    pub fn jitter_ms(&self) -> Option<f64> {
        self.measured().then_some(self.jitter_ns as f64 * 1e-6)
    }

    /// Samples taken over the session.
    pub fn samples(&self) -> u64 {
        self.histogram.count()
    }

    /// Echoes refused (of a feedback this slave cannot have sent).
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// The session's samples, ns.
    pub fn histogram(&self) -> &Histogram {
        &self.histogram
    }

    /// The session's `(p50, p99, p95 − p50)`, ms (NaN without a sample): the summaries'
    /// `rtt_measured_p50_ms`, `rtt_measured_p99_ms`, `rtt_jitter_ms`.
    pub fn summary_ms(&self) -> (f64, f64, f64) {
        if self.samples() == 0 {
            return (f64::NAN, f64::NAN, f64::NAN);
        }
        let q = |p| self.histogram.quantile(p) as f64 * 1e-6;
        (q(0.5), q(0.99), (q(0.95) - q(0.5)).max(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The median ignores a few late samples; the jitter is p95 − p50; a repeated echo is no
    /// sample; an echo from the future or of a feedback not yet sent is refused.
    #[test]
    fn the_window_median_and_p95() {
        let mut e = RoundTripEstimator::new();
        assert_eq!(e.round_trip_ms(), None);
        let ms = 1_000_000;
        for i in 1..=200u64 {
            // 100 ms, every tenth sample 40 ms late.
            let rtt = if i % 10 == 0 { 140 * ms } else { 100 * ms };
            let now = 1000 * ms + i * ms;
            assert!(e.observe(i, now - rtt, i + 100, now));
        }
        assert_eq!(e.round_trip_ms(), Some(100.0));
        assert_eq!(e.jitter_ms(), Some(40.0));
        let now = 2000 * ms;
        assert!(!e.observe(200, 1000 * ms + 200 * ms - 140 * ms, 400, now));
        assert!(!e.observe(201, now + 1, 400, now));
        assert!(!e.observe(500, now - ms, 400, now));
        assert_eq!((e.samples(), e.refused()), (200, 2));
    }
}
