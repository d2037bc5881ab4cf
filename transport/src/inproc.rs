//! Two connected link ends in one process: fixed-capacity queues allocated once, drop-oldest
//! when full, deterministic. Used by tests and the lockstep whole-session simulation.

use std::collections::VecDeque;
use std::marker::PhantomData;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;

use h4_shared::wire::{Command, Feedback, WireMessage};

use crate::{DecodeRejects, Link, LinkError};

/// A bounded queue that drops its oldest entry when full; never reallocates.
#[derive(Debug)]
pub(crate) struct Ring<T> {
    items: VecDeque<T>,
    capacity: usize,
    dropped: u64,
}

impl<T> Ring<T> {
    pub(crate) fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Ring {
            items: VecDeque::with_capacity(capacity),
            capacity,
            dropped: 0,
        }
    }
    pub(crate) fn push(&mut self, item: T) {
        if self.items.len() == self.capacity {
            self.items.pop_front();
            self.dropped += 1;
        }
        self.items.push_back(item);
    }
    pub(crate) fn pop(&mut self) -> Option<T> {
        self.items.pop_front()
    }
    pub(crate) fn dropped(&self) -> u64 {
        self.dropped
    }
    pub(crate) fn is_empty(&self) -> bool {
        self.items.is_empty()
    }
}

/// One direction of an in-process link: the ring, and the signal a waiting receiver
/// ([`Link::wait_message`]) sleeps on. `waiters` spares the publisher the wake-up call when
/// nobody waits (the lockstep simulation never does).
#[derive(Debug)]
pub(crate) struct Queue<T> {
    ring: Mutex<Ring<T>>,
    arrived: Condvar,
    waiters: AtomicUsize,
}

impl<T> Queue<T> {
    fn new(capacity: usize) -> Arc<Self> {
        Arc::new(Queue {
            ring: Mutex::new(Ring::new(capacity)),
            arrived: Condvar::new(),
            waiters: AtomicUsize::new(0),
        })
    }

    fn lock(&self) -> std::sync::LockResult<std::sync::MutexGuard<'_, Ring<T>>> {
        self.ring.lock()
    }

    /// Queues `item` and wakes a waiting receiver.
    fn push(&self, item: T) -> Result<(), LinkError> {
        self.ring.lock().map_err(|_| LinkError::Closed)?.push(item);
        if self.waiters.load(Ordering::Acquire) > 0 {
            self.arrived.notify_all();
        }
        Ok(())
    }

    /// Blocks until the ring holds an item or `deadline` passes; true if it holds one.
    pub(crate) fn wait(&self, deadline: Instant) -> Result<bool, LinkError> {
        let ring = self.ring.lock().map_err(|_| LinkError::Closed)?;
        if !ring.is_empty() {
            return Ok(true);
        }
        let timeout = deadline.saturating_duration_since(Instant::now());
        if timeout.is_zero() {
            return Ok(false);
        }
        self.waiters.fetch_add(1, Ordering::AcqRel);
        let waited = self
            .arrived
            .wait_timeout_while(ring, timeout, |r| r.is_empty());
        self.waiters.fetch_sub(1, Ordering::AcqRel);
        let (ring, _) = waited.map_err(|_| LinkError::Closed)?;
        Ok(!ring.is_empty())
    }
}

type Shared<T> = Arc<Queue<T>>;

/// One end of an in-process link.
#[derive(Debug)]
pub struct InprocEnd<Out, In> {
    tx: Shared<Out>,
    rx: Shared<In>,
    _marker: PhantomData<(Out, In)>,
}

/// A connected pair: the master's end and the slave's end, each queue holding `capacity`
/// messages.
pub fn pair(capacity: usize) -> (InprocEnd<Command, Feedback>, InprocEnd<Feedback, Command>) {
    let commands = Queue::new(capacity);
    let feedback = Queue::new(capacity);
    (
        InprocEnd {
            tx: commands.clone(),
            rx: feedback.clone(),
            _marker: PhantomData,
        },
        InprocEnd {
            tx: feedback,
            rx: commands,
            _marker: PhantomData,
        },
    )
}

impl<Out, In> InprocEnd<Out, In> {
    /// Messages this end published that were dropped because the peer did not read them in time.
    pub fn dropped_outgoing(&self) -> u64 {
        self.tx.lock().map_or(0, |q| q.dropped())
    }
}

