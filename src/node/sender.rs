//! A set's messages go out on a thread of their own (`sweepdepth-send`), so that the GPU thread
//! starts the next set while DDS serialises and sends this one, and a subscriber that cannot
//! keep up (a reliable reader on a slow link makes the writer wait, up to 100 ms a message, for
//! room in its send window) slows only what it receives, not the depth, fusion or the live
//! view. One set waits at most: the newest wins, an older waiting one is dropped and counted.

use std::sync::Arc;
use std::thread::JoinHandle;

use crate::handoff::Handoff;

/// The sending thread. Dropping it stops the thread (the set being sent is finished, one
/// still waiting is dropped) and waits for it.
pub(super) struct Sender<T: Send + 'static> {
    slot: Arc<Handoff<T>>,
    handle: Option<JoinHandle<()>>,
}

impl<T: Send + 'static> Sender<T> {
    /// Starts the thread; it hands every item it takes to `send`, in order.
    pub fn spawn(mut send: impl FnMut(T) + Send + 'static) -> std::io::Result<Self> {
        let slot = Arc::new(Handoff::new());
        let taken = Arc::clone(&slot);
        let handle = std::thread::Builder::new()
            .name("sweepdepth-send".into())
            .spawn(move || {
                while let Some(item) = taken.take() {
                    send(item);
                }
            })?;
        Ok(Self {
            slot,
            handle: Some(handle),
        })
    }

    /// Hands `item` over; never waits. Returns whether it replaced one still waiting.
    pub fn offer(&self, item: T) -> bool {
        self.slot.offer(item)
    }

    /// Items replaced while they waited.
    pub fn dropped(&self) -> u64 {
        self.slot.dropped()
    }
}

impl<T: Send + 'static> Drop for Sender<T> {
    fn drop(&mut self) {
        self.slot.close();
        if let Some(handle) = self.handle.take() {
            let _ = handle.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;
    use std::time::Duration;

    /// While the thread is stuck sending (a subscriber that does not keep up), offers never
    /// wait: the newest waits, older ones are dropped and counted; what is sent goes in order.
    #[test]
    fn a_stuck_send_holds_up_no_offer_and_the_newest_goes_next() {
        let (started_tx, started) = mpsc::channel();
        let (release, released) = mpsc::channel::<()>();
        let (sent_tx, sent) = mpsc::channel();
        let sender = Sender::spawn(move |item: u32| {
            let _ = started_tx.send(item);
            if item == 0 {
                // Stuck until the test lets it go.
                let _ = released.recv();
            }
            let _ = sent_tx.send(item);
        })
        .unwrap();
        assert!(!sender.offer(0));
        let limit = Duration::from_secs(600);
        assert_eq!(started.recv_timeout(limit), Ok(0));
        // The thread is stuck on 0: these return at once, each replacing the one before.
        assert!(!sender.offer(1));
        assert!(sender.offer(2));
        assert!(sender.offer(3));
        assert_eq!(sender.dropped(), 2);
        release.send(()).unwrap();
        assert_eq!(sent.recv_timeout(limit), Ok(0));
        assert_eq!(sent.recv_timeout(limit), Ok(3));
        drop(sender);
        assert!(sent.try_recv().is_err(), "only 0 and 3 were sent");
    }
}
