//! [`DeepMatcher`]: a trained network as a [`Matcher`], with MC-dropout
//! inference. Each vehicle's embedding comes from a dropout stream keyed
//! by its network input and is kept in a small cache, shared by every
//! pair that vehicle is in (bit-identical to computing it per pair); the
//! consensus masks come from the pair's stream. The spline convolutions
//! compute messages only for the kernel cells a graph uses, with those
//! cells' weights kept per cell set, and Sinkhorn runs without tensors
//! ([`sinkhorn_probabilities`]). Tensors stay inside: callers get
//! [`MatchDistribution`]s, correspondences and weights as bytes.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use burn::prelude::*;

use super::arch::{Architecture, DeepMethod, MaskScope, likelihood_terms};
use super::cost::{GraphShape, inference_macs, plain_embedding_macs};
use super::decision::{Decision, MatchDistribution, UncertaintyKind};
use super::features::{GraphInput, PairInput, graph_input, pair_input};
use super::init::Init;
use super::masks::{
    MaskDraw, PairMasks, draw_embedding_masks, draw_pair_masks, draw_phi_mask, dropout_mask_16,
    indicator_values, shared_embedding_mask_values,
};
use super::network::{Combination, Network, PairTensors};
use super::plain_pair::{PairResidual, PlainPair};
use super::shared_conv::SharedMaskConv;
use super::sinkhorn::sinkhorn_probabilities;
use super::spline::{CellWeights, GraphBatch};
use super::weights::{from_bytes, to_bytes};
use crate::fusion::PoseEstimate;
use crate::matching::likelihood::{LikelihoodTerms, assign};
use crate::matching::{Identification, MatchView, Matcher, Method};
use crate::rng::{self, Purpose};

/// A key of everything one vehicle's embedding depends on: its network
/// input (node features and edges with their B-spline bases, which carry
/// the reported heading) and the number of samples.
fn embedding_key(input: &GraphInput, samples: usize) -> u64 {
    let mut parts = vec![input.n as u64, samples as u64, input.edge_count() as u64];
    parts.extend(input.node_features.iter().map(|v| u64::from(v.to_bits())));
    parts.extend(
        input
            .src
            .iter()
            .chain(&input.dst)
            .chain(&input.basis_index)
            .map(|&v| v as u64),
    );
    parts.extend(input.basis_weight.iter().map(|v| u64::from(v.to_bits())));
    rng::key(&parts)
}

/// One vehicle's embedding at inference: its network input, its graph
/// tensors and the node embeddings of every MC-dropout sample, `[T, N,
/// out]` row-major; its shape for the arithmetic counts.
struct Embedded {
    input: GraphInput,
    graph: GraphBatch,
    h: Vec<f32>,
    shape: GraphShape,
}

/// Embeddings computed for recent views, by [`embedding_key`]: a vehicle
/// seen in several pairs of a frame is embedded once. Bounded; a hit is
/// bit-identical to recomputing (same input, same dropout stream).
#[derive(Default)]
struct EmbeddingCache {
    entries: HashMap<u64, Arc<Embedded>>,
    hits: u64,
}

/// At most this many embeddings are kept (a frame of a town holds a few
/// dozen vehicles x pose-noise levels).
const CACHE_CAPACITY: usize = 256;

/// How many kernel-cell sets' weights a matcher keeps (each up to 0.8 MB;
/// a scenario's few most common sets cover most graphs).
const CELL_SETS_KEPT: usize = 16;

/// The stream name of the masks every graph and pair shares
/// ([`MaskScope::Shared`]).
const SHARED_MASKS_KEY: u64 = 0x5a4e_d0e8_0000_0008;

/// A stable key of a matching problem's inputs: the masks of a pair depend
/// only on the pair, not on what was matched before.
fn problem_key(first: &MatchView, second: &MatchView) -> u64 {
    let mut parts = vec![
        first.detections.len() as u64,
        second.detections.len() as u64,
    ];
    for d in first.detections.iter().chain(second.detections) {
        parts.push(d.position_m.x.to_bits());
        parts.push(d.position_m.y.to_bits());
    }
    rng::key(&parts)
}

/// The T MC-dropout samples of one pair.
#[derive(Clone, Debug, PartialEq)]
pub struct PairSamples {
    pub n1: usize,
    pub n2: usize,
    /// Each sample's scores, `T x n1 x n2` row-major (`None`: gated).
    pub scores: Vec<Option<f64>>,
    /// Each sample's soft assignment, `(n1 + 1) x (n2 + 1)` row-major.
    pub assignments: Vec<Vec<f32>>,
    /// The scores' mean over the samples, `n1 x n2`: the shared
    /// likelihood plus the gated mean residual.
    pub mean_scores: Vec<Option<f64>>,
}

