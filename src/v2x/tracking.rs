//! `coid track`'s cooperation over time ([`Tracking`]): every connected
//! vehicle near the junction tracks its own detections and sends its
//! reported tracks as CPMs over the channel ([`Fleet`]); each receiver
//! extrapolates what it receives to its own time, matches it against its
//! own tracks with the frame matcher, carries the association across
//! messages, and fuses what it associated ([`PeerState`]). This file holds
//! one step of it and what it accumulates.

use std::collections::BTreeMap;

use super::context::{Context, Sensing};
use super::counts::{OverTimeCounts, VehicleTracking};
use super::fleet::Fleet;
use super::peer::PeerState;
use crate::graph::GraphError;
use crate::matching::Matcher;

/// What `coid track` measured.
pub struct TrackResults {
    /// One row per connected vehicle, in id order.
    pub vehicles: Vec<VehicleTracking>,
    pub over_time: OverTimeCounts,
}

/// `coid track`'s state: the fleet, what each receiver knows of each peer
/// (by (receiver, sender)), and the counts of every reception so far.
#[derive(Default)]
pub(crate) struct Tracking {
    fleet: Fleet,
    peers: BTreeMap<(String, String), PeerState>,
    counts: OverTimeCounts,
}

impl Tracking {
    /// One step: `sides` (what every connected vehicle near the junction
    /// sensed) track and send; every message that has arrived is received
    /// ([`PeerState::receive`]) and matched with `matcher`.
    pub(crate) fn step(
        &mut self,
        ctx: &Context,
        sides: &[Sensing],
        matcher: &dyn Matcher,
    ) -> Result<(), GraphError> {
        self.fleet.send(ctx, sides);
        for m in self.fleet.arrivals(ctx, sides) {
            let Some(receiver) = self.fleet.vehicle(&m.receiver) else {
                continue;
            };
            let peer = self
                .peers
                .entry((m.receiver.clone(), m.message.sender.clone()))
                .or_default();
            let c = peer.receive(ctx, receiver, &m.message, matcher)?;
            self.counts.add(&c);
        }
        Ok(())
    }

    /// What the run measured: each vehicle's row and the pooled counts.
    pub(crate) fn finish(self) -> TrackResults {
        let mut counts = self.counts;
        for p in self.peers.values() {
            counts.pairs += p.pairs_seen();
        }
        TrackResults {
            vehicles: self.fleet.finish(),
            over_time: counts,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluate::CorrespondenceSource;
    use crate::geometry::{Pose2, Vec2};
    use crate::pipeline::runner;
    use crate::v2x::channel::LossModel;
    use crate::v2x::testkit::{centres, context, sensings, settings, vehicle_side};

    /// Two vehicles that see the same objects, over a lossless channel:
    /// every message is received, each receiver associates the other's
    /// objects with its own tracks, and the rows and counts add up.
    #[test]
    fn two_vehicles_that_see_the_same_objects_associate_them() {
        let mut s = settings();
        s.v2x.channel.loss = LossModel::Independent { probability: 0.0 };
        let objects = [
            ("a", Vec2::new(12.0, 3.0)),
            ("b", Vec2::new(18.0, -4.0)),
            ("c", Vec2::new(25.0, 8.0)),
        ];
        let truth = centres(&objects);
        let level = *s
            .pose_noise
            .iter()
            .find(|l| l.label == s.v2x.pose_noise)
            .unwrap();
        let Ok(CorrespondenceSource::Matcher(matcher)) = runner(&s, s.v2x.matcher) else {
            panic!("[v2x] matcher is a matcher");
        };
        let mut tracking = Tracking::default();
        let poses = [
            Pose2::new(Vec2::new(0.0, 1.0), 0.3),
            Pose2::new(Vec2::new(40.0, 2.0), 3.0),
        ];
        let steps = 20;
        for step in 0..steps {
            let sides = [
                vehicle_side("cv0", poses[0], &objects, step),
                vehicle_side("cv1", poses[1], &objects, step),
            ];
            let ctx = Context {
                levels: std::slice::from_ref(&level),
                ..context(&s, &truth, step, step as f64 * 0.1)
            };
            tracking
                .step(&ctx, &sensings(&sides), matcher.as_ref())
                .unwrap();
        }
        let r = tracking.finish();
        let ids: Vec<&str> = r.vehicles.iter().map(|v| v.ego_id.as_str()).collect();
        assert_eq!(ids, ["cv0", "cv1"]);
        assert!(r.vehicles.iter().all(|v| v.steps == steps && v.lost == 0));
        // Each message arrives one step later: all but the last ones,
        // which are in flight when the run ends, not delivered.
        let delivered: u64 = r.vehicles.iter().map(|v| v.delivered).sum();
        let in_flight: u64 = r.vehicles.iter().map(|v| v.in_flight_at_end).sum();
        assert_eq!((r.over_time.receptions, in_flight), (delivered, 2));
        assert_eq!(r.over_time.pairs, 6, "three objects, both ways");
        assert_eq!(r.over_time.pairs_found, 6);
        assert_eq!(
            r.over_time.over_time.correct,
            r.over_time.over_time.identified
        );
        assert_eq!(r.over_time.switches, 0);
    }
}
