//! The connected vehicles over time ([`Fleet`]): at every step each
//! vehicle near the junction tracks ([`ConnectedVehicle`]) and, when a CPM
//! is due, sends it to every peer near the junction that `[connected]`
//! links it to at that step ([`MessagesInFlight`]); what has arrived is
//! handed to the receivers still there.

use std::collections::{BTreeMap, BTreeSet};

use super::context::Context;
use super::delivery::{InFlight, MessagesInFlight};
use super::instance::InstanceSide;
use super::vehicle::ConnectedVehicle;
use crate::geometry::Vec2;
use crate::report::VehicleTracking;

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
    pub(super) fn send(&mut self, ctx: &Context, sides: &[InstanceSide]) {
        let positions: Vec<Vec2> = sides
            .iter()
            .map(|e| e.sensed.truth.ego_pose.position_m())
            .collect();
        let links = ctx.settings.link.links(&positions);
        for (i, side) in sides.iter().enumerate() {
            let id = side.source.vehicle();
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
    pub(super) fn arrivals(&mut self, ctx: &Context, sides: &[InstanceSide]) -> Vec<InFlight> {
        let here: BTreeSet<&str> = sides.iter().map(|e| e.source.vehicle()).collect();
        let vehicles = &self.vehicles;
        self.in_flight.arrived(ctx.time_s, |receiver| {
            here.contains(receiver) && vehicles.contains_key(receiver)
        })
    }

    /// Every vehicle's row of `coid track`'s table, in id order.
    pub(super) fn finish(self) -> Vec<VehicleTracking> {
        self.vehicles
            .into_values()
            .map(ConnectedVehicle::finish)
            .collect()
    }
}
