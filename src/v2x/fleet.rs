//! The connected vehicles over time ([`Fleet`]): at every step each
//! vehicle near the junction tracks ([`ConnectedVehicle`]) and, when a CPM
//! is due, sends it to every peer near the junction that `[connected]`
//! links it to at that step ([`MessagesInFlight`]); what has arrived is
//! handed to the receivers still there.

use std::collections::{BTreeMap, BTreeSet};

use super::context::{Context, Sensing};
use super::counts::VehicleTracking;
use super::delivery::{InFlight, MessagesInFlight};
use super::vehicle::ConnectedVehicle;
use crate::geometry::Vec2;

/// Every connected vehicle that has been near the junction, by id, and the
/// messages in flight between them.
#[derive(Default)]
pub(super) struct Fleet {
    vehicles: BTreeMap<String, ConnectedVehicle>,
    in_flight: MessagesInFlight,
}

impl Fleet {
    /// Every vehicle near the junction (`sides`: what each sensed at this
    /// step) tracks, and sends its CPM when one is due to its linked peers
    /// over the channel.
    pub(super) fn send(&mut self, ctx: &Context, sides: &[Sensing]) {
        let positions: Vec<Vec2> = sides
            .iter()
            .map(|e| e.sensed.truth.ego_pose.position_m())
            .collect();
        let links = ctx.link.links(&positions);
        for (i, side) in sides.iter().enumerate() {
            let id = side.id;
            let vehicle = self
                .vehicles
                .entry(id.to_owned())
                .or_insert_with(|| ConnectedVehicle::new(id, ctx.v));
            let Some(sent) = vehicle.step(ctx, side) else {
                continue;
            };
            for (j, peer) in sides.iter().enumerate() {
                if j == i || !links.linked(i, j) {
                    continue;
                }
                let d = (positions[j] - positions[i]).norm();
                let delivered = self.in_flight.send(ctx, side, peer, d, &sent);
                vehicle.delivery(delivered);
            }
        }
    }

    /// The vehicle `id`, once it has been near the junction.
    pub(super) fn vehicle(&self, id: &str) -> Option<&ConnectedVehicle> {
        self.vehicles.get(id)
    }

    /// The messages that have arrived by now at receivers still near the
    /// junction (`sides`; the others are dropped), in arrival order.
    pub(super) fn arrivals(&mut self, ctx: &Context, sides: &[Sensing]) -> Vec<InFlight> {
        let here: BTreeSet<&str> = sides.iter().map(|e| e.id).collect();
        let vehicles = &self.vehicles;
        self.in_flight.arrived(ctx.time_s, |receiver| {
            here.contains(receiver) && vehicles.contains_key(receiver)
        })
    }

    /// Every vehicle's row of `coid track`'s table, in id order.
    /// Messages still on their way when the run ends count as in flight,
    /// not delivered.
    pub(super) fn finish(self) -> Vec<VehicleTracking> {
        let mut rows: BTreeMap<String, VehicleTracking> = self
            .vehicles
            .into_iter()
            .map(|(id, v)| (id, v.finish()))
            .collect();
        for (sender, latency_s) in self.in_flight.pending() {
            if let Some(row) = rows.get_mut(sender) {
                row.still_in_flight(latency_s);
            }
        }
        rows.into_values().collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Settings;
    use crate::geometry::Pose2;
    use crate::v2x::channel::LossModel;
    use crate::v2x::testkit::{Side, centres, context, sensings, settings, vehicle_side};

    fn lossless() -> Settings {
        let mut s = settings();
        s.v2x.channel.loss = LossModel::Independent { probability: 0.0 };
        s
    }

    /// Two vehicles `gap_m` apart that see one road user, at `step`.
    fn pair(gap_m: f64, step: u64) -> Vec<Side> {
        let seen = [("a", Vec2::new(5.0, 5.0))];
        vec![
            vehicle_side("cv0", Pose2::identity(), &seen, step),
            vehicle_side("cv1", Pose2::new(Vec2::new(gap_m, 0.0), 0.0), &seen, step),
        ]
    }

    /// Each vehicle sends its message to its linked peer; the messages
    /// arrive after the latency, and the rows count the deliveries (those
    /// still on their way at the end apart).
    #[test]
    fn linked_vehicles_exchange_their_messages() {
        let s = lossless();
        let truth = centres(&[("a", Vec2::new(5.0, 5.0))]);
        let mut fleet = Fleet::default();
        let ctx = context(&s, &truth, 0, 0.0);
        fleet.send(&ctx, &sensings(&pair(20.0, 0)));
        assert!(fleet.arrivals(&ctx, &sensings(&pair(20.0, 0))).is_empty());
        assert!(fleet.vehicle("cv1").is_some() && fleet.vehicle("cv2").is_none());
        let ctx = context(&s, &truth, 1, 0.1);
        fleet.send(&ctx, &sensings(&pair(20.0, 1)));
        let got: Vec<(String, String)> = fleet
            .arrivals(&ctx, &sensings(&pair(20.0, 1)))
            .into_iter()
            .map(|m| (m.message.sender, m.receiver))
            .collect();
        assert_eq!(
            got,
            [("cv0".into(), "cv1".into()), ("cv1".into(), "cv0".into())]
        );
        let rows = fleet.finish();
        assert_eq!(rows[0].ego_id, "cv0");
        assert!(rows.iter().all(|r| {
            let counts = (r.delivered, r.lost, r.in_flight_at_end, r.messages);
            counts == (1, 0, 1, 2)
        }));
    }

    /// Vehicles beyond the communication range exchange nothing; a
    /// message whose receiver has left the junction is dropped.
    #[test]
    fn unlinked_or_absent_receivers_get_nothing() {
        let mut s = lossless();
        s.link.comm_range_m = Some(10.0);
        let truth = centres(&[("a", Vec2::new(5.0, 5.0))]);
        let mut fleet = Fleet::default();
        fleet.send(&context(&s, &truth, 0, 0.0), &sensings(&pair(20.0, 0)));
        let ctx = context(&s, &truth, 1, 0.1);
        assert!(fleet.arrivals(&ctx, &sensings(&pair(20.0, 1))).is_empty());
        s.link.comm_range_m = None;
        fleet.send(&context(&s, &truth, 2, 0.2), &sensings(&pair(20.0, 2)));
        let three = pair(20.0, 3);
        let only_cv0 = &sensings(&three[..1]);
        let ctx = context(&s, &truth, 3, 0.3);
        let got = fleet.arrivals(&ctx, only_cv0);
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].receiver, "cv0");
        let ctx = context(&s, &truth, 4, 0.4);
        assert!(fleet.arrivals(&ctx, &sensings(&pair(20.0, 4))).is_empty());
        let rows = fleet.finish();
        assert!(rows.iter().all(|r| (r.delivered, r.lost) == (1, 0)));
    }
}