/// The plain inference path under shared masks: the second spline layer
/// and the pair part.
struct PlainPath {
    second_layer: SharedMaskConv,
    pair: PlainPair,
}

/// The plain path with the (samples, seed) of its masks.
type KeptPath = ((usize, u64), Arc<PlainPath>);

/// A trained deep matcher with MC-dropout inference.
pub struct DeepMatcher {
    pub method: Method,
    pub arch: Architecture,
    net: Network,
    device: Device,
    /// Monte Carlo samples (paper: T = 20).
    pub samples: usize,
    /// Removal of uncertain pairs in [`Matcher::identify`].
    pub threshold: Option<(UncertaintyKind, f64)>,
    /// How the pairs are chosen from the samples.
    pub decision: Decision,
    /// The calibration temperature of the reported probabilities.
    pub temperature: f64,
    /// Seed of the dropout-mask streams.
    pub seed: u64,
    /// How the MC-dropout masks are drawn.
    pub masks: MaskScope,
    /// The shared likelihood's terms and gates.
    terms: LikelihoodTerms,
    /// Reuse each vehicle's embedding across the pairs it is in.
    share_embeddings: bool,
    /// The spline layers' weights per set of kernel cells (bit mask).
    cell_weights: Mutex<HashMap<u32, Arc<CellWeights>>>,
    /// The network's scalar parameters, read once.
    combination: Combination,
    cache: Mutex<EmbeddingCache>,
    /// Whether the second layer and the pair part run in plain Rust
    /// under shared masks ([`SharedMaskConv`], [`PlainPair`]); else
    /// through the tensors, as in training.
    plain: bool,
    /// Those parts under this matcher's shared masks, built at first use
    /// for its (samples, seed).
    plain_path: Mutex<Option<KeptPath>>,
    /// Multiply-adds done so far ([`super::cost`]).
    macs: AtomicU64,
}

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
    /// Seed of the dropout-mask streams.
    pub seed: u64,
    /// How the MC-dropout masks are drawn (Eq. 8: shared).
    pub masks: MaskScope,
    /// Every layer's dropout rate at inference (`None`: as trained).
    pub dropout: Option<f64>,
    /// The likelihood's gate on the squared Mahalanobis distance.
    pub gate_chi2: f64,
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
        seed: 1,
        masks: MaskScope::Shared,
        dropout: None,
        gate_chi2: 9.21,
    };
}

impl DeepMatcher {
    fn new(method: Method, net: Network, mut arch: Architecture, run: Inference) -> Self {
        // The masks are drawn at this rate; the network is the same.
        if let Some(p) = run.dropout {
            (arch.dropout_conv, arch.dropout_phi) = (p, p);
        }
        let net = net.valid();
        let combination = net.combination();
        Self {
            method,
            arch,
            net,
            device: Device::flex(),
            samples: run.samples,
            threshold: run.threshold,
            decision: run.decision,
            temperature: run.temperature,
            seed: run.seed,
            masks: run.masks,
            terms: likelihood_terms(&arch, run.gate_chi2),
            share_embeddings: true,
            cache: Mutex::default(),
            cell_weights: Mutex::default(),
            combination,
            plain: true,
            plain_path: Mutex::default(),
            macs: AtomicU64::new(0),
        }
    }

    /// Runs the second spline layer and the pair part through the
    /// tensors, as training does: the reference the plain path is held
    /// equal to.
    pub fn with_tensor_path(mut self) -> Self {
        self.plain = false;
        self
    }

    /// The plain path under this matcher's shared masks, when it runs:
    /// the masks are the same for every graph and pair, so the kept
    /// weights are gathered once.
    fn plain_path(&self) -> Option<Arc<PlainPath>> {
        if !self.plain || self.masks != MaskScope::Shared {
            return None;
        }
        let key = (self.samples, self.seed);
        let mut kept = self.plain_path.lock().ok()?;
        if let Some((k, path)) = kept.as_ref()
            && *k == key
        {
            return Some(Arc::clone(path));
        }
        let mut stream = rng::stream(self.seed, Purpose::EmbeddingDropout, &[SHARED_MASKS_KEY]);
        let (m1, m2) = shared_embedding_mask_values(&mut stream, &self.arch, self.samples);
        // The consensus MLP's masks, drawn as `pair_masks` draws them.
        let mut shared = rng::stream(self.seed, Purpose::Dropout, &[SHARED_MASKS_KEY]);
        let r = self.arch.consensus_dim;
        let phi = dropout_mask_16(&mut shared, self.samples * r, self.arch.dropout_phi);
        let path = Arc::new(PlainPath {
            second_layer: SharedMaskConv::new(&self.net.second_layer(), &m1, &m2),
            pair: PlainPair::new(self.net.pair_weights(), self.samples, &phi),
        });
        *kept = Some((key, Arc::clone(&path)));
        Some(path)
    }

