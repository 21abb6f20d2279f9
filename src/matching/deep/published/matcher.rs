//! [`PublishedMatcher`]: a trained published network (GCN-GM, DGMC, or
//! the paper's method on DGMC's network) as a [`Matcher`] on the paper's
//! inputs, with MC-dropout inference. It never reads the reported poses
//! or the relative pose it is handed: only each vehicle's detections in
//! its own body frame, their appearance and their Delaunay graph. So the
//! same pair at another pose-noise level has the same answer: the last
//! few pairs' distributions are kept by their inputs' key and reused, bit
//! for bit what computing them again gives.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use burn::prelude::*;

use super::conv::GraphTensors;
use super::graph::PaperGraph;
use super::model::{
    Dropout, PublishedConfig, PublishedMasks, PublishedNet, draw_indicators, draw_psi1_masks,
};
use super::plain::PlainPublished;
use crate::assignment::assign;
use crate::fusion::PoseEstimate;
use crate::matching::deep::Inference;
use crate::matching::deep::arch::MaskScope;
use crate::matching::deep::cost::published_macs;
use crate::matching::deep::decision::MatchDistribution;
use crate::matching::deep::masks::{dropout_mask_16, indicator_values};
use crate::matching::{Identification, MatchView, Matcher, Method};
use crate::rng::{self, Purpose};

/// The stream name of the psi_1 masks every pair shares
/// ([`MaskScope::Shared`]).
const SHARED_MASKS_KEY: u64 = 0x5a4e_d0e8_0000_0009;

/// A trained published network with MC-dropout inference.
pub struct PublishedMatcher {
    method: Method,
    cfg: PublishedConfig,
    net: PublishedNet,
    run: Inference,
    /// Recent pairs' distributions by [`pair_key`].
    recent: Mutex<HashMap<u64, MatchDistribution>>,
    /// The network in plain Rust ([`PlainPublished`]); `None`: through
    /// the tensors, as in training (the reference).
    plain: Option<PlainPublished>,
    /// Recent graphs' psi_1 embeddings on the plain path, by
    /// [`graph_key`]: a vehicle's graph is embedded once for all its pairs.
    embeddings: Mutex<HashMap<u64, Arc<Vec<f32>>>>,
    /// Multiply-adds done so far ([`published_macs`]).
    macs: AtomicU64,
}

/// One pair's random draws on the plain path: psi_1's masks per node of
/// both graphs (empty under shared masks) and one draw of indicators per
/// consensus step.
struct Draws {
    masks: [Vec<f32>; 2],
    indicators: Vec<Vec<f32>>,
}

impl Draws {
    fn bytes(&self) -> usize {
        let values = self.masks.iter().chain(&self.indicators).map(Vec::len);
        values.sum::<usize>() * size_of::<f32>()
    }
}

/// Recent pairs' draws by everything that makes them ([`draws_key`]):
/// the paper's method, its ablations and DGMC share a network shape and
/// the run's dropout seed, so they draw the same numbers for a pair, and
/// the first to ask draws them for all. Kept oldest first, within
/// [`DRAWS_BYTES`].
static DRAWS: Mutex<VecDeque<(u64, Arc<Draws>)>> = Mutex::new(VecDeque::new());

/// The most the kept draws hold, in bytes.
const DRAWS_BYTES: usize = 64 << 20;

/// At most this many distributions are kept (a frame's pairs at every
/// pose-noise level).
const RECENT_CAPACITY: usize = 256;

/// A key of both graphs' inputs: what a pair's samples depend on.
fn pair_key(graphs: [&PaperGraph; 2]) -> u64 {
    let mut parts = Vec::new();
    for g in graphs {
        graph_parts(g, &mut parts);
    }
    rng::key(&parts)
}

/// A key of one graph's input: what its psi_1 embedding depends on.
fn graph_key(g: &PaperGraph) -> u64 {
    let mut parts = Vec::new();
    graph_parts(g, &mut parts);
    rng::key(&parts)
}

