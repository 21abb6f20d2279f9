//! The paper's Bayesian deep graph matcher (Section 3) and its deep
//! baselines and ablations. `features` and `decision` are plain Rust;
//! `model`, `train` and this module (tensor conversion at its boundary)
//! are the only code in the crate that see tensors (burn). Callers get
//! [`MatchDistribution`]s, correspondences, and weights as bytes: reading
//! and writing weight files is the caller's business (`io`).

pub mod decision;
pub mod features;
pub mod model;
pub mod train;

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use burn::prelude::*;
use rand::{Rng, RngCore};
use rand_chacha::ChaCha8Rng;

use self::decision::{MatchDistribution, UncertaintyKind};
use self::features::GraphInput;
use self::features::graph_input;
use self::model::{
    Architecture, CellWeights, GraphTensors, Init, LossTerms, Masks, Network, PairMasks,
};
use super::{Identification, MatchView, Matcher, Method};
use crate::rng::{self, Purpose};

/// Architecture and loss terms of each deep method (paper Table 1 rows).
pub fn variant(method: Method) -> Option<(Architecture, LossTerms)> {
    let arch = Architecture::default();
    let (consensus, non, unc) = match method {
        Method::Ours | Method::OursNoPrior => (true, true, true),
        Method::CoidNon => (true, true, false),
        Method::CoidUnc => (true, false, true),
        Method::Dgmc => (true, false, false),
        Method::GcnGm => (false, false, false),
        _ => return None,
    };
    let gps_prior = method != Method::OursNoPrior;
    Some((
        Architecture {
            consensus,
            gps_prior,
            ..arch
        },
        LossTerms {
            non,
            unc,
            dustbin: false,
        },
    ))
}

/// Whether a method's decision removes uncertain pairs: the methods trained
/// with the paper's uncertainty-aware losses do; DGMC and GCN-GM, as
/// published, do not (their thresholded F1 is still reported in Table 2).
pub fn thresholds_by_default(method: Method) -> bool {
    matches!(
        method,
        Method::Ours | Method::OursNoPrior | Method::CoidNon | Method::CoidUnc
    )
}

/// Draws inverted-dropout masks (0 or 1 / (1 - p)) of the given shape.
fn dropout_mask(rng: &mut ChaCha8Rng, len: usize, p: f64) -> Vec<f32> {
    if p <= 0.0 {
        return vec![1.0; len];
    }
    let keep = 1.0 - p;
    let scale = (1.0 / keep) as f32;
    // Compare raw 32-bit draws with the keep threshold: one draw per unit.
    let threshold = (keep * 4_294_967_296.0).min(f64::from(u32::MAX)) as u32;
    let mut out = vec![0f32; len];
    for v in out.iter_mut() {
        if rng.next_u32() < threshold {
            *v = scale;
        }
    }
    out
}

/// Inference masks: [`dropout_mask`] with two units per 32-bit draw (the
/// keep probability rounded to 1/65536: 0.8 becomes 0.800003), half the
/// random numbers of the training masks.
fn dropout_mask_16(rng: &mut ChaCha8Rng, len: usize, p: f64) -> Vec<f32> {
    if p <= 0.0 {
        return vec![1.0; len];
    }
    let keep = 1.0 - p;
    let scale = (1.0 / keep) as f32;
    let threshold = (keep * 65_536.0).round().min(65_536.0) as u32;
    let mut words = vec![0u32; len.div_ceil(2)];
    rng.fill(&mut words[..]);
    let mut out = vec![0f32; 2 * words.len()];
    for (o, &w) in out.chunks_exact_mut(2).zip(&words) {
        o[0] = scale * f32::from(u8::from((w & 0xFFFF) < threshold));
        o[1] = scale * f32::from(u8::from((w >> 16) < threshold));
    }
    out.truncate(len);
    out
}

