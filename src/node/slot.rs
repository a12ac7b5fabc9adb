//! A one-slot hand-over from the executor to the GPU worker thread: the newest complete set
//! replaces a pending one (which is counted as dropped).

use std::sync::{Condvar, Mutex};

struct Slot<T> {
    pending: Option<T>,
    closed: bool,
    dropped: u64,
}

/// Capacity-1 "latest wins" channel.
pub struct LatestSlot<T> {
    slot: Mutex<Slot<T>>,
    ready: Condvar,
}

impl<T> Default for LatestSlot<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T> LatestSlot<T> {
    pub fn new() -> Self {
        Self {
            slot: Mutex::new(Slot {
                pending: None,
                closed: false,
                dropped: 0,
            }),
            ready: Condvar::new(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Slot<T>> {
        // A poisoned lock only means a holder panicked; the slot itself is always consistent.
        self.slot.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Offers `item`; returns true if it replaced a pending one (that one is dropped).
    pub fn offer(&self, item: T) -> bool {
        let mut slot = self.lock();
        if slot.closed {
            return false;
        }
        let replaced = slot.pending.replace(item).is_some();
        if replaced {
            slot.dropped += 1;
        }
        drop(slot);
        self.ready.notify_one();
        replaced
    }

    /// Blocks until an item is pending (Some) or the slot is closed (None: a pending item is
    /// abandoned, as a node shutting down has nobody to give its outputs to).
    pub fn take(&self) -> Option<T> {
        let mut slot = self.lock();
        loop {
            if slot.closed {
                slot.pending = None;
                return None;
            }
            if let Some(item) = slot.pending.take() {
                return Some(item);
            }
            slot = self.ready.wait(slot).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Wakes the taker; later `take`s return None (a pending item is dropped) and `offer`s
    /// drop their item.
    pub fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }

    /// Sets replaced before the worker took them.
    pub fn dropped(&self) -> u64 {
        self.lock().dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newest_replaces_pending() {
        let slot = LatestSlot::new();
        assert!(!slot.offer(1));
        assert!(slot.offer(2));
        assert_eq!(slot.take(), Some(2));
        assert_eq!(slot.dropped(), 1);
        slot.close();
        assert_eq!(slot.take(), None);
    }

    #[test]
    fn close_abandons_the_pending_item() {
        let slot = LatestSlot::new();
        slot.offer(1);
        slot.close();
        assert_eq!(slot.take(), None);
        assert!(!slot.offer(2));
        assert_eq!(slot.take(), None);
    }
}
