//! Two connected link ends in one process: fixed-capacity queues allocated once, drop-oldest
//! when full, deterministic. Used by tests and the lockstep whole-session simulation.

use std::collections::VecDeque;
use std::marker::PhantomData;
use std::sync::{Arc, Mutex};

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

type Shared<T> = Arc<Mutex<Ring<T>>>;

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
    let commands = Arc::new(Mutex::new(Ring::new(capacity)));
    let feedback = Arc::new(Mutex::new(Ring::new(capacity)));
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
        let mut q = self.tx.lock().map_err(|_| LinkError::Closed)?;
        q.push(*msg);
        Ok(())
    }

    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        let mut q = self.rx.lock().map_err(|_| LinkError::Closed)?;
        Ok(q.pop())
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
        if let Ok(mut q) = self.tx.lock() {
            q.push(bytes.to_vec());
        }
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
    let commands = Arc::new(Mutex::new(Ring::new(capacity)));
    let feedback = Arc::new(Mutex::new(Ring::new(capacity)));
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
        let mut q = self.tx.lock().map_err(|_| LinkError::Closed)?;
        q.push(bytes);
        Ok(())
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
}
