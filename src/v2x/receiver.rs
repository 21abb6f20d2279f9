//! The receiver's association over time: which of a peer's track ids is
//! which of the ego's tracks, carried across messages. Each message's
//! frame matching (any matcher) is evidence for the pairs it saw; the
//! evidence of a pair is smoothed over messages, so one bad frame does not
//! undo what many good ones showed, and a pair the matcher keeps
//! contradicting loses its association. The association is the
//! one-to-one assignment of the pairs whose evidence passes the threshold.

use std::collections::{BTreeMap, BTreeSet};

use crate::assignment::assign;

/// `[v2x.association]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AssociationSettings {
    /// Weight of the newest message in a pair's evidence, in (0, 1]; 1:
    /// every message decides alone (per-message matching).
    pub smoothing: f64,
    /// Evidence a pair needs to be associated, in [0, 1).
    pub threshold: f64,
    /// Weight of each message's alignment in the relative pose estimated
    /// over time, in [0, 1]; 0: each message's reported poses alone.
    pub pose_smoothing: f64,
}

impl Default for AssociationSettings {
    fn default() -> Self {
        Self {
            smoothing: 0.3,
            threshold: 0.5,
            pose_smoothing: 0.0,
        }
    }
}

/// One ego vehicle's association with one peer's track ids.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Association {
    /// Evidence per (ego track, peer id), in [0, 1].
    evidence: BTreeMap<(u64, u64), f64>,
}

impl Association {
    /// One message: `ego` tracks and `peer` ids were both in view, and the
    /// frame matcher paired `matched` (ego, peer). Every pair in view moves
    /// toward 1 when matched, 0 when not (a vote: matchers' probabilities
    /// are not all calibrated); a pair seen for the first time starts
    /// there. The evidence is thus a smoothed share of messages that
    /// paired them.
    pub fn update(
        &mut self,
        s: &AssociationSettings,
        ego: &[u64],
        peer: &[u64],
        matched: &[(u64, u64)],
    ) {
        let said: BTreeSet<(u64, u64)> = matched.iter().copied().collect();
        for &e in ego {
            for &p in peer {
                let target = if said.contains(&(e, p)) { 1.0 } else { 0.0 };
                self.evidence
                    .entry((e, p))
                    .and_modify(|v| *v += s.smoothing * (target - *v))
                    .or_insert(target);
            }
        }
    }

    /// The association among `ego` tracks and `peer` ids: one-to-one, the
    /// largest total evidence among pairs above the threshold.
    pub fn decide(&self, s: &AssociationSettings, ego: &[u64], peer: &[u64]) -> Vec<(u64, u64)> {
        let mut scores = Vec::with_capacity(ego.len() * peer.len());
        for &e in ego {
            for &p in peer {
                let v = self.evidence.get(&(e, p)).copied().unwrap_or(0.0);
                scores.push((v > s.threshold).then_some(v));
            }
        }
        assign(ego.len(), peer.len(), &scores)
            .into_iter()
            .map(|(i, j)| (ego[i], peer[j]))
            .collect()
    }

    /// Forgets pairs whose ego track or peer id is gone.
    pub fn retain(&mut self, ego_alive: impl Fn(u64) -> bool, peer_alive: impl Fn(u64) -> bool) {
        self.evidence
            .retain(|&(e, p), _| ego_alive(e) && peer_alive(p));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A matcher that is right four times in five: per-message matching
    /// takes every wrong frame, the association over time none; after the
    /// sender's id switch (object 1 now sent as id 9) the association
    /// follows within two messages.
    #[test]
    fn evidence_outlasts_bad_frames_and_follows_an_id_switch() {
        let s = AssociationSettings::default();
        let per_message = AssociationSettings {
            smoothing: 1.0,
            ..s
        };
        let (mut over_time, mut single) = (Association::default(), Association::default());
        let (mut wrong_over_time, mut wrong_single) = (0, 0);
        for k in 0..20 {
            // Ego tracks 1, 2; the peer's ids 1, 2 (the same objects).
            let good = [(1, 1), (2, 2)];
            let bad = [(1, 2), (2, 1)];
            let m: &[(u64, u64)] = if k % 5 == 4 { &bad } else { &good };
            let right = vec![(1, 1), (2, 2)];
            over_time.update(&s, &[1, 2], &[1, 2], m);
            wrong_over_time += usize::from(over_time.decide(&s, &[1, 2], &[1, 2]) != right);
            single.update(&per_message, &[1, 2], &[1, 2], m);
            wrong_single += usize::from(single.decide(&per_message, &[1, 2], &[1, 2]) != right);
        }
        assert_eq!((wrong_over_time, wrong_single), (0, 4));
        // The peer now calls object 1 id 9; id 1 is gone.
        over_time.retain(|_| true, |p| p != 1);
        let mut took = None;
        for k in 0..5 {
            over_time.update(&s, &[1, 2], &[9, 2], &[(1, 9), (2, 2)]);
            if took.is_none() && over_time.decide(&s, &[1, 2], &[9, 2]).contains(&(1, 9)) {
                took = Some(k);
            }
        }
        assert!(took.is_some_and(|k| k <= 1), "{took:?}");
    }
}