impl<Out: WireMessage, In: WireMessage> Link<Out, In> for InprocEnd<Out, In> {
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError> {
        self.tx.push(*msg)
    }

    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        let mut q = self.rx.lock().map_err(|_| LinkError::Closed)?;
        Ok(q.pop())
    }

    fn wait_message(&mut self, deadline: Instant) -> Result<bool, LinkError> {
        self.rx.wait(deadline)
    }

    fn can_wake(&self) -> bool {
        true
    }
}

/// The outside client's end of a byte-level in-process link: it sends and receives raw
/// payloads, as a client in another language does over Zenoh (for tests of the wire format
/// and of the receive path; it allocates per message).
#[derive(Debug)]
pub struct RawEnd {
    tx: Shared<Vec<u8>>,
    rx: Shared<Vec<u8>>,
}

impl RawEnd {
    /// Sends one payload.
    pub fn send(&mut self, bytes: &[u8]) {
        let _ = self.tx.push(bytes.to_vec());
    }

    /// The next payload that has arrived, or `None`.
    pub fn recv(&mut self) -> Option<Vec<u8>> {
        self.rx.lock().ok().and_then(|mut q| q.pop())
    }
}

/// An endpoint's end of a byte-level in-process link: it encodes what it publishes and
/// decodes what it receives exactly as the Zenoh link does (payloads that do not decode are
/// counted by reason in [`Link::decode_rejects`] and never delivered).
#[derive(Debug)]
pub struct DecodingEnd<Out, In> {
    tx: Shared<Vec<u8>>,
    rx: Shared<Vec<u8>>,
    rejects: DecodeRejects,
    _marker: PhantomData<(Out, In)>,
}

/// A byte-level pair: the outside client's raw end (a master) and the slave's decoding end.
pub fn raw_pair(capacity: usize) -> (RawEnd, DecodingEnd<Feedback, Command>) {
    let commands = Queue::new(capacity);
    let feedback = Queue::new(capacity);
    (
        RawEnd {
            tx: commands.clone(),
            rx: feedback.clone(),
        },
        DecodingEnd {
            tx: feedback,
            rx: commands,
            rejects: DecodeRejects::default(),
            _marker: PhantomData,
        },
    )
}

impl<Out: WireMessage, In: WireMessage> Link<Out, In> for DecodingEnd<Out, In> {
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError> {
        let mut bytes = vec![0u8; Out::WIRE_SIZE];
        msg.encode_into(&mut bytes)
            .map_err(|_| LinkError::SendFailed {
                transport: "inproc-bytes",
            })?;
        self.tx.push(bytes)
    }

    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        loop {
            let next = self.rx.lock().map_err(|_| LinkError::Closed)?.pop();
            let Some(bytes) = next else {
                return Ok(None);
            };
            match crate::decode_payload::<In>(&bytes, bytes.len()) {
                Ok(msg) => return Ok(Some(msg)),
                Err(e) => self.rejects.count(&e),
            }
        }
    }

    fn decode_rejects(&self) -> DecodeRejects {
        self.rejects
    }

    fn wait_message(&mut self, deadline: Instant) -> Result<bool, LinkError> {
        self.rx.wait(deadline)
    }

    fn can_wake(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_queue_drops_oldest() {
        let (mut master, mut slave) = pair(2);
        for seq in 1..=3 {
            master
                .publish(&Command {
                    seq,
                    ..Command::default()
                })
                .unwrap();
        }
        assert_eq!(master.dropped_outgoing(), 1);
        assert_eq!(slave.try_recv().unwrap().map(|c| c.seq), Some(2));
        assert_eq!(slave.recv_latest().unwrap().map(|c| c.seq), Some(3));
        assert_eq!(slave.try_recv().unwrap(), None);
    }

    #[test]
    fn a_waiting_receiver_is_woken_by_the_message() {
        let (mut master, mut slave) = pair(4);
        // Nothing sent: the wait ends at its deadline with nothing waiting.
        assert!(!slave.wait_message(Instant::now()).unwrap());
        // A message sent while the receiver waits (with a deadline it never reaches) wakes it.
        let sender = std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(20));
            master
                .publish(&Command {
                    seq: 7,
                    ..Command::default()
                })
                .unwrap();
            master
        });
        let far = Instant::now() + std::time::Duration::from_secs(600);
        assert!(slave.wait_message(far).unwrap());
        assert_eq!(slave.try_recv().unwrap().map(|c| c.seq), Some(7));
        let _master = sender.join().unwrap();
        // A message already waiting: true at once, whatever the deadline.
        let (mut m2, mut s2) = pair(4);
        m2.publish(&Command::default()).unwrap();
        assert!(s2.wait_message(Instant::now()).unwrap());
    }
}
