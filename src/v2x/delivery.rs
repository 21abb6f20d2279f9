//! Messages on their way ([`MessagesInFlight`]): a message sent to a
//! receiver goes over the channel (its own `Purpose::Channel` stream per
//! step, sender and receiver: delivered after a latency, or lost) and is
//! handed out once it has arrived.

use super::context::{Context, Sensing};
use super::message::Sent;
use crate::rng::{self, Purpose};

/// A message on its way to one receiver.
pub(super) struct InFlight {
    pub arrival_s: f64,
    /// The channel's latency (s).
    pub latency_s: f64,
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
        sender: &Sensing,
        receiver: &Sensing,
        distance_m: f64,
        message: &Sent,
    ) -> Option<f64> {
        let mut stream = rng::stream(
            ctx.sensor_seed,
            Purpose::Channel,
            &[ctx.step, sender.id_hash, receiver.id_hash],
        );
        let delivered = ctx.v.channel.deliver(distance_m, &mut stream);
        if let Some(latency) = delivered {
            self.queue.push(InFlight {
                arrival_s: ctx.time_s + latency,
                latency_s: latency,
                receiver: receiver.id.to_owned(),
                message: message.clone(),
            });
        }
        delivered
    }

    /// The messages not arrived yet: their senders and latencies.
    pub(super) fn pending(&self) -> impl Iterator<Item = (&str, f64)> {
        self.queue
            .iter()
            .map(|m| (m.message.sender.as_str(), m.latency_s))
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

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::config::Settings;
    use crate::geometry::{Pose2, Vec2};
    use crate::v2x::channel::LossModel;
    use crate::v2x::testkit::{Side, context, sent, settings, vehicle_side};

    fn with_loss(probability: f64) -> Settings {
        let mut s = settings();
        s.v2x.channel.loss = LossModel::Independent { probability };
        s
    }

    fn sides() -> [Side; 2] {
        let seen = [("a", Vec2::new(5.0, 5.0))];
        [
            vehicle_side("cv0", Pose2::identity(), &seen, 0),
            vehicle_side("cv1", Pose2::new(Vec2::new(20.0, 0.0), 0.0), &seen, 0),
        ]
    }

    /// A delivered message arrives after the channel's latency, once, and
    /// not before.
    #[test]
    fn a_delivered_message_arrives_once_after_its_latency() {
        let s = with_loss(0.0);
        let truth = BTreeMap::new();
        let [a, b] = sides();
        let mut q = MessagesInFlight::default();
        let latency = q.send(
            &context(&s, &truth, 10, 1.0),
            &a.sensing(),
            &b.sensing(),
            20.0,
            &sent("cv0", 1.0),
        );
        assert_eq!(latency, Some(s.v2x.channel.latency_s));
        assert!(q.arrived(1.05, |_| true).is_empty());
        let due = q.arrived(1.0 + s.v2x.channel.latency_s, |_| true);
        assert_eq!(due.len(), 1);
        assert_eq!(
            (due[0].receiver.as_str(), due[0].message.sender.as_str()),
            ("cv1", "cv0")
        );
        assert!(q.arrived(9.0, |_| true).is_empty());
    }

    /// A lost message never arrives.
    #[test]
    fn a_lost_message_never_arrives() {
        let s = with_loss(1.0);
        let truth = BTreeMap::new();
        let [a, b] = sides();
        let mut q = MessagesInFlight::default();
        let ctx = context(&s, &truth, 10, 1.0);
        assert_eq!(
            q.send(&ctx, &a.sensing(), &b.sensing(), 20.0, &sent("cv0", 1.0)),
            None
        );
        assert!(q.arrived(9.0, |_| true).is_empty());
    }

    /// What has arrived comes in arrival order; what arrived at a receiver
    /// that is gone is dropped; what is still on its way stays.
    #[test]
    fn arrivals_come_in_order_and_those_of_absent_receivers_are_dropped() {
        let mut q = MessagesInFlight::default();
        for (arrival_s, receiver, sender) in [
            (1.3, "cv1", "cv0"),
            (1.1, "cv2", "cv0"),
            (1.2, "cv1", "cv2"),
            (1.5, "cv1", "cv3"),
        ] {
            q.queue.push(InFlight {
                arrival_s,
                latency_s: arrival_s - 1.0,
                receiver: receiver.into(),
                message: sent(sender, 1.0),
            });
        }
        let due = q.arrived(1.3, |r| r == "cv1");
        let got: Vec<(f64, &str)> = due
            .iter()
            .map(|m| (m.arrival_s, m.message.sender.as_str()))
            .collect();
        assert_eq!(got, [(1.2, "cv2"), (1.3, "cv0")]);
        // What is still on its way, by sender, with its latency.
        assert_eq!(q.pending().collect::<Vec<_>>(), [("cv3", 0.5)]);
        assert_eq!(q.arrived(2.0, |_| true).len(), 1);
        assert_eq!(q.pending().count(), 0);
    }
}
