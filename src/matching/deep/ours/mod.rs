//! `ours`: the project's network, which sees the reported poses (as the
//! `+gps` ablations do). Each pair is scored by the shared pair
//! log-likelihood ([`crate::matching::likelihood`]), scaled, plus a
//! gated residual the network learns; an untrained network decides
//! exactly as GPS+appearance Hungarian does.
//!
//! - `model`: [`OursNet`] (burn), the embeddings and pair scores as
//!   training runs them; `spline`: graphs as tensors, the SplineCNN layer.
//! - `second_layer` and `pair`: the second spline layer and the pair part
//!   in plain Rust under Eq. 8's shared masks, computing only what the
//!   masks keep.
//! - here: [`Ours`], the network as the MC shell ([`super::mc`]) runs it.

mod first_layer;
mod model;
mod pair;
mod second_layer;
mod spline;
#[cfg(test)]
mod tests;

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use burn::prelude::*;

use self::first_layer::FirstLayer;
pub(crate) use self::model::{OursNet, PairTensors};
use self::pair::{PairResidual, PlainPair};
use self::second_layer::{PlainSpline, SharedMaskConv};
use self::spline::CellWeights;
pub(crate) use self::spline::GraphBatch;
use super::arch::{Architecture, MaskScope, likelihood_terms};
use super::backend::{device, values};
use super::cost::{GraphShape, inference_macs, plain_embedding_macs};
use super::features::{GraphInput, PairInput, graph_input, pair_input};
use super::kernels::sinkhorn::sinkhorn_probabilities;
use super::mc::draws::{DrawStore, dropout_mask_16, indicator_values};
use super::mc::{Inference, Network, Path, Samples, Side, TensorRead};
use super::train::init::Init;
use super::train::masks::{
    MaskDraw, PairMasks, draw_embedding_masks, draw_pair_masks, draw_phi_mask,
};
use super::train::weights::from_bytes;
use crate::fusion::PoseEstimate;
use crate::matching::MatchView;
use crate::matching::likelihood::LikelihoodTerms;
use crate::rng::{self, Purpose};

/// How many kernel-cell sets' weights are kept (each up to 0.8 MB; a
/// scenario's few most common sets cover most graphs).
const CELL_SETS_KEPT: usize = 16;

/// The stream name of the masks every graph and pair shares
/// ([`MaskScope::Shared`]).
const SHARED_MASKS_KEY: u64 = 0x5a4e_d0e8_0000_0008;

/// A stable key of a pair's detections: its consensus draws depend only
/// on the pair, not on what was matched before.
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

/// One vehicle's embedding: the node embeddings of every MC-dropout
/// sample, `[T, N, out]` row-major, its graph as tensors when the tensor
/// path made it, and its shape for the arithmetic counts.
pub(crate) struct Embedded {
    graph: Option<GraphBatch>,
    pub(crate) h: Vec<f32>,
    shape: GraphShape,
}

/// The plain path: the first spline layer (no mask), the second (under
/// shared masks with the weights they keep gathered once, else per node)
/// and the pair part.
struct PlainPath {
    first_layer: FirstLayer,
    second_layer: SecondLayer,
    pair: PlainPair,
}

/// The second spline layer under the run's masks.
enum SecondLayer {
    /// One mask per sample for every node (Eq. 8).
    Shared(SharedMaskConv),
    /// Masks per node, drawn per graph.
    PerNode(PlainSpline),
}

/// `ours`'s network as the MC shell runs it.
pub(crate) struct Ours {
    arch: Architecture,
    net: OursNet,
    device: Device,
    run: Inference,
    /// The shared likelihood's terms and gates.
    terms: LikelihoodTerms,
    /// The network's scalar parameters, read once.
    combination: model::Combination,
    /// The network without tensors, under the run's masks.
    plain: PlainPath,
    /// The spline layers' weights per set of kernel cells (bit mask).
    cell_weights: Mutex<HashMap<u32, Arc<CellWeights>>>,
}

impl Ours {
    /// The network `net` of `arch` run as `run` says; its dropout rates
    /// at inference are `run.dropout`'s when that is set.
    pub(crate) fn new(
        net: OursNet,
        mut arch: Architecture,
        run: Inference,
    ) -> Result<Self, TensorRead> {
        if let Some(p) = run.dropout {
            (arch.dropout_conv, arch.dropout_phi) = (p, p);
        }
        let net = net.valid();
        let combination = net.combination();
        let plain = plain_path(&net, &arch, &run)?;
        Ok(Self {
            terms: likelihood_terms(&arch, run.gate_chi2),
            arch,
            net,
            device: device(),
            run,
            combination,
            plain,
            cell_weights: Mutex::default(),
        })
    }

