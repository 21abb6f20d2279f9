//! The published networks (GCN-GM, DGMC, and the paper's method on
//! DGMC's network) as the MC shell ([`crate::matching::deep::mc`]) runs
//! them, on the paper's inputs: each vehicle's detections in its own body
//! frame, their appearance and their Delaunay graph. They never read the
//! reported poses or the relative pose they are handed, so the shell
//! answers the same pair at every pose-noise level once.

use super::inference::PlainPublished;
use crate::fusion::PoseEstimate;
use crate::matching::MatchView;
use crate::matching::deep::arch::{IndicatorScope, MaskScope, PublishedConfig};
use crate::matching::deep::cost::published_macs;
use crate::matching::deep::graph::LengthGraph;
use crate::matching::deep::mc::draws::{dropout_mask_16, indicator_values};
use crate::matching::deep::mc::{Inference, Network, Samples, Side};
use crate::matching::deep::params::Params;
use crate::rng::{self, Purpose};

/// The stream name of the psi_1 masks every pair shares
/// ([`MaskScope::Shared`]).
pub(crate) const SHARED_MASKS_KEY: u64 = 0x5a4e_d0e8_0000_0009;

/// A key of both graphs' inputs: what a pair's samples depend on.
pub(crate) fn pair_key(graphs: [&LengthGraph; 2]) -> u64 {
    let mut parts = Vec::new();
    for g in graphs {
        graph_parts(g, &mut parts);
    }
    rng::key(&parts)
}

fn graph_parts(g: &LengthGraph, parts: &mut Vec<u64>) {
    parts.push(g.n as u64);
    parts.extend(g.node_features.iter().map(|v| u64::from(v.to_bits())));
    parts.extend(g.edge_m.iter().map(|[v]| u64::from((*v as f32).to_bits())));
    parts.extend(g.src.iter().chain(&g.dst).map(|&v| v as u64));
}

/// A trained published network with its plain inference.
pub(crate) struct Published {
    cfg: PublishedConfig,
    run: Inference,
    /// psi_1's dropout rate at inference.
    rate: f64,
    plain: PlainPublished,
}

impl Published {
    /// The network of `cfg` with the parameters `p`, run as `run` says.
    pub(crate) fn new(cfg: PublishedConfig, p: &Params, run: Inference) -> Self {
        let rate = run.dropout.unwrap_or(cfg.dropout_conv);
        // Shared masks are the same for every pair: drawn once.
        let shared = (run.masks == MaskScope::Shared).then(|| {
            let mut shared = rng::stream(run.seed, Purpose::Dropout, &[SHARED_MASKS_KEY]);
            dropout_mask_16(&mut shared, run.samples * cfg.hidden, rate)
        });
        let plain = PlainPublished::new(
            super::plain_weights(&cfg, p),
            run.samples,
            shared.as_deref(),
            [cfg.consensus_steps(), cfg.sinkhorn_iters],
            cfg.edge_scale_m,
        );
        Self {
            cfg,
            run,
            rate,
            plain,
        }
    }

    /// The network of `cfg` with trained weights (the bytes of its `.bpk`
    /// file); an error says why they do not fit.
    pub(crate) fn from_weights(
        cfg: PublishedConfig,
        bytes: &[u8],
        run: Inference,
    ) -> Result<Self, String> {
        Ok(Self::new(
            cfg,
            &Params::from_bytes(bytes, &super::spec(&cfg))?,
            run,
        ))
    }

    /// The consensus always multiplied anew (tests: the branch large
    /// source graphs take).
    #[cfg(test)]
    pub(crate) fn never_carry(mut self) -> Self {
        self.plain.never_carry();
        self
    }