/// All masks of one forward pass with `t` samples, from one stream.
fn draw_masks(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    t: usize,
    n1: usize,
    n2: usize,
    device: &Device,
) -> Masks {
    let mut mask = |n: usize, d: usize, p: f64| {
        Tensor::<3>::from_data(
            TensorData::new(dropout_mask(rng, t * n * d, p), [t, n, d]),
            device,
        )
    };
    let conv1 = [
        mask(n1, arch.hidden, arch.dropout_conv),
        mask(n2, arch.hidden, arch.dropout_conv),
    ];
    let conv2 = [
        mask(n1, arch.out, arch.dropout_conv),
        mask(n2, arch.out, arch.dropout_conv),
    ];
    let pair = draw_consensus_masks(rng, arch, [t, n1, n2], dropout_mask, device);
    Masks {
        conv1,
        conv2,
        phi: pair.phi,
        indicators: pair.indicators,
    }
}

/// The conv dropout masks of one vehicle's embedding with `t` samples,
/// `[t, n, hidden]` and `[t, n, out]`.
fn draw_embedding_masks(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    t: usize,
    n: usize,
    device: &Device,
) -> (Tensor<3>, Tensor<3>) {
    let mut mask = |d: usize| {
        Tensor::<3>::from_data(
            TensorData::new(
                dropout_mask_16(rng, t * n * d, arch.dropout_conv),
                [t, n, d],
            ),
            device,
        )
    };
    (mask(arch.hidden), mask(arch.out))
}

/// The consensus masks of one pair with `t` samples: the phi dropout
/// (drawn by `draw`: the training or the inference mask) and the random
/// node indicators.
fn draw_consensus_masks(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    [t, n1, n2]: [usize; 3],
    draw: fn(&mut ChaCha8Rng, usize, f64) -> Vec<f32>,
    device: &Device,
) -> PairMasks {
    let r = arch.consensus_dim;
    let phi = if arch.consensus {
        Tensor::<4>::from_data(
            TensorData::new(draw(rng, t * n1 * n2 * r, arch.dropout_phi), [t, n1, n2, r]),
            device,
        )
    } else {
        Tensor::<4>::ones([1, 1, 1, 1], device)
    };
    let normal = rand_distr::StandardNormal;
    let indicators: Vec<f32> = (0..n1 * r)
        .map(|_| rng.sample::<f64, _>(normal) as f32)
        .collect();
    PairMasks {
        phi,
        indicators: Tensor::from_data(TensorData::new(indicators, [1, n1, r]), device),
    }
}

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

/// One vehicle's embedding at inference: its graph tensors and the node
/// embeddings of every MC-dropout sample, `[T, N, out]`.
struct Embedded {
    graph: GraphTensors,
    h: Tensor<3>,
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
    /// Seed of the dropout-mask streams.
    pub seed: u64,
    /// Reuse each vehicle's embedding across the pairs it is in.
    share_embeddings: bool,
    /// The spline layers' weights per set of kernel cells (bit mask).
    cell_weights: Mutex<HashMap<u32, Arc<CellWeights>>>,
    /// The network's dustbin score, read once.
    dustbin: f32,
    cache: Mutex<EmbeddingCache>,
}

