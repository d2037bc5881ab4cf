//! The live view: `--foxglove-ws HOST:PORT` serves the processes' per-cycle records over the
//! Foxglove WebSocket protocol (the `foxglove` crate's server), so the Foxglove app, or any
//! client of that protocol, shows a run while it happens.
//!
//! The 1 kHz loop never touches the network or the encoder: [`LiveTopic::push`] keeps one record
//! in every `decimation` (100 Hz by default) and hands it to the topic's own thread through a
//! bounded queue: no allocation, no lock, no blocking; a full queue drops the record and counts
//! it. That thread encodes JSON (the same message shapes and JSON schemas as the MCAP
//! recordings, so one Foxglove layout serves both) and logs it to the server, which itself
//! drops for a client that cannot keep up rather than slowing anything.

use std::sync::Arc;
use std::sync::mpsc::{SyncSender, TrySendError};
use std::thread::JoinHandle;

use serde::Serialize;

/// Default rate of the live view, Hz.
pub const LIVE_RATE_HZ: f64 = 100.0;

/// Records queued per topic between the loop and the encoder thread.
const QUEUE_LEN: usize = 256;

/// The command-line flag, shared by `h4-slave run`, `h4-master run` and `loopback`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct LiveArgs {
    /// Serve a live view over the Foxglove WebSocket protocol at HOST:PORT (e.g.
    /// `127.0.0.1:8765`; port 0 picks a free one, printed on stderr). Open it in Foxglove with
    /// "Open connection" → `ws://HOST:PORT`; the layout is `config/foxglove/h4-teleop.json`.
    #[arg(long = "foxglove-ws", value_name = "HOST:PORT")]
    pub foxglove_ws: Option<String>,
}

impl LiveArgs {
    /// For `loopback`: the slave's address beside the master's, the next port (port 0 stays
    /// 0: each picks its own).
    pub fn slave_address(&self) -> Option<String> {
        let addr = self.foxglove_ws.as_deref()?;
        match addr.rsplit_once(':').map(|(h, p)| (h, p.parse::<u16>())) {
            Some((host, Ok(0))) => Some(format!("{host}:0")),
            Some((host, Ok(port))) => Some(format!("{host}:{}", port.checked_add(1)?)),
            // Malformed: passed on as given, so the slave refuses it with the same message.
            _ => Some(addr.to_string()),
        }
    }
}

/// Why the live view could not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The address is not `HOST:PORT`.
    #[error("--foxglove-ws {0:?}: expected HOST:PORT, e.g. 127.0.0.1:8765")]
    BadAddress(String),
    /// The server could not start (address in use, no permission, …).
    #[error("--foxglove-ws {addr}: {reason}")]
    Start {
        /// The address as given.
        addr: String,
        /// The server's reason.
        reason: String,
    },
    /// A schema could not be generated or a channel could not be made.
    #[error("live view topic {topic}: {reason}")]
    Topic {
        /// The topic.
        topic: String,
        /// Why.
        reason: String,
    },
}

/// A running live-view server. Dropping it stops the server.
pub struct LiveServer {
    ctx: Option<Arc<foxglove::Context>>,
    handle: Option<foxglove::WebSocketServerHandle>,
    addr: String,
}

