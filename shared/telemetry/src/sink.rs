//! Where a real-time server's per-cycle records go: the recording and the live view. The
//! servers of the product crates (h4-slave, h4-master) are generic over a [`Sink`], so they
//! build without mcap or foxglove; the command-line crates hand them [`Outputs`] (an MCAP
//! recording through [`crate::recording::BackgroundRecorder`] and the Foxglove live view
//! through [`crate::live`]), a test may hand them [`NoSink`] or its own.
//!
//! A sink is called from the 1 kHz loop: it must never block, allocate or log (the
//! recorder and the live topics queue into bounded channels and count what they drop).

/// What a server's loop hands out every cycle: `T` its record (e.g. `/slave/cycle`), `U` a
/// second record some cycles carry (e.g. the simulated arm's `/slave/cut`).
pub trait Sink<T, U = ()> {
    /// One cycle for the recording.
    fn record(&mut self, unix_ns: u64, first: T, second: Option<U>);
    /// One cycle for the live view (not called after a stop request).
    fn show(&mut self, unix_ns: u64, first: T, second: Option<U>);
    /// Records the recording dropped because its writer fell behind.
    fn dropped(&self) -> u64;
    /// Closes the recording (waits for its writer).
    fn finish(self) -> Result<(), String>;
}

/// No recording, no live view.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoSink;

impl<T, U> Sink<T, U> for NoSink {
    fn record(&mut self, _: u64, _: T, _: Option<U>) {}
    fn show(&mut self, _: u64, _: T, _: Option<U>) {}
    fn dropped(&self) -> u64 {
        0
    }
    fn finish(self) -> Result<(), String> {
        Ok(())
    }
}

/// Why the outputs could not start.
#[cfg(feature = "live")]
#[derive(Debug, thiserror::Error)]
pub enum OutputsError {
    /// The recording could not be created.
    #[error("recording: {0}")]
    Recording(String),
    /// The live view could not start.
    #[error("{0}")]
    Live(#[from] crate::live::LiveError),
}

/// A topic: its name and its schema's name (e.g. `/slave/cycle`, `h4.SlaveProcessCycle`).
pub type TopicName<'a> = (&'a str, &'a str);

/// The MCAP recording (`--record`) and the live view (`--foxglove-ws`) of a server, either
/// or both off.
#[cfg(feature = "live")]
pub struct Outputs<T: Send + 'static, U: Send + 'static = ()> {
    recorder: crate::recording::BackgroundRecorder<T, U>,
    live: crate::live::LiveTopic<T>,
    live_second: crate::live::LiveTopic<U>,
    // Declared last: dropped after its topics.
    _server: Option<crate::live::LiveServer>,
}

#[cfg(feature = "live")]
impl<T, U> Outputs<T, U>
where
    T: serde::Serialize + schemars::JsonSchema + Send + 'static,
    U: serde::Serialize + schemars::JsonSchema + Send + 'static,
{
    /// Records `first` (and `second` when given) into `record`, and serves them live at
    /// `live_addr` as `server_name`, for a loop at `loop_hz`.
    pub fn start(
        record: Option<&std::path::Path>,
        live_addr: Option<&str>,
        server_name: &str,
        first: TopicName<'_>,
        second: Option<TopicName<'_>>,
        loop_hz: f64,
    ) -> Result<Self, OutputsError> {
        Self::start_polled(record, live_addr, server_name, first, second, loop_hz, None)
    }

    /// [`Outputs::start`], the recording also holding `polled`'s channels (written by the
    /// recording thread, sampled at their own rate: the ROS 2 topics of `--record-ros2`).
    pub fn start_polled(
        record: Option<&std::path::Path>,
        live_addr: Option<&str>,
        server_name: &str,
        first: TopicName<'_>,
        second: Option<TopicName<'_>>,
        loop_hz: f64,
        polled: Option<crate::recording::PolledChannels>,
    ) -> Result<Self, OutputsError> {
        let recorder = crate::recording::BackgroundRecorder::start_two_for_polled(
            record, first.0, first.1, second, polled,
        )
        .map_err(|e| OutputsError::Recording(e.to_string()))?;
        let server = crate::live::LiveServer::start_if(live_addr, server_name)?;
        let live = crate::live::topic_or_off::<T>(server.as_ref(), first.0, first.1, loop_hz);
        let live_second = match second {
            Some((topic, schema)) => {
                crate::live::topic_or_off::<U>(server.as_ref(), topic, schema, loop_hz)
            }
            None => crate::live::LiveTopic::off(),
        };
        Ok(Outputs {
            recorder,
            live,
            live_second,
            _server: server,
        })
    }
}

#[cfg(feature = "live")]
impl<T, U> Sink<T, U> for Outputs<T, U>
where
    T: serde::Serialize + Copy + Send + 'static,
    U: serde::Serialize + Copy + Send + 'static,
{
    fn record(&mut self, unix_ns: u64, first: T, second: Option<U>) {
        self.recorder.push(unix_ns, first);
        if let Some(s) = second {
            self.recorder.push_second(unix_ns, s);
        }
    }
    fn show(&mut self, unix_ns: u64, first: T, second: Option<U>) {
        self.live.push(unix_ns, first);
        if let Some(s) = second {
            self.live_second.push(unix_ns, s);
        }
    }
    fn dropped(&self) -> u64 {
        self.recorder.dropped()
    }
    fn finish(self) -> Result<(), String> {
        self.recorder.finish()
    }
}
