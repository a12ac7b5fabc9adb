//! The nodes' `/clock` readers, as an rcl node's time source (rclcpp's `TimeSource`): one
//! exists only while `use_sim_time` is on. A node's (the depth node's, `fuse`'s) is made when
//! the parameter turns on (at start or through the parameter services) and dropped, out of the
//! graph, when it turns off; switched on again, the time is the last message's until the next,
//! as rclcpp keeps it. The time itself: `clock.rs`.

use futures::StreamExt;
use ros2_client::{Node, Subscription};

use super::clock::{on_clock, switched_from, uses_sim_time};
use super::log::node_log;
use super::param_services::ParamServices;
use super::topics::subscribe_clock;
use super::NodeError;
use crate::msgs::Clock;

/// Takes `/clock`'s messages from `clock` until `use_sim_time` turns off.
async fn read_until_off(clock: &Subscription<Clock>) {
    let messages = clock.async_stream().for_each(|message| {
        match message {
            Ok((clock, _)) => on_clock(&clock),
            Err(e) => tracing::debug!("/clock: {e:?}"),
        }
        futures::future::ready(())
    });
    futures::pin_mut!(messages);
    let off = switched_from(true);
    futures::pin_mut!(off);
    // The stream ends only with the node: then wait for the switch.
    if let futures::future::Either::Left(((), off)) = futures::future::select(messages, off).await {
        off.await;
    }
}

/// A node's `/clock` (`topic`, after the remaps), as an rcl node's time source: while
/// `use_sim_time` is on, a reader (`topics::subscribe_clock`) whose messages set the time;
/// when it turns off, the reader goes (and out of the node's entities in
/// `ros_discovery_info`). Runs as long as the node; a reader that cannot be made is said in the
/// log (the time stays where it was) and tried again at the next switch. Never returns (the
/// type of the node's other services, which end with an error).
pub(super) async fn follow_clock(node: &mut Node, topic: &str) -> NodeError {
    loop {
        if !uses_sim_time() {
            switched_from(false).await;
            continue;
        }
        match subscribe_clock(node, topic) {
            Ok(clock) => {
                read_until_off(&clock).await;
                let gid = clock.gid();
                drop(clock);
                node.forget_reader(gid);
                tracing::debug!("{topic}: no longer read (use_sim_time is off)");
            }
            Err(e) => {
                let line =
                    format!("{topic} cannot be read (simulated time stays where it is): {e}");
                node_log(tracing::Level::ERROR, &line);
                switched_from(true).await;
            }
        }
    }
}

/// A node's parameter services beside its `/clock` reader, which their `use_sim_time`
/// switches ([`follow_clock`]); the first error of either.
pub(super) async fn serve_parameters(
    services: &ParamServices,
    node: &mut Node,
    clock_topic: &str,
) -> NodeError {
    let clock = follow_clock(node, clock_topic);
    futures::future::select(Box::pin(services.serve()), Box::pin(clock))
        .await
        .factor_first()
        .0
}