impl LiveServer {
    /// Starts a server on `addr` (`HOST:PORT`) and says where it listens on stderr.
    pub fn start(addr: &str, name: &str) -> Result<Self, LiveError> {
        let (host, port) = addr
            .rsplit_once(':')
            .and_then(|(h, p)| Some((h.trim_matches(['[', ']']), p.parse::<u16>().ok()?)))
            .filter(|(h, _)| !h.is_empty())
            .ok_or_else(|| LiveError::BadAddress(addr.to_string()))?;
        // Started on a thread of its own: the server's runtime and sockets are set up away
        // from the caller, which may be a real-time loop's thread.
        let (host, name) = (host.to_string(), name.to_string());
        let started = std::thread::spawn(move || {
            let ctx = foxglove::Context::new();
            foxglove::WebSocketServer::new()
                .name(name.clone())
                .bind(host.clone(), port)
                .context(&ctx)
                .start_blocking()
                .map(|handle| {
                    // Said here, not by the caller: nothing of the start-up is on its thread.
                    eprintln!(
                        "{name}: live view at ws://{host}:{} (Foxglove WebSocket)",
                        handle.port()
                    );
                    (ctx, handle, host)
                })
                .map_err(|e| e.to_string())
        })
        .join()
        .unwrap_or_else(|_| Err("the server's start-up thread panicked".to_string()));
        let (ctx, handle, host) = started.map_err(|reason| LiveError::Start {
            addr: addr.to_string(),
            reason,
        })?;
        let addr = format!("{host}:{}", handle.port());
        Ok(LiveServer {
            ctx: Some(ctx),
            handle: Some(handle),
            addr,
        })
    }

    /// Starts a server if an address is given (`--foxglove-ws`).
    pub fn start_if(addr: Option<&str>, name: &str) -> Result<Option<Self>, LiveError> {
        let Some(addr) = addr else {
            return Ok(None);
        };
        Self::start(addr, name).map(Some)
    }

    /// `HOST:PORT` the server listens on (the real port when 0 was asked for).
    pub fn addr(&self) -> &str {
        &self.addr
    }

    /// A topic publishing `T` as JSON with its generated JSON schema, at `rate_hz` out of a
    /// loop running at `loop_hz`.
    pub fn topic<T>(
        &self,
        topic: &str,
        schema_name: &str,
        loop_hz: f64,
        rate_hz: f64,
    ) -> Result<LiveTopic<T>, LiveError>
    where
        T: Serialize + schemars::JsonSchema + Send + 'static,
    {
        let err = |reason: String| LiveError::Topic {
            topic: topic.to_string(),
            reason,
        };
        let schema =
            crate::recording::json_schema_for::<T>(schema_name).map_err(|e| err(e.to_string()))?;
        // The channel is made on a thread of its own (the server is told of it there), and
        // the records are encoded and logged on the topic's thread: the caller, which may be
        // a real-time loop's thread, does neither.
        let ctx = self
            .ctx
            .clone()
            .ok_or_else(|| err("the server is stopped".to_string()))?;
        let (topic_name, schema_name) = (topic.to_string(), schema_name.to_string());
        let channel = std::thread::spawn(move || {
            ctx.channel_builder(topic_name)
                .message_encoding("json")
                .schema(foxglove::Schema::new(
                    schema_name,
                    "jsonschema",
                    schema.into_bytes(),
                ))
                .build_raw()
                .map_err(|e| e.to_string())
        })
        .join()
        .unwrap_or_else(|_| Err("the channel's thread panicked".to_string()))
        .map_err(err)?;
        let (tx, rx) = std::sync::mpsc::sync_channel::<(u64, T)>(QUEUE_LEN);
        let worker = std::thread::Builder::new()
            .name(format!("live{topic}").chars().take(15).collect())
            .spawn(move || {
                let mut buf = Vec::with_capacity(1024);
                for (time_ns, item) in rx {
                    buf.clear();
                    if serde_json::to_writer(&mut buf, &item).is_ok() {
                        channel
                            .log_with_meta(&buf, foxglove::PartialMetadata::with_log_time(time_ns));
                    }
                }
            })
            .map_err(|e| err(e.to_string()))?;
        Ok(LiveTopic {
            tx: Some(tx),
            worker: Some(worker),
            decimation: decimation(loop_hz, rate_hz),
            count: 0,
            dropped: 0,
        })
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        // Stopped, and its context (channels, sinks) released, on a thread of its own: that
        // work (telling clients, the server's runtime) is not the caller's, which may be a
        // real-time loop's thread. Clients are closed without waiting for them.
        let (handle, ctx) = (self.handle.take(), self.ctx.take());
        let _ = std::thread::spawn(move || {
            if let Some(h) = handle {
                h.stop().detach_all();
            }
            drop(ctx);
        })
        .join();
    }
}