impl DeepMatcher {
    fn new(
        method: Method,
        net: Network,
        arch: Architecture,
        samples: usize,
        threshold: Option<(UncertaintyKind, f64)>,
        seed: u64,
    ) -> Self {
        let net = net.valid();
        let dustbin = net.dustbin_score();
        Self {
            method,
            arch,
            net,
            device: Device::flex(),
            samples,
            threshold,
            seed,
            share_embeddings: true,
            cache: Mutex::default(),
            cell_weights: Mutex::default(),
            dustbin,
        }
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
    fn embedding(&self, view: &MatchView) -> Arc<Embedded> {
        let input = graph_input(view.detections, view.graph, &view.pose_reported);
        let key = embedding_key(&input, self.samples);
        if self.share_embeddings
            && let Ok(mut cache) = self.cache.lock()
            && let Some(e) = cache.entries.get(&key).cloned()
        {
            cache.hits += 1;
            return e;
        }
        let graph = GraphTensors::used_cells(&input, &self.device);
        let graph = match self.cell_weights(&graph) {
            Some(weights) => graph.with_weights(weights),
            None => graph,
        };
        let mut stream = rng::stream(self.seed, Purpose::EmbeddingDropout, &[key]);
        let (m1, m2) =
            draw_embedding_masks(&mut stream, &self.arch, self.samples, input.n, &self.device);
        let h = self.net.embed(&graph, m1, m2);
        let e = Arc::new(Embedded { graph, h });
        if self.share_embeddings
            && let Ok(mut cache) = self.cache.lock()
        {
            if cache.entries.len() >= CACHE_CAPACITY {
                cache.entries.clear();
            }
            cache.entries.insert(key, Arc::clone(&e));
        }
        e
    }

    /// The spline layers' weights of `graph`'s kernel cells, kept per cell
    /// set (a scenario's graphs use a few dozen sets): selecting them anew
    /// for every graph cost as much as a tenth of inference. `None` for a
    /// set not kept (the layers then select them).
    fn cell_weights(&self, graph: &GraphTensors) -> Option<Arc<CellWeights>> {
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
        method: Method,
        weights: &[u8],
        samples: usize,
        threshold: Option<(UncertaintyKind, f64)>,
        seed: u64,
    ) -> Result<Self, String> {
        let (arch, _) = variant(method).ok_or("not a deep method")?;
        let net = model::from_bytes(&arch, weights, &Device::flex())?;
        Ok(Self::new(method, net, arch, samples, threshold, seed))
    }

    /// A deep method with freshly initialised weights (`init_seed`), as
    /// training starts from: for benchmarks, and for tests that must fail
    /// without training.
    pub fn untrained(
        method: Method,
        arch: Architecture,
        init_seed: u64,
        samples: usize,
        seed: u64,
    ) -> Self {
        let net = Network::new(&arch, Init::Seeded(init_seed), &Device::flex());
        Self::new(method, net, arch, samples, None, seed)
    }

    /// The weights as bytes (what a `.bpk` file holds).
    pub fn weights(&self) -> Result<Vec<u8>, String> {
        model::to_bytes(&self.net)
    }

    /// The `samples` MC-dropout assignments, each `(n1 + 1) x (n2 + 1)`
    /// row-major; both sides must be non-empty.
    pub fn samples(&self, first: &MatchView, second: &MatchView) -> Vec<Vec<f32>> {
        let (n1, n2) = (first.detections.len(), second.detections.len());
        let (e1, e2) = (self.embedding(first), self.embedding(second));
        let mut stream = rng::stream(self.seed, Purpose::Dropout, &[problem_key(first, second)]);
        let shape = [self.samples, n1, n2];
        let masks = draw_consensus_masks(
            &mut stream,
            &self.arch,
            shape,
            dropout_mask_16,
            &self.device,
        );
        let cost = Tensor::<3>::from_data(
            TensorData::new(features::position_cost(first, second), [1, n1, n2]),
            &self.device,
        );
        let scores = self
            .net
            .pair_scores((&e1.h, &e1.graph), (&e2.h, &e2.graph), masks, cost);
        let scores: Vec<f32> = scores.try_into_vec_as::<f32>().unwrap_or_default();
        let p = model::sinkhorn_probabilities(
            &scores,
            [self.samples, n1, n2],
            self.dustbin,
            self.arch.sinkhorn_iters,
        );
        p.chunks((n1 + 1) * (n2 + 1)).map(<[f32]>::to_vec).collect()
    }

    /// E[Y] and the per-pair uncertainties from `samples` MC-dropout passes.
    pub fn distribution(&self, first: &MatchView, second: &MatchView) -> MatchDistribution {
        let (n1, n2) = (first.detections.len(), second.detections.len());
        if n1 == 0 || n2 == 0 {
            // Everything goes to the dustbin.
            let mut mean = vec![0f32; (n1 + 1) * (n2 + 1)];
            for i in 0..n1 {
                mean[i * (n2 + 1) + n2] = 1.0;
            }
            for j in 0..n2 {
                mean[n1 * (n2 + 1) + j] = 1.0;
            }
            return MatchDistribution {
                n1,
                n2,
                mean,
                aleatoric: vec![0.0; n1 * n2],
            };
        }
        let samples = self.samples(first, second);
        MatchDistribution::from_samples(n1, n2, &samples)
    }
}

impl Matcher for DeepMatcher {
    fn method(&self) -> Method {
        self.method
    }

