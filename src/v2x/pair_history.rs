//! The association of one (receiver, peer) scored against the truth over
//! time ([`PairHistory`]): each reception's pair counts of both decisions
//! (per message, over time), and what the counts remember across
//! receptions: when each true pair came into view, whether it was ever
//! found, and each ego track's last partner (switches).

use std::collections::{BTreeMap, BTreeSet};

use super::counts::OverTimeCounts;
use super::views::Views;
use crate::evaluate::PairCounts;

/// What the counts remember of one (receiver, peer)'s pairs (ego track id,
/// peer object id).
#[derive(Default)]
pub(super) struct PairHistory {
    /// Each ego track's partner at its last association.
    last: BTreeMap<u64, u64>,
    /// When each true pair was first in view (s).
    first_in_view: BTreeMap<(u64, u64), f64>,
    /// The true pairs the association over time has found.
    found: BTreeSet<(u64, u64)>,
}

impl PairHistory {
    /// True pairs ever in view.
    pub(super) fn pairs_seen(&self) -> u64 {
        self.first_in_view.len() as u64
    }

    /// Pair counts of both decisions at `time_s`, time in view and to first
    /// right, and switches, into `c`; returns the true pairs in view.
    pub(super) fn count(
        &mut self,
        time_s: f64,
        views: &Views,
        per_message: &[(u64, u64)],
        over_time: &[(u64, u64)],
        c: &mut OverTimeCounts,
    ) -> Vec<(u64, u64)> {
        let label = |ids: &[u64], truth: &[Option<String>]| -> BTreeMap<u64, String> {
            ids.iter()
                .zip(truth)
                .filter_map(|(&i, t)| t.clone().map(|t| (i, t)))
                .collect()
        };
        let (ego, peer) = (
            label(&views.ego_ids, &views.ego_truth),
            label(&views.peer_ids, &views.peer_truth),
        );
        let right = |&(e, p): &(u64, u64)| ego.get(&e).is_some_and(|o| peer.get(&p) == Some(o));
        let truths: Vec<(u64, u64)> = ego
            .iter()
            .flat_map(|(&e, o)| {
                peer.iter()
                    .filter(move |(_, q)| *q == o)
                    .map(move |(&p, _)| (e, p))
            })
            .collect();
        let counts = |pairs: &[(u64, u64)]| PairCounts {
            identified: pairs.len(),
            correct: pairs.iter().filter(|p| right(p)).count(),
            ground_truth: truths.len(),
        };
        c.per_message = counts(per_message);
        c.over_time = counts(over_time);
        c.pairs_in_view = truths.len() as u64;
        c.per_message_right = truths.iter().filter(|t| per_message.contains(t)).count() as u64;
        c.over_time_right = truths.iter().filter(|t| over_time.contains(t)).count() as u64;
        for t in &truths {
            let first = *self.first_in_view.entry(*t).or_insert(time_s);
            if over_time.contains(t) && self.found.insert(*t) {
                c.pairs_found += 1;
                c.time_to_first_right_sum_s += time_s - first;
            }
        }
        for &(e, p) in over_time {
            if self.last.insert(e, p).is_some_and(|q| q != p) {
                c.switches += 1;
            }
        }
        truths
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose2;

    /// Views whose ego tracks 1, 2, 3 and peer objects 10, 20, 30 are the
    /// objects `ego` and `peer` name (`None`: a false track).
    fn views(ego: [Option<&str>; 3], peer: [Option<&str>; 3]) -> Views {
        let names = |t: [Option<&str>; 3]| t.map(|o| o.map(str::to_owned)).to_vec();
        Views {
            ego: Vec::new(),
            ego_ids: vec![1, 2, 3],
            ego_truth: names(ego),
            peer: Vec::new(),
            peer_ids: vec![10, 20, 30],
            peer_truth: names(peer),
            peer_reported: Pose2::identity(),
            ego_claim: crate::v2x::testkit::settings().pose_noise[0],
            peer_claim: crate::v2x::testkit::settings().pose_noise[0],
        }
    }

    /// Each decision is counted against the true pairs in view.
    #[test]
    fn both_decisions_are_counted_against_the_true_pairs() {
        let v = views(
            [Some("a"), Some("b"), None],
            [Some("a"), Some("b"), Some("c")],
        );
        let mut h = PairHistory::default();
        let mut c = OverTimeCounts::default();
        let truths = h.count(1.0, &v, &[(1, 10), (2, 30)], &[(1, 10), (2, 20)], &mut c);
        assert_eq!(truths, [(1, 10), (2, 20)]);
        let per = c.per_message;
        assert_eq!((per.identified, per.correct, per.ground_truth), (2, 1, 2));
        let over = c.over_time;
        assert_eq!(
            (over.identified, over.correct, over.ground_truth),
            (2, 2, 2)
        );
        assert_eq!(
            (c.pairs_in_view, c.per_message_right, c.over_time_right),
            (2, 1, 2)
        );
        assert_eq!((c.pairs_found, c.switches), (2, 0));
        assert_eq!(c.time_to_first_right_sum_s, 0.0);
    }

    /// A pair is found once, timed from when it came into view; an ego
    /// track that changes partner is a switch.
    #[test]
    fn pairs_are_found_once_and_switches_counted() {
        let v = views(
            [Some("a"), Some("b"), Some("c")],
            [Some("a"), Some("b"), Some("c")],
        );
        let mut h = PairHistory::default();
        let mut c = OverTimeCounts::default();
        h.count(1.0, &v, &[], &[(1, 10)], &mut c);
        assert_eq!((c.pairs_found, h.pairs_seen()), (1, 3));
        let mut c = OverTimeCounts::default();
        h.count(1.5, &v, &[], &[(1, 20), (3, 30)], &mut c);
        assert_eq!((c.pairs_found, c.switches), (1, 1));
        assert!((c.time_to_first_right_sum_s - 0.5).abs() < 1e-12);
        let mut c = OverTimeCounts::default();
        h.count(2.0, &v, &[], &[(1, 10), (2, 20), (3, 30)], &mut c);
        assert_eq!((c.pairs_found, c.switches), (1, 1));
        assert!((c.time_to_first_right_sum_s - 1.0).abs() < 1e-12);
        assert_eq!(h.pairs_seen(), 3);
    }
}