/// One in how many cycles is published.
fn decimation(loop_hz: f64, rate_hz: f64) -> u32 {
    if !(loop_hz.is_finite() && rate_hz.is_finite() && rate_hz > 0.0) {
        return 1;
    }
    (loop_hz / rate_hz).round().clamp(1.0, 1e6) as u32
}

/// The loop's end of one live topic (a disabled topic, [`LiveTopic::off`], costs a branch).
pub struct LiveTopic<T: Send + 'static> {
    tx: Option<SyncSender<(u64, T)>>,
    worker: Option<JoinHandle<()>>,
    decimation: u32,
    count: u32,
    dropped: u64,
}

impl<T: Send + 'static> LiveTopic<T> {
    /// A topic that publishes nothing (no `--foxglove-ws`).
    pub fn off() -> Self {
        LiveTopic {
            tx: None,
            worker: None,
            decimation: 1,
            count: 0,
            dropped: 0,
        }
    }

    /// Offers this cycle's record, stamped `time_ns` (ns since the Unix epoch); one in every
    /// `decimation` is queued. Never blocks, never allocates.
    pub fn push(&mut self, time_ns: u64, item: T) {
        let Some(tx) = &self.tx else { return };
        self.count += 1;
        if self.count < self.decimation {
            return;
        }
        self.count = 0;
        match tx.try_send((time_ns, item)) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => self.dropped += 1,
            Err(TrySendError::Disconnected(_)) => {
                self.dropped += 1;
                self.tx = None;
            }
        }
    }

    /// Records dropped because the encoder thread fell behind.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

impl<T: Send + 'static> Drop for LiveTopic<T> {
    fn drop(&mut self) {
        self.tx = None;
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}

/// A live topic from an optional server: [`LiveTopic::off`] without one, or when the topic
/// cannot be made (said once on stderr; the run goes on without it).
pub fn topic_or_off<T>(
    server: Option<&LiveServer>,
    topic: &str,
    schema_name: &str,
    loop_hz: f64,
) -> LiveTopic<T>
where
    T: Serialize + schemars::JsonSchema + Send + 'static,
{
    let Some(server) = server else {
        return LiveTopic::off();
    };
    match server.topic(topic, schema_name, loop_hz, LIVE_RATE_HZ) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("live view: {e}; going on without it");
            LiveTopic::off()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimation_is_loop_rate_over_live_rate() {
        assert_eq!(decimation(1000.0, 100.0), 10);
        assert_eq!(decimation(1000.0, 2000.0), 1);
        assert_eq!(decimation(1000.0, 0.0), 1);
        assert_eq!(decimation(f64::NAN, 100.0), 1);
    }

    #[test]
    fn bad_addresses_are_refused() {
        for a in ["", "8765", "localhost", ":8765", "host:port", "h:99999"] {
            assert!(
                matches!(LiveServer::start(a, "t"), Err(LiveError::BadAddress(_))),
                "{a}"
            );
        }
    }

    #[test]
    fn loopback_gives_the_slave_the_next_port() {
        let args = |a: &str| LiveArgs {
            foxglove_ws: Some(a.to_string()),
        };
        assert_eq!(
            args("127.0.0.1:8765").slave_address().as_deref(),
            Some("127.0.0.1:8766")
        );
        assert_eq!(
            args("127.0.0.1:0").slave_address().as_deref(),
            Some("127.0.0.1:0")
        );
        assert_eq!(args("127.0.0.1:65535").slave_address(), None);
        assert_eq!(LiveArgs::default().slave_address(), None);
    }

    #[test]
    fn an_off_topic_takes_anything() {
        let mut t = LiveTopic::<u64>::off();
        for i in 0..10 {
            t.push(i, i);
        }
        assert_eq!(t.dropped(), 0);
    }
}
