//! The MC-dropout shell every deep network runs in (the paper's Section
//! 3.3): T stochastic passes over a pair, each under its own dropout
//! masks, E[Y] and the uncertainties over them, and the decision. A
//! network ([`Network`]) says what it reads of a vehicle, how it embeds
//! it and how it scores a pair; the shell keeps each vehicle's embedding
//! for the other pairs it is in, keeps the answers that do not depend on
//! the poses, and counts the multiply-adds. The plain inference of each
//! network and its tensor reference (`super::train::reference`, for the
//! tests) are two implementations of one [`Network`].

pub(crate) mod draws;

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::decision::{Decision, MatchDistribution, UncertaintyKind};
use crate::assignment::assign;
use crate::fusion::PoseEstimate;
use crate::matching::deep::arch::{IndicatorScope, MaskScope};
use crate::matching::{Identification, MatchView, Matcher, Method};

/// How a deep matcher runs (beyond its weights).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Inference {
    /// Monte Carlo samples (paper: T = 20).
    pub samples: usize,
    /// Removal of uncertain pairs (binary entropy of the kind >= lambda).
    pub threshold: Option<(UncertaintyKind, f64)>,
    pub decision: Decision,
    /// The calibration temperature of the reported probabilities.
    pub temperature: f64,
    /// The operating point: the least E[Y] of a decided pair (0: none).
    pub min_probability: f32,
    /// Seed of the dropout-mask streams.
    pub seed: u64,
    /// How the MC-dropout masks are drawn (Eq. 8: shared).
    pub masks: MaskScope,
    /// Every layer's dropout rate at inference (`None`: as trained).
    pub dropout: Option<f64>,
    /// The likelihood's gate on the squared Mahalanobis distance.
    pub gate_chi2: f64,
    /// DGMC's random node indicators: drawn per sample or per pair.
    pub indicators: IndicatorScope,
}

impl Inference {
    /// The paper's MC-dropout inference with nothing chosen yet: T = 20,
    /// Eq. 8's shared masks at the trained rates, the one-to-one
    /// assignment without a threshold or calibration, the 99 % chi2(2)
    /// gate, dropout seed 1. What tests and the bench start from.
    pub const MC_DROPOUT: Inference = Inference {
        samples: 20,
        threshold: None,
        decision: Decision::Assignment,
        temperature: 1.0,
        min_probability: 0.0,
        seed: 1,
        masks: MaskScope::Shared,
        dropout: None,
        gate_chi2: 9.21,
        indicators: IndicatorScope::PerSample,
    };
}

/// One side of a pair as the shell hands it to its network.
pub(crate) struct Side<'a, N: Network + ?Sized> {
    pub(crate) view: &'a MatchView<'a>,
    pub(crate) input: &'a N::Input,
    /// Its embedding, when the network's embeddings are kept per vehicle
    /// ([`Network::keeps_embeddings`]).
    pub(crate) embedding: Option<&'a N::Embedding>,
}

/// The T MC-dropout samples of one pair.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Samples {
    /// Each sample's soft assignment, `(n1 + 1) x (n2 + 1)` row-major.
    pub(crate) assignments: Vec<Vec<f32>>,
    /// Each sample's pair scores, `T x n1 x n2` row-major (`None`:
    /// gated); empty for a network without pair scores of its own.
    pub(crate) scores: Vec<Option<f64>>,
    /// The scores' mean over the samples, `n1 x n2`, on which the pairs
    /// are assigned; `None`: the network has no pair scores, the pairs
    /// are assigned on E[Y] ([`most_likely_total`]).
    pub(crate) mean_scores: Option<Vec<Option<f64>>>,
}

/// What a deep network does at inference, for the shell.
pub(crate) trait Network: Send + Sync {
    /// What the network reads of one vehicle's view.
    type Input: Send + Sync;
    /// One vehicle's node embeddings in every sample.
    type Embedding: Send + Sync;

    /// What the network reads of `view`.
    fn input(&self, view: &MatchView) -> Self::Input;

    /// A key of everything `input`'s embedding depends on.
    fn embedding_key(&self, input: &Self::Input) -> u64;