    /// `ours`'s network of `arch` with trained weights (the bytes of its
    /// `.bpk` file); an error says why they do not fit.
    pub(crate) fn from_weights(
        arch: Architecture,
        weights: &[u8],
        run: Inference,
    ) -> Result<Self, String> {
        Self::new(from_bytes(&arch, weights, &device())?, arch, run)
    }

    /// Freshly initialised weights (`init_seed`), as training starts from.
    pub(crate) fn untrained(arch: Architecture, init_seed: u64, run: Inference) -> Self {
        let net = OursNet::new(&arch, Init::Seeded(init_seed), &device());
        Self::new(net, arch, run).expect("a fresh network's values are f32")
    }

    /// A graph as tensors with its kept cell weights.
    fn graph(&self, input: &GraphInput) -> GraphBatch {
        let graph = GraphBatch::used_cells(input, &self.device);
        match self.kept_cell_weights(&graph) {
            Some(weights) => graph.with_weights(weights),
            None => graph,
        }
    }

    /// The spline layers' weights of `graph`'s kernel cells, kept per cell
    /// set (a scenario's graphs use a few dozen sets): selecting them anew
    /// for every graph cost as much as a tenth of inference. `None` for a
    /// set not kept (the layers then select them).
    fn kept_cell_weights(&self, graph: &GraphBatch) -> Option<Arc<CellWeights>> {
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

    /// The embedding through the tensors with the masks of its stream.
    fn tensor_embedding(&self, graph: &GraphBatch, input: &GraphInput, key: u64) -> Tensor<4> {
        // Shared masks: one stream for every graph, so that sample t is
        // one draw of the weights wherever it is used.
        let stream_key = match self.run.masks {
            MaskScope::PerNode => key,
            MaskScope::Shared => SHARED_MASKS_KEY,
        };
        let mut stream = rng::stream(self.run.seed, Purpose::EmbeddingDropout, &[stream_key]);
        let (m1, m2) = draw_embedding_masks(
            &mut stream,
            &self.arch,
            [self.run.samples, input.n],
            self.run.masks,
            &self.device,
        );
        self.net.embed(graph, m1, m2)
    }

    /// The consensus masks of one pair: all from the pair's own stream
    /// (per node), or its random indicators from it and the consensus
    /// MLP's dropout mask of each sample, the same for every pair
    /// (shared).
    fn pair_masks(&self, first: &MatchView, second: &MatchView) -> PairMasks {
        let (n1, n2, t) = (
            first.detections.len(),
            second.detections.len(),
            self.run.samples,
        );
        let seed = self.run.seed;
        let mut stream = rng::stream(seed, Purpose::Dropout, &[problem_key(first, second)]);
        let shape = [1, t, n1, n2];
        match self.run.masks {
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
                    let mut shared = rng::stream(seed, Purpose::Dropout, &[SHARED_MASKS_KEY]);
                    let scope = self.run.masks;
                    let dims = [t, n1, n2];
                    m.phi = draw_phi_mask(&mut shared, &self.arch, dims, scope, &self.device);
                }
                m
            }
        }
    }

    /// The pair part through the tensors (the reference of the plain
    /// one, and what per-node masks use).
    fn tensor_pair<'a>(
        &self,
        [s1, s2]: [&Side<'_, Self>; 2],
        [e1, e2]: [&'a Embedded; 2],
        input: &PairInput,
    ) -> Result<PairResidual, TensorRead> {
        let (n1, n2) = (input.n1, input.n2);
        let tensors = PairTensors::new(&[input], [n1, n2], &self.device);
        let masks = self.pair_masks(s1.view, s2.view);
        let h = |e: &Embedded, n: usize| {
            let shape = [1, self.run.samples, n, self.arch.out];
            Tensor::<4>::from_data(TensorData::new(e.h.clone(), shape), &self.device)
        };
        let (h1, h2) = (h(e1, s1.input.n), h(e2, s2.input.n));
        // The tensor path made both embeddings, with their graphs.
        let graph = |e: &'a Embedded| e.graph.as_ref().ok_or("an embedding without its graph");
        let (g1, g2) = (graph(e1)?, graph(e2)?);
        let out = self.net.pair((&h1, g1), (&h2, g2), &tensors, masks);
        Ok(PairResidual {
            residual: values(out.residual)?,
            dust: match out.dust {
                [d1, d2] => [values(d1)?, values(d2)?],
            },
        })
    }

    /// The weights as bytes (what a `.bpk` file holds).
    #[cfg(test)]
    pub(crate) fn weights(&self) -> Result<Vec<u8>, String> {
        super::train::weights::to_bytes(&self.net)
    }
}

