//! Messages on their way ([`MessagesInFlight`]): a message sent to a
//! receiver goes over the channel (its own `Purpose::Channel` stream per
//! step, sender and receiver: delivered after a latency, or lost) and is
//! handed out once it has arrived.

use super::context::Context;
use super::instance::InstanceSide;
use super::message::Sent;
use crate::rng::{self, Purpose};

/// A message on its way to one receiver.
pub(super) struct InFlight {
    pub arrival_s: f64,
    pub receiver: String,
    pub message: Sent,
}

/// The messages sent and not yet arrived.
#[derive(Default)]
pub(super) struct MessagesInFlight {
    queue: Vec<InFlight>,
}

impl MessagesInFlight {
    /// Sends `message` from `sender` to `receiver` (vehicles' sides at
    /// this step), `distance_m` apart,
    /// over `[v2x.channel]`: its latency when it is delivered, `None` when
    /// it is lost.
    pub(super) fn send(
        &mut self,
        ctx: &Context,
        sender: &InstanceSide,
        receiver: &InstanceSide,
        distance_m: f64,
        message: &Sent,
    ) -> Option<f64> {
        let mut stream = rng::stream(
            ctx.settings.seeds.sensor,
            Purpose::Channel,
            &[ctx.step, sender.id_hash, receiver.id_hash],
        );
        let delivered = ctx.v.channel.deliver(distance_m, &mut stream);
        if let Some(latency) = delivered {
            self.queue.push(InFlight {
                arrival_s: ctx.time_s + latency,
                receiver: receiver.source.vehicle().to_owned(),
                message: message.clone(),
            });
        }
        delivered
    }

    /// The messages that have arrived by `time_s` at receivers `here`
    /// accepts (the others are dropped), in arrival order.
    pub(super) fn arrived(&mut self, time_s: f64, here: impl Fn(&str) -> bool) -> Vec<InFlight> {
        let now = time_s + 1e-9;
        let (mut due, rest): (Vec<InFlight>, Vec<InFlight>) = std::mem::take(&mut self.queue)
            .into_iter()
            .partition(|m| m.arrival_s <= now);
        self.queue = rest;
        due.sort_by(|a, b| a.arrival_s.total_cmp(&b.arrival_s));
        due.retain(|m| here(&m.receiver));
        due
    }
}