    /// Whether embeddings are made per vehicle (and kept by
    /// [`Network::embedding_key`]); else [`Network::samples`] makes them
    /// for the pair.
    fn keeps_embeddings(&self) -> bool;

    /// Whether the relative pose it is handed enters its answers.
    fn uses_positions(&self) -> bool;

    /// The embeddings of `inputs` with their keys, computed together,
    /// and the multiply-adds that took.
    fn embed(&self, inputs: &[(&Self::Input, u64)]) -> (Vec<Self::Embedding>, u64);

    /// A key of everything a pair's samples depend on, when that is not
    /// the poses: the shell then keeps the pair's distribution for its
    /// other pose-noise levels. `None`: the samples read the poses.
    fn pose_free_key(&self, inputs: [&Self::Input; 2]) -> Option<u64>;

    /// The MC samples of a pair (both sides non-empty), with `relative`
    /// the second vehicle's pose in the first one's frame, and the
    /// multiply-adds that took beyond the kept embeddings.
    fn samples(&self, sides: [Side<'_, Self>; 2], relative: &PoseEstimate) -> (Samples, u64);
}

/// At most this many embeddings and distributions are kept each (a frame
/// of a town holds a few dozen vehicles x pose-noise levels).
const CAPACITY: usize = 256;

/// Values kept by key, at most [`CAPACITY`] (all dropped when full), and
/// how often one was found.
struct Kept<V> {
    entries: HashMap<u64, V>,
    hits: u64,
}

impl<V: Clone> Kept<V> {
    fn get(&mut self, key: u64) -> Option<V> {
        let v = self.entries.get(&key).cloned()?;
        self.hits += 1;
        Some(v)
    }

    fn insert(&mut self, key: u64, v: V) {
        if self.entries.len() >= CAPACITY {
            self.entries.clear();
        }
        self.entries.insert(key, v);
    }
}

impl<V> Default for Kept<V> {
    fn default() -> Self {
        Self {
            entries: HashMap::new(),
            hits: 0,
        }
    }
}

/// A trained deep network with MC-dropout inference, as a [`Matcher`].
pub(crate) struct McMatcher<N: Network> {
    method: Method,
    network: N,
    run: Inference,
    /// Reuse each vehicle's embedding across the pairs it is in.
    share_embeddings: bool,
    embeddings: Mutex<Kept<Arc<N::Embedding>>>,
    /// Distributions of pairs whose answers do not read the poses.
    distributions: Mutex<Kept<MatchDistribution>>,
    /// Multiply-adds done so far ([`super::cost`]).
    macs: AtomicU64,
}

impl<N: Network> McMatcher<N> {
    pub(crate) fn new(method: Method, network: N, run: Inference) -> Self {
        Self {
            method,
            network,
            run,
            share_embeddings: true,
            embeddings: Mutex::default(),
            distributions: Mutex::default(),
            macs: AtomicU64::new(0),
        }
    }

    /// Computes every pair's embeddings afresh (results are bit-identical
    /// either way).
    #[cfg(test)]
    pub(crate) fn without_shared_embeddings(mut self) -> Self {
        self.share_embeddings = false;
        self
    }

    /// How many embeddings were reused so far.
    #[cfg(test)]
    pub(crate) fn shared_embeddings(&self) -> u64 {
        self.embeddings.lock().map_or(0, |c| c.hits)
    }

    /// Each input's embedding, kept or computed (those not kept
    /// together).
    fn embeddings<const K: usize>(&self, inputs: [&N::Input; K]) -> [Arc<N::Embedding>; K] {
        let keys = inputs.map(|i| self.network.embedding_key(i));
        let mut found: [Option<Arc<N::Embedding>>; K] = keys.map(|k| {
            self.share_embeddings
                .then(|| self.embeddings.lock().ok()?.get(k))
                .flatten()
        });
        let missing: Vec<usize> = (0..K).filter(|&k| found[k].is_none()).collect();
        if !missing.is_empty() {
            let asked: Vec<(&N::Input, u64)> =
                missing.iter().map(|&k| (inputs[k], keys[k])).collect();
            let (made, macs) = self.network.embed(&asked);
            self.macs.fetch_add(macs, Ordering::Relaxed);
            for (e, &k) in made.into_iter().zip(&missing) {
                let e = Arc::new(e);
                if self.share_embeddings
                    && let Ok(mut kept) = self.embeddings.lock()
                {
                    kept.insert(keys[k], Arc::clone(&e));
                }
                found[k] = Some(e);
            }
        }
        found.map(|e| e.expect("every embedding found or computed"))
    }

    /// The `samples` MC-dropout passes over one pair (both sides
    /// non-empty).
    #[cfg(test)]
    pub(crate) fn samples(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> Samples {
        let inputs = [self.network.input(first), self.network.input(second)];
        self.samples_of([first, second], &inputs, relative)
    }

    fn samples_of(
        &self,
        [first, second]: [&MatchView; 2],
        [i1, i2]: &[N::Input; 2],
        relative: &PoseEstimate,
    ) -> Samples {
        let embeddings = if self.network.keeps_embeddings() {
            Some(self.embeddings([i1, i2]))
        } else {
            None
        };
        let [e1, e2] = match &embeddings {
            Some([e1, e2]) => [Some(&**e1), Some(&**e2)],
            None => [None, None],
        };
        let sides = [
            Side {
                view: first,
                input: i1,
                embedding: e1,
            },
            Side {
                view: second,
                input: i2,
                embedding: e2,
            },
        ];
        let (samples, macs) = self.network.samples(sides, relative);
        self.macs.fetch_add(macs, Ordering::Relaxed);
        samples
    }

    /// E[Y], the per-pair uncertainties and the assigned pairs from
    /// `samples` MC-dropout passes.
    pub(crate) fn distribution(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> MatchDistribution {
        let (n1, n2) = (first.detections.len(), second.detections.len());
        let mut d = if n1 == 0 || n2 == 0 {
            MatchDistribution::all_unmatched(n1, n2)
        } else {
            let inputs = [self.network.input(first), self.network.input(second)];
            let kept_as = self.network.pose_free_key([&inputs[0], &inputs[1]]);
            let kept = kept_as.and_then(|k| self.distributions.lock().ok()?.get(k));
            match kept {
                Some(d) => d,
                None => {
                    let s = self.samples_of([first, second], &inputs, relative);
                    let mut d = MatchDistribution::from_samples(n1, n2, &s.assignments);
                    d.assigned = match &s.mean_scores {
                        Some(scores) => assign(n1, n2, scores),
                        None => most_likely_total(&d),
                    };
                    if let Some(k) = kept_as
                        && let Ok(mut kept) = self.distributions.lock()
                    {
                        kept.insert(k, d.clone());
                    }
                    d
                }
            }
        };
        d.decision = self.run.decision;
        d.temperature = self.run.temperature;
        d.min_probability = self.run.min_probability;
        d
    }
}

/// The one-to-one assignment of E[Y] with the most likely total: pairs
/// maximising the sum of `ln E[Y]_ij`, a pair allowed only where it is
/// more likely than "no match" for both of its nodes (its row's and its
/// column's dustbin). What [`Decision::Assignment`] pairs for a network
/// without pair scores of its own.
fn most_likely_total(d: &MatchDistribution) -> Vec<(usize, usize)> {
    let (n1, n2) = (d.n1, d.n2);
    let scores: Vec<Option<f64>> = (0..n1)
        .flat_map(|i| (0..n2).map(move |j| (i, j)))
        .map(|(i, j)| {
            let p = d.p(i, j);
            (p > d.p(i, n2) && p > d.p(n1, j) && p > 0.0).then(|| f64::from(p).ln())
        })
        .collect();
    assign(n1, n2, &scores)
}

impl<N: Network> Matcher for McMatcher<N> {
    fn method(&self) -> Method {
        self.method
    }

    fn network_macs(&self) -> u64 {
        self.macs.load(Ordering::Relaxed)
    }

    fn uses_positions(&self) -> bool {
        self.network.uses_positions()
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> Identification {
        let distribution = self.distribution(first, second, relative);
        Identification {
            matches: distribution.decide(self.run.threshold),
            distribution: Some(distribution),
        }
    }
}