/// The plain path of `net` under `run`'s masks: shared masks are the
/// same for every graph and pair, so the weights they keep are gathered
/// once.
fn plain_path(
    net: &OursNet,
    arch: &Architecture,
    run: &Inference,
) -> Result<PlainPath, TensorRead> {
    let first_layer = FirstLayer::new(net.first_layer_weights()?);
    if run.masks == MaskScope::PerNode {
        return Ok(PlainPath {
            first_layer,
            second_layer: SecondLayer::PerNode(net.second_layer()?),
            pair: PlainPair::new(net.pair_weights()?, run.samples, None),
        });
    }
    let mut stream = rng::stream(run.seed, Purpose::EmbeddingDropout, &[SHARED_MASKS_KEY]);
    let p = arch.dropout_conv;
    let m1 = dropout_mask_16(&mut stream, run.samples * arch.hidden, p);
    let m2 = dropout_mask_16(&mut stream, run.samples * arch.out, p);
    // The consensus MLP's masks, drawn as `pair_masks` draws them.
    let mut shared = rng::stream(run.seed, Purpose::Dropout, &[SHARED_MASKS_KEY]);
    let r = arch.consensus_dim;
    let phi = dropout_mask_16(&mut shared, run.samples * r, arch.dropout_phi);
    Ok(PlainPath {
        first_layer,
        second_layer: SecondLayer::Shared(SharedMaskConv::new(&net.second_layer()?, &m1, &m2)),
        pair: PlainPair::new(net.pair_weights()?, run.samples, Some(&phi)),
    })
}

impl Network for Ours {
    type Input = GraphInput;
    type Embedding = Embedded;

    fn input(&self, view: &MatchView) -> GraphInput {
        graph_input(
            view.detections,
            view.graph,
            &view.pose_reported,
            self.arch.appearance_width(),
        )
    }