fn graph_parts(g: &PaperGraph, parts: &mut Vec<u64>) {
    parts.push(g.n as u64);
    parts.extend(g.node_features.iter().map(|v| u64::from(v.to_bits())));
    parts.extend(g.length_m.iter().map(|v| u64::from(v.to_bits())));
    parts.extend(g.src.iter().chain(&g.dst).map(|&v| v as u64));
}

impl PublishedMatcher {
    /// `method`'s network of `cfg` with the weights `bytes`; an error says
    /// why the bytes do not fit.
    pub fn from_weights(
        method: Method,
        cfg: PublishedConfig,
        bytes: &[u8],
        run: Inference,
    ) -> Result<Self, String> {
        let net = super::from_bytes(&cfg, bytes, &Device::flex())?;
        // Shared masks are the same for every pair: drawn once, as
        // `samples` draws them for the tensors.
        let shared = (run.masks == MaskScope::Shared).then(|| {
            let mut shared = rng::stream(run.seed, Purpose::Dropout, &[SHARED_MASKS_KEY]);
            let rate = run.dropout.unwrap_or(cfg.dropout);
            dropout_mask_16(&mut shared, run.samples * cfg.hidden, rate)
        });
        let plain = Some(PlainPublished::new(
            net.plain(),
            run.samples,
            shared.as_deref(),
            [cfg.consensus_steps(), cfg.sinkhorn_iters],
            cfg.edge_scale_m,
        ));
        Ok(Self {
            method,
            cfg,
            net,
            run,
            recent: Mutex::default(),
            plain,
            embeddings: Mutex::default(),
            macs: AtomicU64::new(0),
        })
    }

    /// Runs the network through the tensors, as training does: the
    /// reference the plain path is held equal to.
    pub fn with_tensor_path(mut self) -> Self {
        self.plain = None;
        self
    }

    /// psi_1's embedding of `g` on the plain path, kept for its other
    /// pairs.
    fn embedding(&self, plain: &PlainPublished, g: &PaperGraph) -> Arc<Vec<f32>> {
        let key = graph_key(g);
        if let Some(h) = self
            .embeddings
            .lock()
            .ok()
            .and_then(|e| e.get(&key).cloned())
        {
            return h;
        }
        let h = Arc::new(plain.embed(g));
        let macs = published_macs(&self.cfg, [g.n, g.n], self.run.samples, false);
        self.macs.fetch_add(macs.embeddings[0], Ordering::Relaxed);
        if let Ok(mut kept) = self.embeddings.lock() {
            if kept.len() >= RECENT_CAPACITY {
                kept.clear();
            }
            kept.insert(key, Arc::clone(&h));
        }
        h
    }

    /// E[Y] and the per-pair uncertainties over `samples` MC-dropout
    /// passes.
    pub fn distribution(&self, first: &MatchView, second: &MatchView) -> MatchDistribution {
        let (n1, n2) = (first.detections.len(), second.detections.len());
        let mut d = if n1 == 0 || n2 == 0 {
            MatchDistribution::all_unmatched(n1, n2)
        } else {
            let g1 = PaperGraph::new(first.detections, first.graph);
            let g2 = PaperGraph::new(second.detections, second.graph);
            let key = pair_key([&g1, &g2]);
            let kept = self.recent.lock().ok().and_then(|r| r.get(&key).cloned());
            match kept {
                Some(d) => d,
                None => {
                    let samples = self.samples([&g1, &g2], key);
                    let mut d = MatchDistribution::from_samples(n1, n2, &samples);
                    d.assigned = assignment(&d);
                    if let Ok(mut recent) = self.recent.lock() {
                        if recent.len() >= RECENT_CAPACITY {
                            recent.clear();
                        }
                        recent.insert(key, d.clone());
                    }
                    d
                }
            }
        };
        d.decision = self.run.decision;
        d.temperature = self.run.temperature;
        d
    }

