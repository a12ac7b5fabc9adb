//! Ctrl-C (and SIGTERM) during `sweepdepth bag`: the first stops the reading, and the sets in
//! hand finish and are written (the bag, the mesh); the second quits at once. After the bag,
//! with `--view`, Ctrl-C ends the view.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

use crate::viewer::Viewer;

/// Set by the first Ctrl-C (or SIGTERM) of `bag`: reading stops, the sets in hand finish and
/// the bag and the mesh are written with what was processed.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Set while `--view` holds the last set on view ([`hold_view`]): the run is over and written,
/// so Ctrl-C only ends the view.
static VIEWING: AtomicBool = AtomicBool::new(false);

/// `bag`'s Ctrl-C: the first stops the run cleanly ([`INTERRUPTED`]), the second quits at
/// once (exit status 130, nothing more written). False when no handler could be set.
pub(super) fn handle_interrupts() -> bool {
    static PRESSED: AtomicUsize = AtomicUsize::new(0);
    let set = ctrlc::set_handler(|| {
        if VIEWING.load(Ordering::SeqCst) {
            eprintln!("\nCtrl-C: the view ends");
            INTERRUPTED.store(true, Ordering::SeqCst);
        } else if PRESSED.fetch_add(1, Ordering::SeqCst) == 0 {
            INTERRUPTED.store(true, Ordering::SeqCst);
            eprintln!(
                "\nCtrl-C: stopping; the sets processed so far are written (Ctrl-C again to quit \
                 without writing)"
            );
        } else {
            std::process::exit(130);
        }
    });
    if let Err(e) = &set {
        tracing::warn!("cannot handle Ctrl-C ({e}): it ends the run without writing");
    }
    set.is_ok()
}

/// `--view` after the bag: the last set stays on view until Ctrl-C (or SIGTERM).
pub(super) fn hold_view(viewer: &Viewer, interrupts: bool) {
    if !interrupts {
        return;
    }
    VIEWING.store(true, Ordering::SeqCst);
    eprintln!(
        "done; the last set stays on view at {} (Foxglove/Lichtblick: {}) until Ctrl-C",
        viewer.page_url(),
        viewer.websocket_url()
    );
    while !INTERRUPTED.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Whether Ctrl-C asked the run to stop.
pub(super) fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::Relaxed)
}