    /// Everything one vehicle's embedding depends on: its network input
    /// (node features and edges with their B-spline bases, which carry
    /// the reported heading) and the number of samples.
    fn embedding_key(&self, input: &GraphInput) -> u64 {
        let mut parts = vec![
            input.n as u64,
            self.run.samples as u64,
            input.edge_count() as u64,
        ];
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

    fn keeps_embeddings(&self, _path: Path) -> bool {
        true
    }

    fn uses_positions(&self) -> bool {
        self.arch.positions
    }

    /// On the plain path the graphs go through the second layer together,
    /// so that each sample's weights are read once for all of them.
    fn embed(
        &self,
        inputs: &[(&GraphInput, u64)],
        path: Path,
    ) -> Result<(Vec<Embedded>, u64), TensorRead> {
        let shapes: Vec<GraphShape> = inputs
            .iter()
            .map(|(i, _)| GraphShape::of_input(i))
            .collect();
        let t = self.run.samples;
        let shared = match (path, &self.plain.second_layer) {
            (Path::Plain, SecondLayer::Shared(layer)) => Some(layer),
            _ => None,
        };
        let macs = |&s: &GraphShape| match shared {
            Some(_) => plain_embedding_macs(&self.arch, s, t) as u64,
            None => inference_macs(&self.arch, s, s, t).embeddings[0],
        };
        let macs = shapes.iter().map(macs).sum();
        let (graphs, hs): (Vec<Option<GraphBatch>>, Vec<Vec<f32>>) = if path == Path::Plain {
            let firsts: Vec<Vec<f32>> = inputs
                .iter()
                .map(|(i, _)| self.plain.first_layer.forward(i))
                .collect();
            let hs = match &self.plain.second_layer {
                SecondLayer::Shared(layer) => {
                    let layers: Vec<(&[f32], &GraphInput)> = firsts
                        .iter()
                        .zip(inputs)
                        .map(|(h, (i, _))| (h.as_slice(), *i))
                        .collect();
                    layer.forward_many(&layers)
                }
                SecondLayer::PerNode(layer) => firsts
                    .iter()
                    .zip(inputs)
                    .map(|(h, &(i, key))| {
                        let [m1, m2] = self.embedding_masks(i.n, key);
                        layer.forward_per_node(i, h, [&m1, &m2])
                    })
                    .collect(),
            };
            (hs.iter().map(|_| None).collect(), hs)
        } else {
            let mut graphs = Vec::with_capacity(inputs.len());
            let mut hs = Vec::with_capacity(inputs.len());
            for &(i, key) in inputs {
                let g = self.graph(i);
                hs.push(values(self.tensor_embedding(&g, i, key))?);
                graphs.push(Some(g));
            }
            (graphs, hs)
        };
        let made = graphs
            .into_iter()
            .zip(hs)
            .zip(shapes)
            .map(|((graph, h), shape)| Embedded { graph, h, shape })
            .collect();
        Ok((made, macs))
    }

    fn pose_free_key(&self, _inputs: [&GraphInput; 2]) -> Option<u64> {
        None
    }

    fn samples(
        &self,
        sides: [Side<'_, Self>; 2],
        relative: &PoseEstimate,
        path: Path,
        _draws: &DrawStore,
    ) -> Result<(Samples, u64), TensorRead> {
        let [s1, s2] = &sides;
        let (n1, n2, t) = (s1.input.n, s2.input.n, self.run.samples);
        let (Some(e1), Some(e2)) = (s1.embedding, s2.embedding) else {
            return Err("ours pairs kept embeddings".into());
        };
        let macs = inference_macs(&self.arch, e1.shape, e2.shape, t).shared_pair();
        let input = pair_input(s1.view, s2.view, relative, &self.terms);
        let out = match path {
            Path::Plain => {
                let [indicators, phi] = self.pair_draws(s1.view, s2.view);
                let (h1, h2) = ((&e1.h[..], s1.input), (&e2.h[..], s2.input));
                self.plain.pair.forward(h1, h2, &input, [&indicators, &phi])
            }
            Path::Tensor => self.tensor_pair([s1, s2], [e1, e2], &input)?,
        };
        Ok((self.combine(&input, &out, [n1, n2]), macs))
    }
}

impl Ours {
    /// The conv dropout masks of one vehicle's embedding under masks per
    /// node (`[T, n, hidden]`, `[T, n, out]`), from the stream of its
    /// embedding `key`, as the tensor path draws them.
    fn embedding_masks(&self, n: usize, key: u64) -> [Vec<f32>; 2] {
        let mut stream = rng::stream(self.run.seed, Purpose::EmbeddingDropout, &[key]);
        let (t, p) = (self.run.samples, self.arch.dropout_conv);
        let m1 = dropout_mask_16(&mut stream, t * n * self.arch.hidden, p);
        let m2 = dropout_mask_16(&mut stream, t * n * self.arch.out, p);
        [m1, m2]
    }

    /// A pair's draws from its own stream, as the tensor path draws them:
    /// under masks per node the consensus MLP's masks (`[T, n1, n2, R]`,
    /// when the network has consensus), then the random node indicators
    /// (`[n1, R]`; under shared masks, the first normals of the stream).
    fn pair_draws(&self, first: &MatchView, second: &MatchView) -> [Vec<f32>; 2] {
        let key = problem_key(first, second);
        let mut stream = rng::stream(self.run.seed, Purpose::Dropout, &[key]);
        let (n1, n2, t) = (
            first.detections.len(),
            second.detections.len(),
            self.run.samples,
        );
        let r = self.arch.consensus_dim;
        let phi = if self.run.masks == MaskScope::PerNode && self.arch.consensus {
            dropout_mask_16(&mut stream, t * n1 * n2 * r, self.arch.dropout_phi)
        } else {
            Vec::new()
        };
        [indicator_values(&mut stream, n1 * r), phi]
    }

    /// The samples' scores (the shared likelihood, scaled, plus the gated
    /// residual), their mean, and Sinkhorn's soft assignments with the
    /// nodes' "no match" scores.
    fn combine(&self, input: &PairInput, out: &PairResidual, [n1, n2]: [usize; 2]) -> Samples {
        let t = self.run.samples;
        let residual = &out.residual;
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
            self.arch.sinkhorn_iters,
        );
        Samples {
            assignments: p.chunks((n1 + 1) * (n2 + 1)).map(<[f32]>::to_vec).collect(),
            scores,
            mean_scores: Some(mean_scores),
        }
    }
}
