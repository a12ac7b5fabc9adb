//! A one-item hand-over between the engine's thread and the viewer's: `put` never waits (the
//! newest replaces one not yet taken), `take` waits for an item or for `close`.

use std::sync::{Condvar, Mutex, MutexGuard};

struct State<T> {
    item: Option<T>,
    closed: bool,
    replaced: u64,
}

pub(super) struct Handoff<T> {
    state: Mutex<State<T>>,
    ready: Condvar,
}

impl<T> Handoff<T> {
    pub(super) fn new() -> Self {
        Self {
            state: Mutex::new(State {
                item: None,
                closed: false,
                replaced: 0,
            }),
            ready: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State<T>> {
        // A panic elsewhere while holding the lock leaves a valid state (an Option and flags).
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Offers an item; an item not taken yet is replaced (and counted).
    pub(super) fn put(&self, item: T) {
        let mut state = self.lock();
        if state.item.replace(item).is_some() {
            state.replaced += 1;
        }
        drop(state);
        self.ready.notify_one();
    }

    /// The next item, or `None` once closed.
    pub(super) fn take(&self) -> Option<T> {
        let mut state = self.lock();
        loop {
            if state.closed {
                return None;
            }
            if let Some(item) = state.item.take() {
                return Some(item);
            }
            state = self.ready.wait(state).unwrap_or_else(|e| e.into_inner());
        }
    }

    pub(super) fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }

    /// Items replaced before the viewer's thread took them.
    pub(super) fn replaced(&self) -> u64 {
        self.lock().replaced
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn newest_wins_and_close_ends_take() {
        let h = Arc::new(Handoff::new());
        h.put(1);
        h.put(2);
        assert_eq!(h.replaced(), 1);
        assert_eq!(h.take(), Some(2));
        let h2 = Arc::clone(&h);
        let waiter = std::thread::spawn(move || h2.take());
        h.close();
        assert_eq!(waiter.join().unwrap(), None);
    }
}
