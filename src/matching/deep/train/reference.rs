//! The tensor reference of inference (tests only): each network as
//! training runs it, through burn's modules, behind the same
//! [`Network`] trait as its plain inference, with the same draws from
//! the same streams. The path tests run one matcher of each and hold the
//! plain one to this one.

use burn::prelude::*;

use super::backend::{device, values};
use super::masks::{MaskDraw, PairMasks, draw_embedding_masks, draw_pair_masks, draw_phi_mask};
use super::ours_net::{OursNet, PairTensors};
use super::published_net::{
    Dropout, PublishedMasks, PublishedNet, draw_indicators, draw_psi1_masks,
};
use super::spline::GraphTensors;
use crate::fusion::PoseEstimate;
use crate::matching::MatchView;
use crate::matching::deep::arch::{Architecture, MaskScope, PublishedConfig, likelihood_terms};
use crate::matching::deep::cost::{GraphShape, inference_macs, published_macs};
use crate::matching::deep::features::{PairInput, pair_input};
use crate::matching::deep::graph::{LengthGraph, OffsetGraph};
use crate::matching::deep::mc::draws::dropout_mask_16;
use crate::matching::deep::mc::{Inference, Network, Samples, Side};
use crate::matching::deep::ours::{self, Combination, PairResidual};
use crate::matching::deep::published;
use crate::matching::likelihood::LikelihoodTerms;
use crate::rng::{self, Purpose};

/// `ours`'s network through the tensors.
pub(crate) struct TensorOurs {
    arch: Architecture,
    net: OursNet,
    device: Device,
    run: Inference,
    terms: LikelihoodTerms,
    combination: Combination,
}

/// One vehicle's embedding through the tensors, with its graph.
pub(crate) struct TensorEmbedded {
    graph: GraphTensors,
    h: Vec<f32>,
    shape: GraphShape,
}

impl TensorOurs {
    /// The network `net` of `arch`, run as `run` says.
    pub(crate) fn new(net: OursNet, arch: Architecture, run: Inference) -> Self {
        let arch = ours::at_inference(arch, &run);
        let net = net.valid();
        Self {
            terms: likelihood_terms(&arch, run.gate_chi2),
            combination: net.combination(),
            arch,
            net,
            device: device(),
            run,
        }
    }

    /// The network of `arch` with the weights `bytes`.
    pub(crate) fn from_weights(arch: Architecture, bytes: &[u8], run: Inference) -> Self {
        let net = super::weights::from_bytes(&arch, bytes, &device()).expect("weights");
        Self::new(net, arch, run)
    }

    /// A graph as tensors, with the kernel cells its edges use.
    fn graph(&self, input: &OffsetGraph) -> GraphTensors {
        GraphTensors::used_cells(input, &self.device)
    }

    /// The embedding with the masks of its stream.
    fn embedding(&self, graph: &GraphTensors, input: &OffsetGraph, key: u64) -> Tensor<4> {
        let stream_key = match self.run.masks {
            MaskScope::PerNode => key,
            MaskScope::Shared => ours::SHARED_MASKS_KEY,
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

    /// The consensus masks of one pair, drawn as the plain path draws
    /// them.
    fn pair_masks(&self, first: &MatchView, second: &MatchView) -> PairMasks {
        let (n1, n2, t) = (
            first.detections.len(),
            second.detections.len(),
            self.run.samples,
        );
        let seed = self.run.seed;
        let key = ours::problem_key(first, second);
        let mut stream = rng::stream(seed, Purpose::Dropout, &[key]);
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
                if self.arch.has_consensus() {
                    let key = ours::SHARED_MASKS_KEY;
                    let mut shared = rng::stream(seed, Purpose::Dropout, &[key]);
                    let (scope, dims) = (self.run.masks, [t, n1, n2]);
                    m.phi = draw_phi_mask(&mut shared, &self.arch, dims, scope, &self.device);
                }
                m
            }
        }
    }

    fn pair(
        &self,
        [s1, s2]: [&Side<'_, Self>; 2],
        [e1, e2]: [&TensorEmbedded; 2],
        input: &PairInput,
    ) -> PairResidual {
        let (n1, n2) = (input.n1, input.n2);
        let tensors = PairTensors::new(&[input], [n1, n2], &self.device);
        let masks = self.pair_masks(s1.view, s2.view);
        let h = |e: &TensorEmbedded, n: usize| {
            let shape = [1, self.run.samples, n, self.arch.out];
            Tensor::<4>::from_data(TensorData::new(e.h.clone(), shape), &self.device)
        };
        let (h1, h2) = (h(e1, s1.input.n), h(e2, s2.input.n));
        let out = self
            .net
            .pair((&h1, &e1.graph), (&h2, &e2.graph), &tensors, masks);
        let [d1, d2] = out.dust;
        PairResidual {
            residual: values(out.residual).expect("f32 tensors"),
            dust: [d1, d2].map(|d| values(d).expect("f32 tensors")),
        }
    }
}

impl Network for TensorOurs {
    type Input = OffsetGraph;
    type Embedding = TensorEmbedded;

    fn input(&self, view: &MatchView) -> OffsetGraph {
        OffsetGraph::offsets(
            view.detections,
            view.graph,
            &view.pose_reported,
            self.arch.appearance_width(),
        )
    }

    fn embedding_key(&self, input: &OffsetGraph) -> u64 {
        ours::embedding_key(input, self.run.samples)
    }

