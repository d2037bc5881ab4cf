//! The link watchdog: trips when no valid message has been seen for a timeout on the
//! caller's clock (pure logic, no clock of its own).

/// Trips when no valid message has been seen for `timeout_ns` on the caller's clock.
#[derive(Clone, Copy, Debug)]
pub struct Watchdog {
    timeout_ns: u64,
    last_valid_ns: Option<u64>,
}

impl Watchdog {
    /// A watchdog that has seen nothing yet (it is not tripped until the first message).
    pub fn new(timeout_ns: u64) -> Self {
        Watchdog {
            timeout_ns,
            last_valid_ns: None,
        }
    }

    /// A valid message arrived at `now_ns`.
    pub fn feed(&mut self, now_ns: u64) {
        self.last_valid_ns = Some(now_ns);
    }

    /// Whether a message was ever seen.
    pub fn ever_fed(&self) -> bool {
        self.last_valid_ns.is_some()
    }

    /// Time since the last valid message, or `None` before the first.
    pub fn silence_ns(&self, now_ns: u64) -> Option<u64> {
        self.last_valid_ns.map(|t| now_ns.saturating_sub(t))
    }

    /// Tripped: something was seen, and nothing valid for longer than the timeout.
    pub fn tripped(&self, now_ns: u64) -> bool {
        self.silence_ns(now_ns).is_some_and(|s| s > self.timeout_ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn watchdog_trips_only_after_silence() {
        let mut w = Watchdog::new(20_000_000);
        assert!(!w.tripped(1_000_000_000), "not before the first message");
        w.feed(1_000_000_000);
        assert!(!w.tripped(1_020_000_000));
        assert!(w.tripped(1_020_000_001));
        w.feed(1_030_000_000);
        assert!(!w.tripped(1_040_000_000));
    }
}
