//! Edge policies: what a full queue does to the sender.
//!
//! - `block` waits for room (lossless backpressure, the offline default);
//! - `drop_oldest` evicts the oldest queued item to make room (live replay);
//! - `latest` is `drop_oldest` with room for one item, so a consumer always sees the newest.
//!
//! Every eviction is counted. Because only the sender evicts and the consumer only receives,
//! every sent item is either received or counted as dropped, exactly.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use crossbeam_channel::{Receiver, Sender, TryRecvError, TrySendError, select};
use serde::{Deserialize, Serialize};

use crate::message::Message;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EdgePolicy {
    #[default]
    Block,
    DropOldest,
    Latest,
}

impl EdgePolicy {
    pub const ACCEPTED: &'static str = "block, drop_oldest, latest";

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Block => "block",
            Self::DropOldest => "drop_oldest",
            Self::Latest => "latest",
        }
    }

    /// The queue capacity actually used for a requested one.
    pub fn effective_capacity(self, requested: usize) -> usize {
        match self {
            Self::Latest => 1,
            _ => requested.max(1),
        }
    }
}

/// Counters of one edge, shared between its sender and the metrics report.
#[derive(Debug, Default)]
pub struct EdgeCounters {
    pub sent: AtomicU64,
    pub dropped: AtomicU64,
}

/// The sending half of one edge, applying the edge's policy.
pub struct EdgeSender {
    pub(crate) tx: Sender<Message>,
    /// Kept by evicting policies so the sender can pop the oldest item.
    pub(crate) evict: Option<Receiver<Message>>,
    pub(crate) counters: Arc<EdgeCounters>,
    pub(crate) abort: Receiver<()>,
}

/// Why a send did not deliver.
#[derive(Debug, PartialEq, Eq)]
pub enum SendOutcome {
    Queued,
    /// The receiving node is gone, or the graph is aborting.
    Closed,
}

impl EdgeSender {
    pub fn send(&self, message: Message) -> SendOutcome {
        self.counters.sent.fetch_add(1, Ordering::Relaxed);
        match &self.evict {
            None => self.send_blocking(message),
            Some(oldest) => self.send_evicting(message, oldest),
        }
    }

    fn send_blocking(&self, message: Message) -> SendOutcome {
        // Fast path: room in the queue, no select needed.
        let message = match self.tx.try_send(message) {
            Ok(()) => return SendOutcome::Queued,
            Err(TrySendError::Disconnected(_)) => return SendOutcome::Closed,
            Err(TrySendError::Full(message)) => message,
        };
        select! {
            send(self.tx, message) -> result => match result {
                Ok(()) => SendOutcome::Queued,
                Err(_) => SendOutcome::Closed,
            },
            recv(self.abort) -> _ => SendOutcome::Closed,
        }
    }

    fn send_evicting(&self, mut message: Message, oldest: &Receiver<Message>) -> SendOutcome {
        loop {
            match self.tx.try_send(message) {
                Ok(()) => return SendOutcome::Queued,
                Err(TrySendError::Disconnected(_)) => return SendOutcome::Closed,
                Err(TrySendError::Full(back)) => {
                    message = back;
                    match oldest.try_recv() {
                        Ok(_evicted) => {
                            self.counters.dropped.fetch_add(1, Ordering::Relaxed);
                        }
                        // The consumer took it first: there is room now.
                        Err(TryRecvError::Empty) => {}
                        Err(TryRecvError::Disconnected) => return SendOutcome::Closed,
                    }
                }
            }
        }
    }
}