    fn keeps_embeddings(&self) -> bool {
        true
    }

    fn uses_positions(&self) -> bool {
        self.arch.positions
    }

    fn embed(&self, inputs: &[(&OffsetGraph, u64)]) -> (Vec<TensorEmbedded>, u64) {
        let t = self.run.samples;
        let mut made = Vec::with_capacity(inputs.len());
        let mut macs = 0;
        for &(i, key) in inputs {
            let shape = GraphShape::of_input(i);
            let graph = self.graph(i);
            let h = values(self.embedding(&graph, i, key)).expect("f32 tensors");
            macs += inference_macs(&self.arch, shape, shape, t).embeddings[0];
            made.push(TensorEmbedded { graph, h, shape });
        }
        (made, macs)
    }

    fn pose_free_key(&self, _inputs: [&OffsetGraph; 2]) -> Option<u64> {
        None
    }

    fn samples(&self, sides: [Side<'_, Self>; 2], relative: &PoseEstimate) -> (Samples, u64) {
        let [s1, s2] = &sides;
        let (n1, n2, t) = (s1.input.n, s2.input.n, self.run.samples);
        let (Some(e1), Some(e2)) = (s1.embedding, s2.embedding) else {
            unreachable!("every embedding is kept");
        };
        let macs = inference_macs(&self.arch, e1.shape, e2.shape, t).shared_pair();
        let input = pair_input(s1.view, s2.view, relative, &self.terms);
        let out = self.pair([s1, s2], [e1, e2], &input);
        let c = (self.combination, self.arch.sinkhorn_iters);
        (ours::combine(c, t, &input, &out, [n1, n2]), macs)
    }
}

/// A published network through the tensors.
pub(crate) struct TensorPublished {
    cfg: PublishedConfig,
    net: PublishedNet,
    run: Inference,
    rate: f64,
}

impl TensorPublished {
    /// The network `net` of `cfg`, run as `run` says.
    pub(crate) fn new(cfg: PublishedConfig, net: PublishedNet, run: Inference) -> Self {
        Self {
            rate: run.dropout.unwrap_or(cfg.dropout_conv),
            cfg,
            net,
            run,
        }
    }

    /// The network of `cfg` with the weights `bytes`.
    pub(crate) fn from_weights(cfg: PublishedConfig, bytes: &[u8], run: Inference) -> Self {
        let net = super::weights::published_from_bytes(&cfg, bytes, &device()).expect("weights");
        Self::new(cfg, net, run)
    }

    /// The soft assignments of the samples, from the stream of the pair's
    /// `key`.
    fn assignments(&self, [g1, g2]: [&LengthGraph; 2], key: u64) -> Vec<Vec<f32>> {
        let (n1, n2, t) = (g1.n, g2.n, self.run.samples);
        let device = device();
        let scale = self.cfg.edge_scale_m;
        let (t1, t2) = (
            GraphTensors::lengths(&[g1], scale, &device),
            GraphTensors::lengths(&[g2], scale, &device),
        );
        let mut stream = rng::stream(self.run.seed, Purpose::Dropout, &[key]);
        let dropout = Dropout::On(self.rate, self.run.masks);
        let shape = [1, t, n1, n2];
        let psi1 = match self.run.masks {
            MaskScope::PerNode => draw_psi1_masks(&mut stream, &self.cfg, shape, dropout, &device),
            MaskScope::Shared => {
                let key = published::SHARED_MASKS_KEY;
                let mut shared = rng::stream(self.run.seed, Purpose::Dropout, &[key]);
                draw_psi1_masks(&mut shared, &self.cfg, shape, dropout, &device)
            }
        };
        let indicators = draw_indicators(&mut stream, &self.cfg, [1, t, n1], &device);
        let masks = PublishedMasks { psi1, indicators };
        let p = values(self.net.forward(&self.cfg, [&t1, &t2], masks).last().exp())
            .expect("f32 tensors");
        p.chunks_exact((n1 + 1) * (n2 + 1))
            .map(<[f32]>::to_vec)
            .collect()
    }
}

impl Network for TensorPublished {
    type Input = LengthGraph;
    type Embedding = ();

    fn input(&self, view: &MatchView) -> LengthGraph {
        LengthGraph::lengths(
            view.detections,
            view.graph,
            self.cfg.graph,
            self.cfg.appearance_width,
        )
    }

    fn embedding_key(&self, g: &LengthGraph) -> u64 {
        published::pair_key([g, g])
    }

    fn keeps_embeddings(&self) -> bool {
        false
    }

    fn uses_positions(&self) -> bool {
        false
    }

    fn embed(&self, inputs: &[(&LengthGraph, u64)]) -> (Vec<()>, u64) {
        (vec![(); inputs.len()], 0)
    }

    fn pose_free_key(&self, [g1, g2]: [&LengthGraph; 2]) -> Option<u64> {
        Some(published::pair_key([g1, g2]))
    }

    fn samples(&self, [s1, s2]: [Side<'_, Self>; 2], _relative: &PoseEstimate) -> (Samples, u64) {
        let (g1, g2) = (s1.input, s2.input);
        let key = published::pair_key([g1, g2]);
        let per_node = self.run.masks == MaskScope::PerNode;
        let macs = published_macs(&self.cfg, [g1.n, g2.n], self.run.samples, per_node);
        let a = self.assignments([g1, g2], key);
        (published::pair_samples(a), macs.new_pair())
    }
}
