//! How both nodes (`sweepdepth node`, `sweepdepth fuse`) run and stop: the SIGINT/SIGTERM
//! handler, and the executor that drives the ros2-client spinner and the event loop until one of
//! them ends or a signal comes, with a background thread (diagnostics) stopped and joined at
//! the end.

use std::future::Future;
use std::sync::atomic::{AtomicBool, Ordering};

use futures::channel::mpsc::UnboundedReceiver;
use futures::future::Either;
use futures::StreamExt;

use super::log::log_info;
use super::NodeError;

/// Installs the SIGINT / SIGTERM handler (Ctrl-C, `ros2 launch` shutting down); each signal
/// comes out of the receiver. Installed before the node says it is up, so a signal sent as soon
/// as it is up is never the default action.
pub(super) fn signals() -> UnboundedReceiver<()> {
    let (signal_tx, signal_rx) = futures::channel::mpsc::unbounded::<()>();
    if let Err(e) = ctrlc::set_handler(move || {
        let _ = signal_tx.unbounded_send(());
    }) {
        tracing::warn!("no clean shutdown on SIGINT/SIGTERM: {e}");
    }
    signal_rx
}

/// Runs `background` on a thread of its own (named `thread_name`, told to stop through the
/// flag it gets) while the spinner and the event loop run on this one, until the spinner
/// fails, the event loop ends with its error, or a signal comes (a clean stop: `Ok`); then
/// calls `on_stop` at once (the node cancels its set in flight and takes no other: the
/// background thread may take up to its tick to see its flag) and stops and joins the thread.
pub(super) fn run_until_signal<S, E>(
    spin: S,
    event_loop: E,
    mut signals: UnboundedReceiver<()>,
    thread_name: &str,
    background: impl FnOnce(&AtomicBool) + Send,
    on_stop: impl FnOnce(),
) -> Result<(), NodeError>
where
    S: Future<Output = ros2_client::CreateResult<()>> + Unpin,
    E: Future<Output = NodeError>,
{
    let stop = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let stop = &stop;
        let thread = std::thread::Builder::new()
            .name(thread_name.into())
            .spawn_scoped(scope, move || background(stop))
            .map_err(|e| NodeError::Ros(format!("cannot start the {thread_name} thread: {e}")))?;
        let outcome = futures::executor::block_on(async {
            futures::pin_mut!(event_loop);
            let stopped = signals.next();
            match futures::future::select(futures::future::select(spin, event_loop), stopped).await
            {
                Either::Left((Either::Left((r, _)), _)) => {
                    r.map_err(|e| NodeError::Ros(format!("{e:?}")))
                }
                Either::Left((Either::Right((e, _)), _)) => Err(e),
                Either::Right(_) => {
                    log_info("shutting down (signal received)");
                    Ok(())
                }
            }
        });
        on_stop();
        stop.store(true, Ordering::Relaxed);
        let _ = thread.join();
        outcome
    })
}
