//! A one-item hand-over between two threads, the newest wins: `offer` never waits (an item not
//! taken yet is replaced, and counted as dropped), `take` waits for an item or for `close`.
//! The node hands each complete set from its executor to the GPU thread through one
//! (`node/events.rs` -> `node/worker.rs`), the live view each offered set from the engine's
//! thread to its own (`viewer/server.rs`).

use std::sync::{Condvar, Mutex, MutexGuard};

struct State<T> {
    pending: Option<T>,
    closed: bool,
    dropped: u64,
}

/// Capacity-1 "newest wins" channel.
pub struct Handoff<T> {
    state: Mutex<State<T>>,
    ready: Condvar,
}

impl<T> Default for Handoff<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T> Handoff<T> {
    pub fn new() -> Self {
        Self {
            state: Mutex::new(State {
                pending: None,
                closed: false,
                dropped: 0,
            }),
            ready: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State<T>> {
        // A poisoned lock only means a holder panicked; the state (an Option and two counters)
        // is always consistent.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Offers `item`; returns true if it replaced a pending one (that one is dropped and
    /// counted). Never waits. Once closed, the item is dropped (not counted) and it returns
    /// false.
    pub fn offer(&self, item: T) -> bool {
        let mut state = self.lock();
        if state.closed {
            return false;
        }
        let replaced = state.pending.replace(item).is_some();
        if replaced {
            state.dropped += 1;
        }
        drop(state);
        self.ready.notify_one();
        replaced
    }

    /// Blocks until an item is pending (Some) or the hand-over is closed (None: a pending item
    /// is abandoned, as a thread shutting down has nobody to give its outputs to).
    pub fn take(&self) -> Option<T> {
        self.take_before(None)
    }

    /// [`Handoff::take`] that waits at most `limit`: None when nothing came in time or the
    /// hand-over is closed ([`Handoff::is_closed`] says which).
    pub fn take_timeout(&self, limit: std::time::Duration) -> Option<T> {
        self.take_before(Some(std::time::Instant::now() + limit))
    }

    /// Waits for an item until `deadline` (None: for ever) or `close`.
    fn take_before(&self, deadline: Option<std::time::Instant>) -> Option<T> {
        let mut state = self.lock();
        loop {
            if state.closed {
                state.pending = None;
                return None;
            }
            if let Some(item) = state.pending.take() {
                return Some(item);
            }
            state = match deadline {
                None => self.ready.wait(state).unwrap_or_else(|e| e.into_inner()),
                Some(deadline) => {
                    let left = deadline.saturating_duration_since(std::time::Instant::now());
                    if left.is_zero() {
                        return None;
                    }
                    self.ready
                        .wait_timeout(state, left)
                        .map(|(state, _)| state)
                        .unwrap_or_else(|e| e.into_inner().0)
                }
            };
        }
    }

    /// Whether [`Handoff::close`] was called.
    pub fn is_closed(&self) -> bool {
        self.lock().closed
    }

    /// The pending item if there is one, without waiting; None once closed.
    pub fn try_take(&self) -> Option<T> {
        let mut state = self.lock();
        if state.closed {
            state.pending = None;
            return None;
        }
        state.pending.take()
    }

    /// Wakes the taker; later `take`s return None (a pending item is dropped) and `offer`s
    /// drop their item.
    pub fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }

    /// Items replaced before the taker took them.
    pub fn dropped(&self) -> u64 {
        self.lock().dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn newest_replaces_pending() {
        let slot = Handoff::new();
        assert!(!slot.offer(1));
        assert!(slot.offer(2));
        assert_eq!(slot.take(), Some(2));
        assert_eq!(slot.dropped(), 1);
        slot.close();
        assert_eq!(slot.take(), None);
    }

    #[test]
    fn close_abandons_the_pending_item() {
        let slot = Handoff::new();
        slot.offer(1);
        slot.close();
        assert_eq!(slot.take(), None);
        assert!(!slot.offer(2));
        assert_eq!(slot.take(), None);
    }

    #[test]
    fn newest_wins_and_close_ends_take() {
        let h = Arc::new(Handoff::new());
        h.offer(1);
        h.offer(2);
        assert_eq!(h.dropped(), 1);
        assert_eq!(h.take(), Some(2));
        let h2 = Arc::clone(&h);
        let waiter = std::thread::spawn(move || h2.take());
        h.close();
        assert_eq!(waiter.join().unwrap(), None);
    }

    #[test]
    fn try_take_never_waits() {
        let h = Handoff::new();
        assert_eq!(h.try_take(), None);
        h.offer(1);
        h.offer(2);
        assert_eq!(h.try_take(), Some(2));
        assert_eq!(h.try_take(), None);
        h.offer(3);
        h.close();
        assert_eq!(h.try_take(), None);
    }

    /// `take_timeout` gives an item offered while it waits, and None after its limit or once
    /// closed (waiting no longer than needed for a close: the generous limit is never reached).
    #[test]
    fn take_timeout_gives_what_comes_in_time() {
        use std::time::Duration;
        let h = Arc::new(Handoff::new());
        assert_eq!(h.take_timeout(Duration::from_millis(1)), None);
        assert!(!h.is_closed());
        let h2 = Arc::clone(&h);
        let waiter = std::thread::spawn(move || h2.take_timeout(Duration::from_secs(600)));
        h.offer(7);
        assert_eq!(waiter.join().unwrap(), Some(7));
        let h2 = Arc::clone(&h);
        let waiter = std::thread::spawn(move || h2.take_timeout(Duration::from_secs(600)));
        h.close();
        assert_eq!(waiter.join().unwrap(), None);
        assert!(h.is_closed());
    }
}
