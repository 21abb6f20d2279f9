//! `ours`: the project's network, which sees the reported poses (as the
//! `+gps` ablations do). Each pair is scored by the shared pair
//! log-likelihood ([`crate::matching::likelihood`]), scaled, plus a
//! gated residual the network learns; an untrained network decides
//! exactly as GPS+appearance Hungarian does.
//!
//! Inference in plain Rust (training's modules, the reference the tests
//! hold this to, are `super::train`'s):
//! - `first_layer`, `second_layer` and `pair`: the spline layers and the
//!   pair part, under Eq. 8's shared masks computing only what the masks
//!   keep;
//! - here: the network's parameters ([`spec`]) and [`Ours`], the network
//!   as the MC shell ([`super::mc`]) runs it.

pub(crate) mod first_layer;
mod pair;
mod second_layer;

use self::first_layer::FirstLayer;
pub(crate) use self::pair::{Combination, PairResidual};
use self::pair::{PairWeights, PlainPair};
pub(crate) use self::second_layer::PlainSpline;
use self::second_layer::SharedMaskConv;
use super::arch::{Architecture, MaskScope, likelihood_terms};
use super::cost::{GraphShape, inference_macs, plain_embedding_macs};
use super::features::{DUST_FEATURES, PAIR_FEATURES, PairInput, pair_input};
use super::graph::{KERNEL_2D, OffsetGraph};
use super::kernels::sinkhorn::sinkhorn_probabilities;
use super::mc::draws::{dropout_mask_16, indicator_values};
use super::mc::{Inference, Network, Samples, Side};
use super::params::{self, ParamSpec, Params};
use crate::fusion::PoseEstimate;
use crate::matching::MatchView;
use crate::matching::likelihood::LikelihoodTerms;
use crate::rng::{self, Purpose};

/// The dustbin score before training: a pair is more likely matched than
/// not about where its log-likelihood passes this (a squared Mahalanobis
/// distance of 6 at identical looks).
const INITIAL_DUSTBIN: f32 = -3.0;

/// The parameters of `ours`'s network of `arch`, as its weights file
/// names them: the two spline layers over 2-D offsets, the consensus
/// (its spline layer and MLP) when it has one, the pair and "no match"
/// MLPs, and the scalars that combine them with the likelihood (scale 1,
/// gates 0: an untrained network scores pairs as the likelihood does).
pub(crate) fn spec(arch: &Architecture) -> Vec<ParamSpec> {
    let (r, h) = (arch.consensus_dim, arch.pair_hidden);
    let mut out = params::spline_conv("conv1", "", [arch.node_features(), arch.hidden], KERNEL_2D);
    out.extend(params::spline_conv(
        "conv2",
        "",
        [arch.hidden, arch.out],
        KERNEL_2D,
    ));
    if arch.has_consensus() {
        out.extend(params::spline_conv("consensus_conv", "", [r, r], KERNEL_2D));
        out.extend(params::linear("phi_in", "", [r, r]));
        out.extend(params::linear("phi_out", "", [r, 1]));
    }
    out.extend(params::linear("pair_in", "", [PAIR_FEATURES, h]));
    out.extend(params::linear("pair_out", "", [h, 1]));
    out.extend(params::linear("dust_in", "", [DUST_FEATURES, h]));
    out.extend(params::linear("dust_out", "", [h, 1]));
    out.extend([
        params::scalar("log_scale", "", 0.0),
        params::scalar("gate", "", 0.0),
        params::scalar("dustbin", "", INITIAL_DUSTBIN),
        params::scalar("dust_gate", "", 0.0),
    ]);
    out
}

/// The scalars that combine the likelihood with what the network learned.
pub(crate) fn combination(p: &Params) -> Combination {
    Combination {
        scale: p.scalar("log_scale").exp(),
        gate: p.scalar("gate"),
        dustbin: p.scalar("dustbin"),
        dust_gate: p.scalar("dust_gate"),
    }
}

/// The stream name of the masks every graph and pair shares
/// ([`MaskScope::Shared`]).
pub(crate) const SHARED_MASKS_KEY: u64 = 0x5a4e_d0e8_0000_0008;