    /// Computes every pair's embeddings afresh (the per-pair path; results
    /// are bit-identical either way).
    pub fn without_shared_embeddings(mut self) -> Self {
        self.share_embeddings = false;
        self
    }

    /// How many embeddings were reused so far.
    pub fn shared_embeddings(&self) -> u64 {
        self.cache.lock().map_or(0, |c| c.hits)
    }

    /// One vehicle's embedding: from the cache, or computed with the
    /// conv dropout masks of its own stream (keyed by its input).
    #[cfg(test)]
    fn embedding(&self, view: &MatchView) -> Arc<Embedded> {
        let [e] = self.embeddings([view]);
        e
    }

    /// Each view's embedding, from the cache or computed; with the plain
    /// second layer, those not cached go through it together, so that
    /// each sample's weights are read once for all of them.
    fn embeddings<const K: usize>(&self, views: [&MatchView; K]) -> [Arc<Embedded>; K] {
        let inputs = views.map(|v| graph_input(v.detections, v.graph, &v.pose_reported));
        let keys = inputs.each_ref().map(|i| embedding_key(i, self.samples));
        let mut found = keys.map(|k| self.cached(k));
        let missing: Vec<usize> = (0..K).filter(|&k| found[k].is_none()).collect();
        let graphs: Vec<GraphBatch> = missing.iter().map(|&k| self.graph(&inputs[k])).collect();
        let shapes: Vec<GraphShape> = missing
            .iter()
            .map(|&k| GraphShape::of_input(&inputs[k]))
            .collect();
        let plain = self.plain_path();
        let macs = |&s: &GraphShape| match plain {
            Some(_) => plain_embedding_macs(&self.arch, s, self.samples) as u64,
            None => inference_macs(&self.arch, s, s, self.samples).embeddings[0],
        };
        self.macs
            .fetch_add(shapes.iter().map(macs).sum(), Ordering::Relaxed);
        let hs: Vec<Vec<f32>> = if let Some(plain) = plain {
            let firsts: Vec<Vec<f32>> = graphs.iter().map(|g| self.net.first_layer(g)).collect();
            let layers: Vec<(&[f32], &GraphInput)> = firsts
                .iter()
                .zip(&missing)
                .map(|(h, &k)| (h.as_slice(), &inputs[k]))
                .collect();
            plain.second_layer.forward_many(&layers)
        } else {
            graphs
                .iter()
                .zip(&missing)
                .map(|(g, &k)| {
                    let h = self.tensor_embedding(g, &inputs[k], keys[k]);
                    h.try_into_vec_as::<f32>().unwrap_or_default()
                })
                .collect()
        };
        let mut inputs = inputs.map(Some);
        for (((graph, h), shape), &k) in graphs.into_iter().zip(hs).zip(shapes).zip(&missing) {
            let input = inputs[k].take().expect("each view computed once");
            let e = Arc::new(Embedded {
                input,
                graph,
                h,
                shape,
            });
            if self.share_embeddings
                && let Ok(mut cache) = self.cache.lock()
            {
                if cache.entries.len() >= CACHE_CAPACITY {
                    cache.entries.clear();
                }
                cache.entries.insert(keys[k], Arc::clone(&e));
            }
            found[k] = Some(e);
        }
        found.map(|e| e.expect("every embedding found or computed"))
    }

    /// The embedding under `key` if it is kept.
    fn cached(&self, key: u64) -> Option<Arc<Embedded>> {
        if !self.share_embeddings {
            return None;
        }
        let mut cache = self.cache.lock().ok()?;
        let e = cache.entries.get(&key).cloned()?;
        cache.hits += 1;
        Some(e)
    }

    /// A graph as tensors with its kept cell weights.
    fn graph(&self, input: &GraphInput) -> GraphBatch {
        let graph = GraphBatch::used_cells(input, &self.device);
        match self.cell_weights(&graph) {
            Some(weights) => graph.with_weights(weights),
            None => graph,
        }
    }

    /// The embedding through the tensors with the masks of its stream.
    fn tensor_embedding(&self, graph: &GraphBatch, input: &GraphInput, key: u64) -> Tensor<4> {
        // Shared masks: one stream for every graph, so that sample t is
        // one draw of the weights wherever it is used.
        let stream_key = match self.masks {
            MaskScope::PerNode => key,
            MaskScope::Shared => SHARED_MASKS_KEY,
        };
        let mut stream = rng::stream(self.seed, Purpose::EmbeddingDropout, &[stream_key]);
        let (m1, m2) = draw_embedding_masks(
            &mut stream,
            &self.arch,
            [self.samples, input.n],
            self.masks,
            &self.device,
        );
        self.net.embed(graph, m1, m2)
    }