    /// The pair's draws ([`Draws`]) from the stream of its `key`: per
    /// node masks as `draw_psi1_masks` draws them, then one draw of
    /// indicators per consensus step as `draw_indicators` does; kept for
    /// the other networks that draw the same.
    fn draws(&self, key: u64, [n1, n2]: [usize; 2]) -> Arc<Draws> {
        let (t, rate) = (
            self.run.samples,
            self.run.dropout.unwrap_or(self.cfg.dropout),
        );
        let per_node = self.run.masks == MaskScope::PerNode;
        let (d, r, steps) = (
            self.cfg.hidden,
            self.cfg.rnd_dim,
            self.cfg.consensus_steps(),
        );
        let id = rng::key(&[
            self.run.seed,
            key,
            u64::from(per_node),
            rate.to_bits(),
            t as u64,
            n1 as u64,
            n2 as u64,
            d as u64,
            r as u64,
            steps as u64,
        ]);
        let find = |kept: &VecDeque<(u64, Arc<Draws>)>| {
            kept.iter()
                .find(|(k, _)| *k == id)
                .map(|(_, d)| Arc::clone(d))
        };
        if let Some(found) = DRAWS.lock().ok().and_then(|kept| find(&kept)) {
            return found;
        }
        let mut stream = rng::stream(self.run.seed, Purpose::Dropout, &[key]);
        let masks = if per_node {
            [n1, n2].map(|n| dropout_mask_16(&mut stream, t * n * d, rate))
        } else {
            [Vec::new(), Vec::new()]
        };
        let indicators = (0..steps)
            .map(|_| indicator_values(&mut stream, t * n1 * r))
            .collect();
        let drawn = Arc::new(Draws { masks, indicators });
        if let Ok(mut kept) = DRAWS.lock()
            && find(&kept).is_none()
            && drawn.bytes() <= DRAWS_BYTES
        {
            let mut total: usize = kept.iter().map(|(_, d)| d.bytes()).sum();
            while total + drawn.bytes() > DRAWS_BYTES {
                let Some((_, old)) = kept.pop_front() else {
                    break;
                };
                total -= old.bytes();
            }
            kept.push_back((id, Arc::clone(&drawn)));
        }
        drawn
    }

    /// The soft assignments of the samples, each `(n1 + 1) x (n2 + 1)`;
    /// indicators (and per-node masks) from the stream of the pair's
    /// `key`, so that a pair's samples depend on nothing matched before.
    fn samples(&self, graphs: [&PaperGraph; 2], key: u64) -> Vec<Vec<f32>> {
        let [g1, g2] = graphs;
        let (n1, n2, t) = (g1.n, g2.n, self.run.samples);
        // Under shared masks a graph's embedding is counted where it is
        // computed (once for its pairs).
        let per_node = self.run.masks == MaskScope::PerNode;
        let macs = published_macs(&self.cfg, [n1, n2], t, per_node);
        let counted = if per_node || self.plain.is_none() {
            macs.new_pair()
        } else {
            macs.shared_pair()
        };
        self.macs.fetch_add(counted, Ordering::Relaxed);
        if let Some(plain) = &self.plain {
            let drawn = self.draws(key, [n1, n2]);
            let (h1, h2) = match self.run.masks {
                MaskScope::Shared => (self.embedding(plain, g1), self.embedding(plain, g2)),
                MaskScope::PerNode => (
                    Arc::new(plain.embed_per_node(g1, &drawn.masks[0])),
                    Arc::new(plain.embed_per_node(g2, &drawn.masks[1])),
                ),
            };
            return plain.assignments([(&h1, g1), (&h2, g2)], &drawn.indicators);
        }
        let device = Device::flex();
        let scale = self.cfg.edge_scale_m;
        let (t1, t2) = (
            GraphTensors::new(&[g1], scale, &device),
            GraphTensors::new(&[g2], scale, &device),
        );
        let mut stream = rng::stream(self.run.seed, Purpose::Dropout, &[key]);
        let rate = self.run.dropout.unwrap_or(self.cfg.dropout);
        let dropout = Dropout::On(rate, self.run.masks);
        let psi1 = match self.run.masks {
            MaskScope::PerNode => {
                draw_psi1_masks(&mut stream, &self.cfg, [1, t, n1, n2], dropout, &device)
            }
            MaskScope::Shared => {
                let mut shared = rng::stream(self.run.seed, Purpose::Dropout, &[SHARED_MASKS_KEY]);
                draw_psi1_masks(&mut shared, &self.cfg, [1, t, n1, n2], dropout, &device)
            }
        };
        let indicators = draw_indicators(&mut stream, &self.cfg, [1, t, n1], &device);
        let masks = PublishedMasks { psi1, indicators };
        let p = self.net.forward(&self.cfg, [&t1, &t2], masks).last().exp();
        let v: Vec<f32> = p.try_into_vec_as::<f32>().unwrap_or_default();
        v.chunks_exact((n1 + 1) * (n2 + 1))
            .map(<[f32]>::to_vec)
            .collect()
    }
}