/// A stable key of a pair's detections: its consensus draws depend only
/// on the pair, not on what was matched before.
pub(crate) fn problem_key(first: &MatchView, second: &MatchView) -> u64 {
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

/// Everything one vehicle's embedding depends on: its network input
/// (node features and edges with their B-spline bases, which carry the
/// reported heading) and the number of samples.
pub(crate) fn embedding_key(input: &OffsetGraph, samples: usize) -> u64 {
    let mut parts = vec![input.n as u64, samples as u64, input.edge_count() as u64];
    parts.extend(input.node_features.iter().map(|v| u64::from(v.to_bits())));
    parts.extend(input.src.iter().chain(&input.dst).map(|&v| v as u64));
    let bases: Vec<_> = (0..input.edge_count())
        .flat_map(|e| input.basis(e))
        .collect();
    parts.extend(bases.iter().map(|&(k, _)| k as u64));
    parts.extend(bases.iter().map(|&(_, w)| u64::from(w.to_bits())));
    rng::key(&parts)
}

/// One vehicle's embedding: the node embeddings of every MC-dropout
/// sample, `[T, N, out]` row-major, and its shape for the arithmetic
/// counts.
pub(crate) struct Embedded {
    pub(crate) h: Vec<f32>,
    pub(crate) shape: GraphShape,
}

/// The second spline layer under the run's masks.
enum SecondLayer {
    /// One mask per sample for every node (Eq. 8).
    Shared(SharedMaskConv),
    /// Masks per node, drawn per graph.
    PerNode(PlainSpline),
}

/// `ours`'s network as the MC shell runs it: the first spline layer (no
/// mask), the second (under shared masks with the weights they keep
/// gathered once, else per node) and the pair part, in plain Rust.
pub(crate) struct Ours {
    arch: Architecture,
    run: Inference,
    /// The shared likelihood's terms and gates.
    terms: LikelihoodTerms,
    /// The network's scalar parameters.
    combination: Combination,
    first_layer: FirstLayer,
    second_layer: SecondLayer,
    pair: PlainPair,
}

impl Ours {
    /// The network of `arch` with the parameters `p`, run as `run` says;
    /// its dropout rates at inference are `run.dropout`'s when that is
    /// set.
    pub(crate) fn new(p: &Params, arch: Architecture, run: Inference) -> Self {
        let arch = at_inference(arch, &run);
        let layer = |name: &str| PlainSpline::of(p, name);
        let consensus = arch.has_consensus().then(|| {
            (
                layer("consensus_conv"),
                p.linear("phi_in"),
                p.linear("phi_out"),
            )
        });
        let pair_weights = PairWeights {
            pair_in: p.linear("pair_in"),
            pair_out: p.linear("pair_out"),
            dust_in: p.linear("dust_in"),
            dust_out: p.linear("dust_out"),
            consensus,
            combination: combination(p),
        };
        let first_layer = FirstLayer::new(layer("conv1"));
        let (second_layer, pair) = if run.masks == MaskScope::PerNode {
            (
                SecondLayer::PerNode(layer("conv2")),
                PlainPair::new(pair_weights, run.samples, None),
            )
        } else {
            // Shared masks are the same for every graph and pair, so the
            // weights they keep are gathered once.
            let mut stream = rng::stream(run.seed, Purpose::EmbeddingDropout, &[SHARED_MASKS_KEY]);
            let q = arch.dropout_conv;
            let m1 = dropout_mask_16(&mut stream, run.samples * arch.hidden, q);
            let m2 = dropout_mask_16(&mut stream, run.samples * arch.out, q);
            // The consensus MLP's masks, drawn as the pair's are.
            let mut shared = rng::stream(run.seed, Purpose::Dropout, &[SHARED_MASKS_KEY]);
            let r = arch.consensus_dim;
            let phi = dropout_mask_16(&mut shared, run.samples * r, arch.dropout_phi);
            (
                SecondLayer::Shared(SharedMaskConv::new(&layer("conv2"), &m1, &m2)),
                PlainPair::new(pair_weights, run.samples, Some(&phi)),
            )
        };
        Self {
            terms: likelihood_terms(&arch, run.gate_chi2),
            arch,
            run,
            combination: combination(p),
            first_layer,
            second_layer,
            pair,
        }
    }

    /// `ours`'s network of `arch` with trained weights (the bytes of its
    /// `.bpk` file); an error says why they do not fit.
    pub(crate) fn from_weights(
        arch: Architecture,
        weights: &[u8],
        run: Inference,
    ) -> Result<Self, String> {
        Ok(Self::new(
            &Params::from_bytes(weights, &spec(&arch))?,
            arch,
            run,
        ))
    }

    /// Freshly initialised weights (`init_seed`), as training starts from.
    pub(crate) fn untrained(arch: Architecture, init_seed: u64, run: Inference) -> Self {
        Self::new(&Params::seeded(&spec(&arch), init_seed), arch, run)
    }
}

/// `arch` with `run`'s dropout rates, when it sets them.
pub(crate) fn at_inference(mut arch: Architecture, run: &Inference) -> Architecture {
    if let Some(p) = run.dropout {
        (arch.dropout_conv, arch.dropout_phi) = (p, p);
    }
    arch
}

impl Network for Ours {
    type Input = OffsetGraph;
    type Embedding = Embedded;

    fn input(&self, view: &MatchView) -> OffsetGraph {
        OffsetGraph::offsets(
            view.detections,
            view.graph,
            &view.pose_reported,
            self.arch.appearance_width(),
        )
    }

    fn embedding_key(&self, input: &OffsetGraph) -> u64 {
        embedding_key(input, self.run.samples)
    }

    fn keeps_embeddings(&self) -> bool {
        true
    }

    fn uses_positions(&self) -> bool {
        self.arch.positions
    }

    /// The graphs go through the second layer together, so that each
    /// sample's weights are read once for all of them.
    fn embed(&self, inputs: &[(&OffsetGraph, u64)]) -> (Vec<Embedded>, u64) {
        let t = self.run.samples;
        let shapes: Vec<GraphShape> = inputs
            .iter()
            .map(|(i, _)| GraphShape::of_input(i))
            .collect();
        let firsts: Vec<Vec<f32>> = inputs
            .iter()
            .map(|(i, _)| self.first_layer.forward(i))
            .collect();
        let (hs, macs): (Vec<Vec<f32>>, u64) = match &self.second_layer {
            SecondLayer::Shared(layer) => {
                let layers: Vec<(&[f32], &OffsetGraph)> = firsts
                    .iter()
                    .zip(inputs)
                    .map(|(h, (i, _))| (h.as_slice(), *i))
                    .collect();
                let macs = shapes
                    .iter()
                    .map(|&s| plain_embedding_macs(&self.arch, s, t) as u64)
                    .sum();
                (layer.forward_many(&layers), macs)
            }
            SecondLayer::PerNode(layer) => {
                let hs = firsts
                    .iter()
                    .zip(inputs)
                    .map(|(h, &(i, key))| {
                        let [m1, m2] = embedding_masks(&self.arch, &self.run, i.n, key);
                        layer.forward_per_node(i, h, [&m1, &m2])
                    })
                    .collect();
                let macs = shapes
                    .iter()
                    .map(|&s| inference_macs(&self.arch, s, s, t).embeddings[0])
                    .sum();
                (hs, macs)
            }
        };
        let made = hs
            .into_iter()
            .zip(shapes)
            .map(|(h, shape)| Embedded { h, shape })
            .collect();
        (made, macs)
    }

    fn pose_free_key(&self, _inputs: [&OffsetGraph; 2]) -> Option<u64> {
        None
    }

    fn samples(&self, sides: [Side<'_, Self>; 2], relative: &PoseEstimate) -> (Samples, u64) {
        let [s1, s2] = &sides;
        let (n1, n2, t) = (s1.input.n, s2.input.n, self.run.samples);
        let (Some(e1), Some(e2)) = (s1.embedding, s2.embedding) else {
            unreachable!("ours keeps every embedding");
        };
        let macs = inference_macs(&self.arch, e1.shape, e2.shape, t).shared_pair();
        let input = pair_input(s1.view, s2.view, relative, &self.terms);
        let [indicators, phi] = pair_draws(&self.arch, &self.run, s1.view, s2.view);
        let (h1, h2) = ((&e1.h[..], s1.input), (&e2.h[..], s2.input));
        let out = self.pair.forward(h1, h2, &input, [&indicators, &phi]);
        let c = (self.combination, self.arch.sinkhorn_iters);
        (combine(c, t, &input, &out, [n1, n2]), macs)
    }
}

/// The conv dropout masks of one vehicle's embedding under masks per
/// node (`[T, n, hidden]`, `[T, n, out]`), from the stream of its
/// embedding `key`, as training draws them.
fn embedding_masks(arch: &Architecture, run: &Inference, n: usize, key: u64) -> [Vec<f32>; 2] {
    let mut stream = rng::stream(run.seed, Purpose::EmbeddingDropout, &[key]);
    let (t, p) = (run.samples, arch.dropout_conv);
    let m1 = dropout_mask_16(&mut stream, t * n * arch.hidden, p);
    let m2 = dropout_mask_16(&mut stream, t * n * arch.out, p);
    [m1, m2]
}

/// A pair's draws from its own stream: under masks per node the
/// consensus MLP's masks (`[T, n1, n2, R]`, when the network has
/// consensus), then the random node indicators (`[n1, R]`; under shared
/// masks, the first normals of the stream).
fn pair_draws(
    arch: &Architecture,
    run: &Inference,
    first: &MatchView,
    second: &MatchView,
) -> [Vec<f32>; 2] {
    let key = problem_key(first, second);
    let mut stream = rng::stream(run.seed, Purpose::Dropout, &[key]);
    let (n1, n2, t) = (first.detections.len(), second.detections.len(), run.samples);
    let r = arch.consensus_dim;
    let phi = if run.masks == MaskScope::PerNode && arch.has_consensus() {
        dropout_mask_16(&mut stream, t * n1 * n2 * r, arch.dropout_phi)
    } else {
        Vec::new()
    };
    [indicator_values(&mut stream, n1 * r), phi]
}

/// The samples' scores (the shared likelihood, scaled, plus the gated
/// residual), their mean, and Sinkhorn's soft assignments with the
/// nodes' "no match" scores: `(c, iters)` the network's scalars and its
/// Sinkhorn iterations, `t` the samples.
pub(crate) fn combine(
    (c, iters): (Combination, usize),
    t: usize,
    input: &PairInput,
    out: &PairResidual,
    [n1, n2]: [usize; 2],
) -> Samples {
    let residual = &out.residual;
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
    let dust = out.dust.each_ref().map(|d| {
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
        iters,
    );
    Samples {
        assignments: p.chunks((n1 + 1) * (n2 + 1)).map(<[f32]>::to_vec).collect(),
        scores,
        mean_scores: Some(mean_scores),
    }
}
