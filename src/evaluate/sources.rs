//! Where a pair's correspondences come from: a method that matches what
//! the vehicles know, the oracle that reads the truth, or a file of
//! matches made elsewhere (`coid score`), with the checks that such a file
//! names instances and nodes the run has.

use std::collections::BTreeMap;

use super::PairAtLevel;
use crate::matching::{Correspondence, Identification, Matcher, Method, oracle};
use crate::sensor::PoseNoiseLabel;

/// The source of a pair's correspondences: what the vehicles know, the
/// truth, or a file.
pub enum CorrespondenceSource {
    Matcher(Box<dyn Matcher>),
    /// The true correspondences ([`oracle::true_pairs`]).
    Oracle,
    /// Correspondences made elsewhere (`coid score`), for one run.
    External(ExternalMatches),
}

impl CorrespondenceSource {
    /// Multiply-adds the source's network has done so far (0 without one).
    pub fn network_macs(&self) -> u64 {
        match self {
            CorrespondenceSource::Matcher(m) => m.network_macs(),
            _ => 0,
        }
    }

    /// The method whose correspondences these are.
    pub(super) fn method(&self) -> Method {
        match self {
            CorrespondenceSource::Matcher(m) => m.method(),
            CorrespondenceSource::Oracle => Method::Oracle,
            CorrespondenceSource::External(_) => Method::External,
        }
    }

    /// `pair`'s correspondences (`a` a node of its first vehicle).
    pub(super) fn identify(&self, pair: &PairAtLevel) -> Identification {
        match self {
            CorrespondenceSource::Matcher(m) => m.identify(&pair.first.view, &pair.second.view),
            CorrespondenceSource::Oracle => Identification::matches_only(oracle::true_pairs(
                pair.first.truth,
                pair.second.truth,
            )),
            CorrespondenceSource::External(e) => Identification::matches_only(e.for_pair(pair)),
        }
    }
}

/// One run's correspondences made elsewhere: per (instance, pose-noise
/// level), pairs of the instance's first and second vehicle's nodes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExternalMatches {
    pub by_instance: BTreeMap<(usize, PoseNoiseLabel), Vec<Correspondence>>,
    /// The first row that matches a node a second time, with its
    /// instance and level: refused by [`ExternalMatches::check`] once that
    /// instance's nodes are known to exist.
    pub repeated: Option<((usize, PoseNoiseLabel), String)>,
}

impl ExternalMatches {
    /// The correspondences of `pair`'s instance at its level, those that
    /// name nodes it has ([`ExternalMatches::check`] refuses the others).
    fn for_pair(&self, pair: &PairAtLevel) -> Vec<Correspondence> {
        let (n1, n2) = node_counts(pair);
        self.by_instance
            .get(&(pair.instance, pair.level.label))
            .map(|m| m.iter().filter(|c| c.a < n1 && c.b < n2).copied().collect())
            .unwrap_or_default()
    }

    /// Why the correspondences do not fit a frame's instances, if they do
    /// not: a node index beyond what a vehicle detected.
    pub fn check(&self, pairs: &[PairAtLevel]) -> Result<(), String> {
        for pair in pairs {
            let key = (pair.instance, pair.level.label);
            let (n1, n2) = node_counts(pair);
            for c in self.by_instance.get(&key).into_iter().flatten() {
                if c.a >= n1 || c.b >= n2 {
                    let (side, node, n) = if c.a >= n1 {
                        ("first", c.a, n1)
                    } else {
                        ("second", c.b, n2)
                    };
                    return Err(format!(
                        "instance {} at level {}: a match names node {node} of the {side} \
                         vehicle, which has no such node (it has {n} nodes)",
                        pair.instance,
                        pair.level.label.as_str(),
                    ));
                }
            }
            if let Some((k, why)) = &self.repeated
                && *k == key
            {
                return Err(why.clone());
            }
        }
        Ok(())
    }

    /// Why the correspondences do not fit a run of `n_instances`
    /// instances, if they do not.
    pub fn check_instances(&self, n_instances: usize) -> Result<(), String> {
        match self.by_instance.keys().map(|k| k.0).max() {
            Some(i) if i >= n_instances => Err(format!(
                "the run has {n_instances} instances, but matches name instance {i}"
            )),
            _ => Ok(()),
        }
    }
}

/// The node counts of `pair`'s first and second vehicle.
fn node_counts(pair: &PairAtLevel) -> (usize, usize) {
    (
        pair.first.view.detections.len(),
        pair.second.view.detections.len(),
    )
}