/// The one-to-one assignment of E[Y] with the most likely total: pairs
/// maximising the sum of `ln E[Y]_ij`, a pair allowed only where it is
/// more likely than "no match" for both of its nodes (its row's and its
/// column's dustbin). What [`crate::matching::deep::decision::Decision::Assignment`]
/// pairs for a published network, which has no pair scores of its own.
fn assignment(d: &MatchDistribution) -> Vec<(usize, usize)> {
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

impl Matcher for PublishedMatcher {
    fn method(&self) -> Method {
        self.method
    }

    fn network_macs(&self) -> u64 {
        self.macs.load(Ordering::Relaxed)
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        _relative: &PoseEstimate,
    ) -> Identification {
        let distribution = self.distribution(first, second);
        Identification {
            matches: distribution.decide(self.run.threshold),
            distribution: Some(distribution),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::deep::arch::{Backbone, DeepMethod};
    use crate::matching::testkit::{self, GPS, Side};

    const RUN: Inference = Inference::MC_DROPOUT;

    /// The plain path under shared and per-node masks against the tensor
    /// path (the reference, as training runs it) with the shipped weights of GCN-GM,
    /// DGMC and the paper's method (DGMC's network), on graphs of 8, 9, 2
    /// and 1 nodes: every sample's assignment within 1e-4 (the f32
    /// log-domain Sinkhorn's own rounding, see `sinkhorn.rs`), the same
    /// decided pairs, and the plain path's answers the same when a
    /// graph's embedding comes from another pair. The target's first
    /// consensus product both ways: carried over from the source's (as
    /// these graphs take it) and multiplied anew (as sources of more than
    /// `rnd_dim` nodes take it).
    #[test]
    fn the_plain_published_path_equals_the_tensor_one() {
        let shipped: [(DeepMethod, &[u8]); 3] = [
            (
                DeepMethod::GcnGm,
                include_bytes!("../../../../models/gcn-gm.bpk"),
            ),
            (
                DeepMethod::Dgmc,
                include_bytes!("../../../../models/dgmc.bpk"),
            ),
            (
                DeepMethod::Coid,
                include_bytes!("../../../../models/coid.bpk"),
            ),
        ];
        let objects = testkit::world_objects();
        let side = |at, order: &[usize]| Side::of(at, &objects, order, GPS);
        let scenes = [
            testkit::moved_copy(),
            (
                side(testkit::POSE_A, &[0, 1, 2, 3, 4, 5, 6, 7]),
                side(testkit::POSE_B, &[7, 6, 5, 4, 3, 2, 1, 0]),
            ),
            (side(testkit::POSE_A, &[0, 3]), side(testkit::POSE_B, &[3])),
        ];
        let runs = [MaskScope::Shared, MaskScope::PerNode].map(|masks| Inference { masks, ..RUN });
        for ((method, bytes), run) in shipped.into_iter().flat_map(|s| runs.map(|r| (s, r))) {
            let Backbone::Published(cfg) = method.backbone() else {
                panic!("{method:?} is a published network");
            };
            let open = || PublishedMatcher::from_weights(method.method(), cfg, bytes, run).unwrap();
            let (tensor, mut direct) = (open().with_tensor_path(), open());
            if let Some(p) = &mut direct.plain {
                p.never_carry();
            }
            for (plain, (a, b)) in [open(), direct]
                .iter()
                .flat_map(|m| scenes.iter().map(move |s| (m, s)))
            {
                assert!(plain.plain.is_some() && tensor.plain.is_none());
                let (va, vb) = (a.view(), b.view());
                let g1 = PaperGraph::new(va.detections, va.graph);
                let g2 = PaperGraph::new(vb.detections, vb.graph);
                let key = pair_key([&g1, &g2]);
                let (sp, st) = (
                    plain.samples([&g1, &g2], key),
                    tensor.samples([&g1, &g2], key),
                );
                assert_eq!(sp.len(), 20);
                assert_eq!(sp.len(), st.len());
                for (p, t) in sp.iter().flatten().zip(st.iter().flatten()) {
                    assert!((p - t).abs() <= 1e-4, "{method:?} {run:?}: {p} vs {t}");
                }
                let pairs = |m: &PublishedMatcher| {
                    let d = m.distribution(&va, &vb);
                    d.decide(None)
                        .iter()
                        .map(|c| (c.a, c.b))
                        .collect::<Vec<_>>()
                };
                assert_eq!(pairs(plain), pairs(&tensor), "{method:?}");
                // Both embeddings now kept: the same answer again.
                assert_eq!(plain.samples([&g1, &g2], key), sp);
            }
        }
    }

    /// A matcher counts what its network multiplies: a new pair as
    /// `published_macs` counts it (masks per node: both embeddings and
    /// the pair part), the same pair at another pose-noise level (kept)
    /// nothing more; under shared masks a graph already embedded only
    /// the pair part.
    #[test]
    fn a_matcher_counts_what_its_network_multiplies() {
        let Backbone::Published(cfg) = DeepMethod::Dgmc.backbone() else {
            panic!("DGMC is a published network");
        };
        let bytes = include_bytes!("../../../../models/dgmc.bpk");
        let objects = testkit::world_objects();
        let side = |at, order: &[usize]| Side::of(at, &objects, order, GPS);
        let (a, b) = (
            side(testkit::POSE_A, &[0, 1, 2, 3, 4, 5]),
            side(testkit::POSE_B, &[5, 4, 3, 2, 1]),
        );
        let c = side(testkit::POSE_B, &[0, 2, 4, 6]);
        let (va, vb, vc) = (a.view(), b.view(), c.view());
        for masks in [MaskScope::PerNode, MaskScope::Shared] {
            let run = Inference { masks, ..RUN };
            let m = PublishedMatcher::from_weights(Method::Dgmc, cfg, bytes, run).unwrap();
            assert_eq!(m.network_macs(), 0);
            m.distribution(&va, &vb);
            let ab = published_macs(&cfg, [6, 5], 20, masks == MaskScope::PerNode);
            assert_eq!(m.network_macs(), ab.new_pair(), "{masks:?}");
            m.distribution(&va, &vb);
            assert_eq!(m.network_macs(), ab.new_pair(), "{masks:?}: kept");
            m.distribution(&va, &vc);
            let ac = published_macs(&cfg, [6, 4], 20, masks == MaskScope::PerNode);
            let more = match masks {
                MaskScope::PerNode => ac.new_pair(),
                MaskScope::Shared => ac.shared_pair() + ac.embeddings[1],
            };
            assert_eq!(m.network_macs(), ab.new_pair() + more, "{masks:?}");
        }
    }
}