    /// The spline layers' weights of `graph`'s kernel cells, kept per cell
    /// set (a scenario's graphs use a few dozen sets): selecting them anew
    /// for every graph cost as much as a tenth of inference. `None` for a
    /// set not kept (the layers then select them).
    fn cell_weights(&self, graph: &GraphBatch) -> Option<Arc<CellWeights>> {
        let mut cache = self.cell_weights.lock().ok()?;
        if let Some(weights) = cache.get(&graph.cell_mask) {
            return Some(Arc::clone(weights));
        }
        // The first sets seen are kept: the common ones come early.
        (cache.len() < CELL_SETS_KEPT).then(|| {
            let weights = Arc::new(self.net.cell_weights(graph));
            cache.insert(graph.cell_mask, Arc::clone(&weights));
            weights
        })
    }

    /// A deep method with trained weights (the bytes of its `.bpk` file);
    /// an error says why the bytes do not fit the method's network.
    pub fn from_weights(
        method: DeepMethod,
        weights: &[u8],
        run: Inference,
    ) -> Result<Self, String> {
        let arch = method.architecture().ok_or_else(|| {
            format!(
                "'{}' is a published network, not the project's",
                method.method().as_str()
            )
        })?;
        let net = from_bytes(&arch, weights, &Device::flex())?;
        Ok(Self::new(method.method(), net, arch, run))
    }

    /// The same matcher reporting its answers as `method`'s (a
    /// single-pass variant of the method whose weights it runs).
    pub fn labelled(mut self, method: Method) -> Self {
        self.method = method;
        self
    }

    /// A deep method with freshly initialised weights (`init_seed`), as
    /// training starts from: for benchmarks, and for tests.
    pub fn untrained(method: Method, arch: Architecture, init_seed: u64, run: Inference) -> Self {
        let net = Network::new(&arch, Init::Seeded(init_seed), &Device::flex());
        Self::new(method, net, arch, run)
    }

    /// The weights as bytes (what a `.bpk` file holds).
    pub fn weights(&self) -> Result<Vec<u8>, String> {
        to_bytes(&self.net)
    }

    /// The consensus masks of one pair: all from the pair's own stream
    /// (per node), or its random indicators from it and the consensus
    /// MLP's dropout mask of each sample, the same for every pair
    /// (shared).
    fn pair_masks(&self, first: &MatchView, second: &MatchView) -> PairMasks {
        let (n1, n2, t) = (
            first.detections.len(),
            second.detections.len(),
            self.samples,
        );
        let mut stream = rng::stream(self.seed, Purpose::Dropout, &[problem_key(first, second)]);
        let shape = [1, t, n1, n2];
        match self.masks {
            MaskScope::PerNode => draw_pair_masks(
                &mut stream,
                &self.arch,
                shape,
                dropout_mask_16,
                &self.device,
            ),
            MaskScope::Shared => {
                let ones: MaskDraw = |_, len, _| vec![1.0; len];
                let mut m = draw_pair_masks(&mut stream, &self.arch, shape, ones, &self.device);
                if self.arch.consensus {
                    let mut shared = rng::stream(self.seed, Purpose::Dropout, &[SHARED_MASKS_KEY]);
                    m.phi = draw_phi_mask(
                        &mut shared,
                        &self.arch,
                        [t, n1, n2],
                        self.masks,
                        &self.device,
                    );
                }
                m
            }
        }
    }