    fn identify(&self, first: &MatchView, second: &MatchView) -> Identification {
        let distribution = self.distribution(first, second);
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
    use crate::matching::testkit::{self, Side};
    use crate::traffic::ObjectClass;
    use rand::SeedableRng;

    #[test]
    fn sinkhorn_rows_and_columns_sum_to_one_with_dustbins() {
        let device = Device::flex();
        let mut r = ChaCha8Rng::seed_from_u64(1);
        let scores: Vec<f32> = (0..48).map(|_| r.random_range(-6.0..6.0)).collect();
        let scores = Tensor::<3>::from_data(TensorData::new(scores, [2, 4, 6]), &device);
        let p = model::log_sinkhorn(scores, Tensor::ones([1], &device), 50).exp();
        let v: Vec<f32> = p.try_into_vec_as::<f32>().unwrap();
        for t in 0..2 {
            let at = |i: usize, j: usize| v[t * 35 + i * 7 + j];
            for i in 0..4 {
                let row: f32 = (0..7).map(|j| at(i, j)).sum();
                assert!((row - 1.0).abs() < 1e-3, "row {i}: {row}");
            }
            for j in 0..6 {
                let col: f32 = (0..5).map(|i| at(i, j)).sum();
                assert!((col - 1.0).abs() < 1e-3, "col {j}: {col}");
            }
        }
    }

    fn untrained(arch: Architecture, seed: u64) -> DeepMatcher {
        DeepMatcher::untrained(Method::Ours, arch, seed, 20, seed)
    }

    /// The MC samples of the moved-copy scene.
    fn mc_samples(m: &DeepMatcher) -> Vec<Vec<f32>> {
        let (a, b) = testkit::moved_copy();
        let samples = m.samples(&a.view(), &b.view());
        assert_eq!(samples.len(), 20);
        samples
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
        let v = max_variance(&mc_samples(&untrained(Architecture::default(), 3)));
        assert!(
            v > 1e-4,
            "p > 0 must give varying samples (max variance {v})"
        );
        let without = Architecture {
            dropout_conv: 0.0,
            dropout_phi: 0.0,
            ..Architecture::default()
        };
        let samples = mc_samples(&untrained(without, 3));
        assert!(
            samples.iter().all(|s| *s == samples[0]),
            "p = 0 must give identical samples"
        );
    }

    #[test]
    fn dropout_masks_have_the_right_rate_and_scale() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let m = dropout_mask(&mut rng, 100_000, 0.4);
        let kept = m.iter().filter(|&&v| v > 0.0).count() as f64 / m.len() as f64;
        assert!((kept - 0.6).abs() < 0.01, "{kept}");
        assert!(m.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.6).abs() < 1e-6));
        assert!(dropout_mask(&mut rng, 10, 0.0).iter().all(|&v| v == 1.0));
        let m = dropout_mask_16(&mut rng, 100_001, 0.2);
        let kept = m.iter().filter(|&&v| v > 0.0).count() as f64 / m.len() as f64;
        assert!((kept - 0.8).abs() < 0.01, "{kept}");
        assert!(m.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.8).abs() < 1e-6));
        assert!(dropout_mask_16(&mut rng, 7, 0.0).iter().all(|&v| v == 1.0));
    }

    #[test]
    fn weights_as_bytes_give_identical_outputs() {
        let m = untrained(Architecture::default(), 11);
        let loaded =
            DeepMatcher::from_weights(Method::Ours, &m.weights().unwrap(), 20, None, 11).unwrap();
        let (a, b) = testkit::moved_copy();
        assert_eq!(
            m.distribution(&a.view(), &b.view()),
            loaded.distribution(&a.view(), &b.view())
        );
        // gcn-gm has no consensus: the weights of `ours` do not fit it.
        let e = DeepMatcher::from_weights(Method::GcnGm, &m.weights().unwrap(), 20, None, 1);
        assert!(e.is_err());
    }

    /// The shipped weights of `method` with their default threshold.
    fn shipped(method: Method) -> DeepMatcher {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("models")
            .join(format!("{}.bpk", method.as_str()));
        let bytes = std::fs::read(path).expect("shipped weights");
        DeepMatcher::from_weights(method, &bytes, 20, Some((UncertaintyKind::Total, 0.7)), 1)
            .unwrap()
    }

    use crate::matching::testkit::GPS;

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
                .map(|&(i, j)| m.samples(&sides[i].view(), &sides[j].view()))
                .collect()
        };
        let shared = shipped(Method::Ours);
        let per_pair = shipped(Method::Ours).without_shared_embeddings();
        let (a, b) = (run(&shared), run(&per_pair));
        assert_eq!(a, b);
        assert_eq!(shared.shared_embeddings(), 3);
        assert_eq!(per_pair.shared_embeddings(), 0);
        // The MC samples differ from each other (dropout is on).
        assert_ne!(a[0][0], a[0][1]);
    }

    /// The shipped model matches a scene seen from across the junction when
    /// the second vehicle's GPS is 2 m off along the queue (about what two
    /// 1.2 m receivers give together): most objects, no wrong pair (the
    /// family-trained weights leave two of the nine queued cars unpaired
    /// rather than risk a shifted pair). An untrained network of the same
    /// architecture finds few of them, so this tests the training, not the
    /// GPS prior.
    #[test]
    fn shipped_model_matches_a_scene_under_gps_error_and_untrained_does_not() {
        let scene = queue_scene();
        let a = Side::of(testkit::POSE_A, &scene, &(0..9).collect::<Vec<_>>(), GPS);
        let mut b = Side::of(
            (50.0, -10.0, 2.6),
            &scene,
            &[8, 3, 0, 5, 7, 1, 6, 4, 2],
            GPS,
        );
        b.pose = crate::geometry::Pose2::new(b.pose.position_m() + Vec2::new(2.0, 0.0), 2.6);
        let score = |m: &DeepMatcher| {
            let found = m.identify(&a.view(), &b.view()).matches;
            (testkit::correct(&a, &b, &found), found.len())
        };
        let (correct, found) = score(&shipped(Method::Ours));
        assert_eq!(correct, found, "a wrong pair");
        assert!(correct >= 7, "only {correct} of 9 paired");
        let untrained = untrained(Architecture::default(), 7);
        assert!(score(&untrained).0 < 5, "{:?}", score(&untrained));
    }

    /// Partial overlap: the second vehicle shares four objects with the
    /// first and sees four others; the shipped model pairs exactly the
    /// shared ones ("no match" for the rest); untrained pairs none.
    #[test]
    fn shipped_model_pairs_the_shared_objects_and_no_others() {
        let mut world = testkit::world_objects();
        let only_b = [
            (Vec2::new(60.0, 40.0), ObjectClass::Car, [0.95; 3]),
            (Vec2::new(52.0, 48.0), ObjectClass::Van, [0.1; 3]),
            (Vec2::new(66.0, 52.0), ObjectClass::Car, [0.7, 0.1, 0.1]),
            (Vec2::new(58.0, 60.0), ObjectClass::Pedestrian, [0.2; 3]),
        ];
        world.extend(only_b);
        let a = Side::of(testkit::POSE_A, &world, &[0, 1, 2, 3, 4, 5, 6, 7], GPS);
        let b = Side::of(testkit::POSE_B, &world, &[9, 2, 10, 5, 8, 3, 11, 6], GPS);
        let found = shipped(Method::Ours).identify(&a.view(), &b.view()).matches;
        assert_eq!((testkit::correct(&a, &b, &found), found.len()), (4, 4));
        let none = untrained(Architecture::default(), 7)
            .identify(&a.view(), &b.view())
            .matches;
        assert!(testkit::correct(&a, &b, &none) < 4);
    }

    #[test]
    fn empty_sides_send_everything_to_the_dustbin() {
        let m = untrained(Architecture::default(), 1);
        let (a, b) = testkit::moved_copy();
        let empty = Side::new(vec![], vec![], b.pose, testkit::EXACT);
        let id = m.identify(&a.view(), &empty.view());
        assert!(id.matches.is_empty());
        let d = id.distribution.unwrap();
        assert!((0..a.detections.len()).all(|i| d.p(i, 0) == 1.0));
    }
}