    /// The pair's draws from the stream of its `key`: per node masks
    /// (none under shared masks), then one draw of indicators per
    /// consensus step, as training draws them (or, [`IndicatorScope::PerPair`],
    /// one shared by the pair's samples).
    /// Never kept: the shell keeps a pair's distribution for its other
    /// pose-noise levels (the network does not read the poses), so a
    /// pair's draws are read once.
    fn draws(&self, key: u64, [n1, n2]: [usize; 2]) -> [Vec<Vec<f32>>; 2] {
        let (t, rate) = (self.run.samples, self.rate);
        let per_node = self.run.masks == MaskScope::PerNode;
        let (d, r, steps) = (
            self.cfg.hidden,
            self.cfg.consensus_dim,
            self.cfg.consensus_steps(),
        );
        let mut stream = rng::stream(self.run.seed, Purpose::Dropout, &[key]);
        let masks = if per_node {
            [n1, n2]
                .map(|n| dropout_mask_16(&mut stream, t * n * d, rate))
                .to_vec()
        } else {
            Vec::new()
        };
        let indicators = (0..steps)
            .map(|_| match self.run.indicators {
                IndicatorScope::PerSample => indicator_values(&mut stream, t * n1 * r),
                IndicatorScope::PerPair => indicator_values(&mut stream, n1 * r).repeat(t),
            })
            .collect();
        [masks, indicators]
    }
}

impl Network for Published {
    type Input = LengthGraph;
    type Embedding = Vec<f32>;

    fn input(&self, view: &MatchView) -> LengthGraph {
        LengthGraph::lengths(
            view.detections,
            view.graph,
            self.cfg.graph,
            self.cfg.appearance_width,
        )
    }

    fn embedding_key(&self, g: &LengthGraph) -> u64 {
        let mut parts = Vec::new();
        graph_parts(g, &mut parts);
        rng::key(&parts)
    }

    /// Under shared masks a graph's psi_1 embedding is the same in all its
    /// pairs; per-node masks are drawn per pair.
    fn keeps_embeddings(&self) -> bool {
        self.run.masks == MaskScope::Shared
    }

    fn uses_positions(&self) -> bool {
        false
    }

    fn embed(&self, inputs: &[(&LengthGraph, u64)]) -> (Vec<Vec<f32>>, u64) {
        let t = self.run.samples;
        let macs = |g: &LengthGraph| published_macs(&self.cfg, [g.n, g.n], t, false).embeddings[0];
        let made = inputs.iter().map(|(g, _)| self.plain.embed(g)).collect();
        (made, inputs.iter().map(|(g, _)| macs(g)).sum())
    }

    fn pose_free_key(&self, [g1, g2]: [&LengthGraph; 2]) -> Option<u64> {
        Some(pair_key([g1, g2]))
    }

    fn samples(&self, [s1, s2]: [Side<'_, Self>; 2], _relative: &PoseEstimate) -> (Samples, u64) {
        let (g1, g2) = (s1.input, s2.input);
        let (n1, n2, t) = (g1.n, g2.n, self.run.samples);
        let key = pair_key([g1, g2]);
        // A graph's kept embedding is counted where it was computed.
        let per_node = self.run.masks == MaskScope::PerNode;
        let macs = published_macs(&self.cfg, [n1, n2], t, per_node);
        let [masks, indicators] = self.draws(key, [n1, n2]);
        match (s1.embedding, s2.embedding) {
            (Some(h1), Some(h2)) => {
                let a = self.plain.assignments([(h1, g1), (h2, g2)], &indicators);
                (pair_samples(a), macs.shared_pair())
            }
            _ => {
                let h1 = self.plain.embed_per_node(g1, &masks[0]);
                let h2 = self.plain.embed_per_node(g2, &masks[1]);
                let a = self.plain.assignments([(&h1, g1), (&h2, g2)], &indicators);
                (pair_samples(a), macs.new_pair())
            }
        }
    }
}

/// Samples of a network without pair scores of its own.
pub(crate) fn pair_samples(assignments: Vec<Vec<f32>>) -> Samples {
    Samples {
        assignments,
        scores: Vec::new(),
        mean_scores: None,
    }
}