    /// The `samples` MC-dropout passes over one pair (both sides
    /// non-empty), with `relative` the second vehicle's pose in the first
    /// one's frame.
    pub fn samples(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> PairSamples {
        let (n1, n2, t) = (
            first.detections.len(),
            second.detections.len(),
            self.samples,
        );
        let [e1, e2] = self.embeddings([first, second]);
        let macs = inference_macs(&self.arch, e1.shape, e2.shape, t).shared_pair();
        self.macs.fetch_add(macs, Ordering::Relaxed);
        let input = pair_input(first, second, relative, &self.terms);
        let out = match self.plain_path() {
            Some(plain) => {
                // The pair's indicators: the first normals of its stream,
                // as `pair_masks` draws them under shared masks.
                let key = problem_key(first, second);
                let mut stream = rng::stream(self.seed, Purpose::Dropout, &[key]);
                let indicators = indicator_values(&mut stream, n1 * self.arch.consensus_dim);
                plain
                    .pair
                    .forward((&e1.h, &e1.input), (&e2.h, &e2.input), &input, &indicators)
            }
            None => self.tensor_pair([&e1, &e2], &input, first, second),
        };
        let residual = out.residual;
        let c = self.combination;
        let (scale, gate) = (f64::from(c.scale), f64::from(c.gate));
        let score = |ll: Option<f64>, r: f64| ll.map(|l| scale * l + gate * r);
        let mut scores = Vec::with_capacity(t * n1 * n2);
        for sample in residual.chunks(n1 * n2) {
            scores.extend(
                input
                    .log_likelihood
                    .iter()
                    .zip(sample)
                    .map(|(&ll, &r)| score(ll, f64::from(r))),
            );
        }
        let mean_scores: Vec<Option<f64>> = (0..n1 * n2)
            .map(|k| {
                let r = (0..t)
                    .map(|s| f64::from(residual[s * n1 * n2 + k]))
                    .sum::<f64>();
                score(input.log_likelihood[k], r / t as f64)
            })
            .collect();
        let dust = out.dust.map(|d| {
            d.iter()
                .map(|&v| f64::from(c.dustbin) + f64::from(c.dust_gate) * f64::from(v))
                .collect::<Vec<f64>>()
        });
        let finite: Vec<f64> = scores
            .iter()
            .map(|s| s.unwrap_or(f64::NEG_INFINITY))
            .collect();
        let p = sinkhorn_probabilities(
            &finite,
            [t, n1, n2],
            [&dust[0], &dust[1]],
            f64::from(c.dustbin),
            self.arch.sinkhorn_iters,
        );
        PairSamples {
            n1,
            n2,
            scores,
            assignments: p.chunks((n1 + 1) * (n2 + 1)).map(<[f32]>::to_vec).collect(),
            mean_scores,
        }
    }

    /// The pair part through the tensors (the reference of the plain
    /// one, and what per-node masks use).
    fn tensor_pair(
        &self,
        [e1, e2]: [&Embedded; 2],
        input: &PairInput,
        first: &MatchView,
        second: &MatchView,
    ) -> PairResidual {
        let (n1, n2) = (input.n1, input.n2);
        let tensors = PairTensors::new(&[input], [n1, n2], &self.device);
        let masks = self.pair_masks(first, second);
        let h = |e: &Embedded| {
            let shape = [1, self.samples, e.input.n, self.arch.out];
            Tensor::<4>::from_data(TensorData::new(e.h.clone(), shape), &self.device)
        };
        let (h1, h2) = (h(e1), h(e2));
        let out = self
            .net
            .pair((&h1, &e1.graph), (&h2, &e2.graph), &tensors, masks);
        PairResidual {
            residual: out.residual.try_into_vec_as::<f32>().unwrap_or_default(),
            dust: out
                .dust
                .map(|d| d.try_into_vec_as::<f32>().unwrap_or_default()),
        }
    }

    /// E[Y], the per-pair uncertainties and the decided pairs from
    /// `samples` MC-dropout passes.
    pub fn distribution(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> MatchDistribution {
        let (n1, n2) = (first.detections.len(), second.detections.len());
        if n1 == 0 || n2 == 0 {
            let mut d = MatchDistribution::all_unmatched(n1, n2);
            d.decision = self.decision;
            d.temperature = self.temperature;
            return d;
        }
        let s = self.samples(first, second, relative);
        let mut d = MatchDistribution::from_samples(n1, n2, &s.assignments);
        d.assigned = assign(n1, n2, &s.mean_scores);
        d.decision = self.decision;
        d.temperature = self.temperature;
        d
    }
}

/// The weights of an untrained network of `method` whose gates are open
/// (as after the first training steps): for tests of everything the
/// learned parts touch, without training.
#[cfg(test)]
pub(crate) fn opened_weights(method: DeepMethod, seed: u64) -> Vec<u8> {
    match method.backbone() {
        super::arch::Backbone::Likelihood(arch) => {
            let net = Network::new(&arch, Init::Seeded(seed), &Device::flex()).with_gates(1.0);
            to_bytes(&net).expect("weights")
        }
        super::arch::Backbone::Published(cfg) => {
            let net =
                super::published::PublishedNet::new(&cfg, Init::Seeded(seed), &Device::flex());
            super::published::to_bytes(&net).expect("weights")
        }
    }
}

impl Matcher for DeepMatcher {
    fn method(&self) -> Method {
        self.method
    }

    fn network_macs(&self) -> u64 {
        self.macs.load(Ordering::Relaxed)
    }

    fn uses_positions(&self) -> bool {
        self.arch.positions
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> Identification {
        let distribution = self.distribution(first, second, relative);
        Identification {
            matches: distribution.decide(self.threshold),
            distribution: Some(distribution),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Vec2;
    use crate::matching::Correspondence;
    use crate::matching::gps_hungarian::GpsHungarian;
    use crate::matching::testkit::{self, GPS, Side};
    use crate::traffic::ObjectClass;

    const RUN: Inference = Inference {
        seed: 3,
        masks: MaskScope::PerNode,
        ..Inference::MC_DROPOUT
    };

    /// An untrained network whose gates are open (as after the first
    /// training steps), so that the residual and its dropout count.
    fn opened(arch: Architecture, seed: u64) -> DeepMatcher {
        let net = Network::new(&arch, Init::Seeded(seed), &Device::flex()).with_gates(1.0);
        DeepMatcher::new(Method::Ours, net, arch, RUN)
    }

    /// The MC samples of the moved-copy scene.
    fn mc_samples(m: &DeepMatcher) -> Vec<Vec<f32>> {
        let (a, b) = testkit::moved_copy();
        let (va, vb) = (a.view(), b.view());
        let s = m.samples(&va, &vb, &crate::matching::gps_relative_pose(&va, &vb));
        assert_eq!(s.assignments.len(), 20);
        s.assignments
    }

    /// Largest per-entry variance across samples.
    fn max_variance(samples: &[Vec<f32>]) -> f64 {
        let t = samples.len() as f64;
        (0..samples[0].len())
            .map(|k| {
                let mean = samples.iter().map(|s| f64::from(s[k])).sum::<f64>() / t;
                samples
                    .iter()
                    .map(|s| (f64::from(s[k]) - mean).powi(2))
                    .sum::<f64>()
                    / t
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn mc_dropout_samples_really_differ_at_inference() {
        let v = max_variance(&mc_samples(&opened(Architecture::default(), 3)));
        assert!(
            v > 1e-4,
            "p > 0 must give varying samples (max variance {v})"
        );
        let without = Architecture {
            dropout_conv: 0.0,
            dropout_phi: 0.0,
            ..Architecture::default()
        };
        let samples = mc_samples(&opened(without, 3));
        assert!(
            samples.iter().all(|s| *s == samples[0]),
            "p = 0 must give identical samples"
        );
    }

    /// Eq. 8's shared masks: the samples still vary, the same seed gives
    /// the same samples, and they are other draws than per-node masks.
    #[test]
    fn shared_dropout_masks_vary_by_sample_and_repeat_by_seed() {
        let shared = |seed| {
            let mut m = opened(Architecture::default(), 3);
            m.masks = MaskScope::Shared;
            m.seed = seed;
            mc_samples(&m)
        };
        let s = shared(3);
        assert!(max_variance(&s) > 1e-4);
        assert_eq!(s, shared(3));
        assert_ne!(s, shared(4));
        assert_ne!(s, mc_samples(&opened(Architecture::default(), 3)));
    }

    #[test]
    fn weights_as_bytes_give_identical_outputs() {
        let m = opened(Architecture::default(), 11);
        let loaded =
            DeepMatcher::from_weights(DeepMethod::Ours, &m.weights().unwrap(), RUN).unwrap();
        let (a, b) = testkit::moved_copy();
        let (va, vb) = (a.view(), b.view());
        let relative = crate::matching::gps_relative_pose(&va, &vb);
        assert_eq!(
            m.distribution(&va, &vb, &relative),
            loaded.distribution(&va, &vb, &relative)
        );
        // gcn-gm has no consensus: the weights of `ours` do not fit it.
        let e = DeepMatcher::from_weights(DeepMethod::GcnGmGps, &m.weights().unwrap(), RUN);
        assert!(e.is_err());
        // gcn-gm (as published) is not this network at all.
        let e = DeepMatcher::from_weights(DeepMethod::GcnGm, &m.weights().unwrap(), RUN);
        assert!(e.is_err());
    }

    /// The plain path under shared masks (second layer and pair part)
    /// against the tensor path (the reference, as training runs it), on
    /// graphs of 8, 9, 2 and 1 nodes (the last has no edge): every
    /// sample's embedding, score and assignment and the mean scores within
    /// 1e-5 of the largest of its magnitude and 1, and the same
    /// correspondences.
    #[test]
    fn the_plain_path_equals_the_tensor_one() {
        // The shipped weights: an untrained network's biases are zero and
        // would hide a bias the plain path forgot.
        let shared = |plain: bool| {
            let weights = include_bytes!("../../../models/ours.bpk");
            let mut m = DeepMatcher::from_weights(DeepMethod::Ours, weights, RUN).unwrap();
            m.masks = MaskScope::Shared;
            if plain { m } else { m.with_tensor_path() }
        };
        let (plain, tensor) = (shared(true), shared(false));
        let objects = testkit::world_objects();
        let side = |at, order: &[usize]| Side::of(at, &objects, order, GPS);
        let scenes = [
            testkit::moved_copy(),
            (side(testkit::POSE_A, &[0, 1, 2, 3, 4, 5, 6, 7]), queue()),
            (side(testkit::POSE_A, &[0, 3]), side(testkit::POSE_B, &[3])),
        ];
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-5 * a.abs().max(1.0);
        for (a, b) in &scenes {
            let (va, vb) = (a.view(), b.view());
            for v in [&va, &vb] {
                let h = |m: &DeepMatcher| m.embedding(v).h.clone();
                let (hp, ht) = (h(&plain), h(&tensor));
                assert_eq!(hp.len(), ht.len());
                for (x, y) in hp.iter().zip(&ht) {
                    assert!(close(f64::from(*x), f64::from(*y)), "{x} vs {y}");
                }
            }
            let relative = crate::matching::gps_relative_pose(&va, &vb);
            let (sp, st) = (
                plain.samples(&va, &vb, &relative),
                tensor.samples(&va, &vb, &relative),
            );
            assert_eq!(sp.scores.len(), st.scores.len());
            for (p, t) in sp.scores.iter().zip(&st.scores) {
                assert_eq!(p.is_some(), t.is_some());
                if let (Some(p), Some(t)) = (p, t) {
                    assert!(close(*p, *t), "{p} vs {t}");
                }
            }
            for (p, t) in sp
                .assignments
                .iter()
                .flatten()
                .zip(st.assignments.iter().flatten())
            {
                assert!(close(f64::from(*p), f64::from(*t)), "{p} vs {t}");
            }
            for (p, t) in sp.mean_scores.iter().zip(&st.mean_scores) {
                assert_eq!(p.is_some(), t.is_some());
                if let (Some(p), Some(t)) = (p, t) {
                    assert!(close(*p, *t), "{p} vs {t}");
                }
            }
            let (mp, mt) = (
                plain.identify(&va, &vb).matches,
                tensor.identify(&va, &vb).matches,
            );
            let pairs = |m: &[Correspondence]| m.iter().map(|c| (c.a, c.b)).collect::<Vec<_>>();
            assert_eq!(pairs(&mp), pairs(&mt));
            for (p, t) in mp.iter().zip(&mt) {
                assert!(close(p.probability, t.probability), "{p:?} vs {t:?}");
                assert!(close(p.uncertainty, t.uncertainty), "{p:?} vs {t:?}");
            }
        }
        // A single node: no edge, the root alone.
        let one = side(testkit::POSE_A, &[4]);
        let h = |m: &DeepMatcher| m.embedding(&one.view()).h.clone();
        for (x, y) in h(&plain).iter().zip(&h(&tensor)) {
            assert!(close(f64::from(*x), f64::from(*y)), "{x} vs {y}");
        }
    }

    /// The queue scene seen from the second fixture pose.
    fn queue() -> Side {
        let scene = queue_scene();
        Side::of(
            testkit::POSE_B,
            &scene,
            &(0..scene.len()).collect::<Vec<_>>(),
            GPS,
        )
    }

    /// A queue of six cars 5.5 m apart (colours differ), a pedestrian, a
    /// truck and a bicycle.
    fn queue_scene() -> Vec<(Vec2, ObjectClass, [f64; 3])> {
        let colours = [
            [0.95; 3],
            [0.1; 3],
            [0.7, 0.1, 0.1],
            [0.6; 3],
            [0.1, 0.2, 0.7],
            [0.9, 0.8, 0.1],
        ];
        let mut v: Vec<_> = (0..6)
            .map(|k| {
                (
                    Vec2::new(10.0 + 5.5 * k as f64, 2.0),
                    ObjectClass::Car,
                    colours[k],
                )
            })
            .collect();
        v.push((Vec2::new(14.0, 12.0), ObjectClass::Pedestrian, [0.2; 3]));
        v.push((Vec2::new(30.0, -9.0), ObjectClass::Truck, [0.7, 0.1, 0.1]));
        v.push((Vec2::new(24.0, 15.0), ObjectClass::Bicycle, [0.1; 3]));
        v
    }

    /// Untrained, every variant with positions scores each pair by the
    /// shared likelihood alone, so that its assignment is GPS+appearance
    /// Hungarian's, pair for pair, on scenes with GPS error, look-alikes
    /// and objects only one vehicle sees; `ours-noprior` is the
    /// appearance-only Hungarian. With the gates open it is not.
    #[test]
    fn untrained_decides_exactly_as_gps_appearance_hungarian() {
        let scene = queue_scene();
        let mut world = testkit::world_objects();
        world.extend(
            scene
                .iter()
                .map(|&(p, c, col)| (p + Vec2::new(40.0, 40.0), c, col)),
        );
        let all: Vec<usize> = (0..world.len()).collect();
        let a = Side::of(testkit::POSE_A, &world, &all, GPS);
        let mut b = Side::of(
            testkit::POSE_B,
            &world,
            &[3, 9, 12, 0, 5, 14, 2, 10, 7, 16],
            GPS,
        );
        b.pose = crate::geometry::Pose2::new(b.pose.position_m() + Vec2::new(2.0, -1.0), -2.39);
        let (va, vb) = (a.view(), b.view());
        let hungarian = |appearance_only: bool| {
            let relative = crate::matching::gps_relative_pose(&va, &vb);
            let terms = LikelihoodTerms {
                position: !appearance_only,
                ..LikelihoodTerms::full(9.21)
            };
            let s: Vec<Option<f64>> =
                crate::matching::likelihood::pair_terms(&va, &vb, &relative, &terms)
                    .iter()
                    .map(|p| p.map(|p| p.log_likelihood()))
                    .collect();
            assign(va.detections.len(), vb.detections.len(), &s)
        };
        let pairs = |m: &dyn Matcher| -> Vec<(usize, usize)> {
            m.identify(&va, &vb)
                .matches
                .iter()
                .map(|c| (c.a, c.b))
                .collect()
        };
        let expected = pairs(&GpsHungarian {
            gate_chi2: 9.21,
            appearance: true,
        });
        assert_eq!(expected, hungarian(false));
        assert!(expected.len() >= 6, "{expected:?}");
        for method in [
            DeepMethod::Ours,
            DeepMethod::CoidNonGps,
            DeepMethod::CoidUncGps,
            DeepMethod::DgmcGps,
            DeepMethod::GcnGmGps,
        ] {
            let arch = method.architecture().unwrap();
            let m = DeepMatcher::untrained(method.method(), arch, 5, RUN);
            assert_eq!(pairs(&m), expected, "{method:?}");
        }
        // Without the position term: an appearance-only Hungarian.
        let arch = Architecture {
            positions: false,
            ..Architecture::default()
        };
        let noprior = DeepMatcher::untrained(Method::Ours, arch, 5, RUN);
        assert_eq!(pairs(&noprior), hungarian(true));
        assert_ne!(hungarian(true), expected);
        let net = Network::new(&Architecture::default(), Init::Seeded(5), &Device::flex());
        let loud = DeepMatcher::new(
            Method::Ours,
            net.with_gates(30.0),
            Architecture::default(),
            RUN,
        );
        assert_ne!(pairs(&loud), expected);
    }

    /// Three vehicles, three pairs: sharing each vehicle's embedding across
    /// its pairs gives the same bits as computing it for every pair, and
    /// it is reused (each vehicle is in two pairs).
    #[test]
    fn shared_embeddings_are_bit_identical_to_the_per_pair_path() {
        let objects = testkit::world_objects();
        let all: Vec<usize> = (0..objects.len()).collect();
        let sides = [
            Side::of(testkit::POSE_A, &objects, &all, GPS),
            Side::of(testkit::POSE_B, &objects, &[5, 2, 7, 0, 3, 6, 1, 4], GPS),
            Side::of((20.0, 40.0, -1.2), &objects, &[1, 3, 4, 6, 7], GPS),
        ];
        let pairs = [(0, 1), (0, 2), (1, 2)];
        let run = |m: &DeepMatcher| -> Vec<Vec<Vec<f32>>> {
            pairs
                .iter()
                .map(|&(i, j)| {
                    let (a, b) = (sides[i].view(), sides[j].view());
                    m.samples(&a, &b, &crate::matching::gps_relative_pose(&a, &b))
                        .assignments
                })
                .collect()
        };
        let shared = opened(Architecture::default(), 4);
        let per_pair = opened(Architecture::default(), 4).without_shared_embeddings();
        let (a, b) = (run(&shared), run(&per_pair));
        assert_eq!(a, b);
        assert_eq!(shared.shared_embeddings(), 3);
        assert_eq!(per_pair.shared_embeddings(), 0);
        // Each counts what it multiplied: every pair part, and each
        // vehicle's embedding once (shared) or once per pair.
        let arch = Architecture::default();
        let shape = |k: usize| GraphShape::of(&sides[k].view());
        let macs = |i: usize, j: usize| inference_macs(&arch, shape(i), shape(j), 20);
        let parts: u64 = pairs.iter().map(|&(i, j)| macs(i, j).shared_pair()).sum();
        let embedded = |k: usize| macs(k, k).embeddings[0];
        let once: u64 = (0..3).map(embedded).sum();
        assert_eq!(shared.network_macs(), parts + once);
        assert_eq!(per_pair.network_macs(), parts + 2 * once);
        // The MC samples differ from each other (dropout is on).
        assert_ne!(a[0][0], a[0][1]);
    }

    #[test]
    fn empty_sides_send_everything_to_the_dustbin() {
        let m = opened(Architecture::default(), 1);
        let (a, b) = testkit::moved_copy();
        let empty = Side::new(vec![], vec![], b.pose, testkit::EXACT);
        let id = m.identify(&a.view(), &empty.view());
        assert!(id.matches.is_empty());
        let d = id.distribution.unwrap();
        assert!((0..a.detections.len()).all(|i| d.p(i, 0) == 1.0));
    }
}
