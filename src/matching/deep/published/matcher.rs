//! [`PublishedMatcher`]: a trained published network (GCN-GM, DGMC, or
//! the paper's method on DGMC's network) as a [`Matcher`] on the paper's
//! inputs, with MC-dropout inference. It never reads the reported poses
//! or the relative pose it is handed: only each vehicle's detections in
//! its own body frame, their appearance and their Delaunay graph. So the
//! same pair at another pose-noise level has the same answer: the last
//! few pairs' distributions are kept by their inputs' key and reused, bit
//! for bit what computing them again gives.

use std::collections::HashMap;
use std::sync::Mutex;

use burn::prelude::*;

use super::conv::GraphTensors;
use super::graph::PaperGraph;
use super::model::{
    Dropout, PublishedConfig, PublishedMasks, PublishedNet, draw_indicators, draw_psi1_masks,
};
use crate::assignment::assign;
use crate::fusion::PoseEstimate;
use crate::matching::deep::Inference;
use crate::matching::deep::arch::MaskScope;
use crate::matching::deep::decision::MatchDistribution;
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
}

/// At most this many distributions are kept (a frame's pairs at every
/// pose-noise level).
const RECENT_CAPACITY: usize = 256;

/// A key of both graphs' inputs: what a pair's samples depend on.
fn pair_key(graphs: [&PaperGraph; 2]) -> u64 {
    let mut parts = Vec::new();
    for g in graphs {
        parts.push(g.n as u64);
        parts.extend(g.node_features.iter().map(|v| u64::from(v.to_bits())));
        parts.extend(g.length_m.iter().map(|v| u64::from(v.to_bits())));
        parts.extend(g.src.iter().chain(&g.dst).map(|&v| v as u64));
    }
    rng::key(&parts)
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
        Ok(Self {
            method,
            cfg,
            net,
            run,
            recent: Mutex::default(),
        })
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

    /// The soft assignments of the samples, each `(n1 + 1) x (n2 + 1)`;
    /// indicators (and per-node masks) from the stream of the pair's
    /// `key`, so that a pair's samples depend on nothing matched before.
    fn samples(&self, graphs: [&PaperGraph; 2], key: u64) -> Vec<Vec<f32>> {
        let [g1, g2] = graphs;
        let (n1, n2, t) = (g1.n, g2.n, self.run.samples);
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
