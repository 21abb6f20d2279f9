//! A published network's forward pass opened to a check from outside:
//! the plain inference ([`super::inference::PlainPublished`]) on node
//! attributes, edges and draws the caller gives, and the parameters by
//! name. `tools/dgmc_reference` holds DGMC's PyTorch code to it through
//! the Python package; nothing in the pipeline uses it.

use super::inference::PlainPublished;
use crate::matching::Method;
use crate::matching::deep::arch::{Backbone, PublishedConfig};
use crate::matching::deep::graph::LengthGraph;
use crate::matching::deep::params::Params;
use crate::sensor::AppearanceWidth;

/// One vehicle's graph as the caller gives it: `n x width` node
/// attributes (row-major), each undirected edge once with its length.
pub struct GraphParts {
    pub node_features: Vec<f32>,
    pub edges: Vec<(usize, usize)>,
    pub length_m: Vec<f64>,
}

/// A trained published network with its draws left to the caller.
pub struct PublishedForward {
    cfg: PublishedConfig,
    params: Params,
    plain: PlainPublished,
}

impl PublishedForward {
    /// The network of `method` (one on the paper's inputs) reading
    /// appearance vectors `appearance_width` wide, of `shape` (its
    /// record's), with the weights `bytes` of its `.bpk` file, computing
    /// `samples` samples per pair. The caller gives the edges, so a
    /// network trained on every pair of detections is refused: its
    /// edges are not a dataset's.
    pub fn new(
        method: Method,
        appearance_width: AppearanceWidth,
        shape: crate::matching::deep::arch::NetworkShape,
        bytes: &[u8],
        samples: usize,
    ) -> Result<Self, String> {
        if shape.graph != crate::matching::deep::arch::NetworkGraph::Delaunay {
            return Err(
                "its record says it convolves over every pair of detections, and this \
                 forward pass takes the dataset's Delaunay edges"
                    .into(),
            );
        }
        let cfg = match method
            .backbone()
            .map(|b| b.with_appearance(appearance_width).with_shape(shape))
        {
            Some(Backbone::Published(cfg)) => cfg,
            _ => {
                return Err(format!(
                    "{} is not a network on the paper's inputs",
                    method.as_str()
                ));
            }
        };
        let params = Params::from_bytes(bytes, &super::spec(&cfg))?;
        let plain = PlainPublished::new(
            super::plain_weights(&cfg, &params),
            samples,
            None,
            [cfg.consensus_steps(), cfg.sinkhorn_iters],
            cfg.edge_scale_m,
        );
        Ok(Self { cfg, params, plain })
    }

    /// Its architecture.
    pub fn config(&self) -> PublishedConfig {
        self.cfg
    }

    /// Every parameter by the name its weights file gives it: shape and
    /// values (row-major; a layer's weights are `[in, out]`, a spline
    /// convolution's `[in, knots * out]`).
    pub fn parameters(&self) -> Vec<(String, Vec<usize>, Vec<f32>)> {
        self.params
            .iter()
            .map(|(k, shape, v)| (k.to_owned(), shape.to_vec(), v.to_vec()))
            .collect()
    }

    /// The `(n1 + 1) x (n2 + 1)` assignment of each sample (dustbins last)
    /// for the graphs `first` and `second`: psi_1 with the per-node
    /// dropout masks `masks` (`samples x n x hidden` each, a dropped
    /// channel 0, a kept one `1 / (1 - p)`), then each consensus step with
    /// its indicators (`samples x n1 x consensus_dim`).
    pub fn forward(
        &self,
        [first, second]: [&GraphParts; 2],
        masks: [&[f32]; 2],
        indicators: &[Vec<f32>],
    ) -> Result<Vec<Vec<f32>>, String> {
        let (g1, g2) = (self.graph(first)?, self.graph(second)?);
        let t = self.plain.samples();
        for (g, m) in [(&g1, masks[0]), (&g2, masks[1])] {
            if m.len() != t * g.n * self.cfg.hidden {
                return Err(format!(
                    "a mask of {} values for {t} samples x {} nodes x {} channels",
                    m.len(),
                    g.n,
                    self.cfg.hidden
                ));
            }
        }
        let steps = self.cfg.consensus_steps();
        let per_step = t * g1.n * self.cfg.consensus_dim;
        if indicators.len() != steps || indicators.iter().any(|r| r.len() != per_step) {
            return Err(format!(
                "{steps} consensus steps need {steps} indicator draws of {per_step} values each"
            ));
        }
        let h1 = self.plain.embed_per_node(&g1, masks[0]);
        let h2 = self.plain.embed_per_node(&g2, masks[1]);
        Ok(self.plain.assignments([(&h1, &g1), (&h2, &g2)], indicators))
    }

    fn graph(&self, g: &GraphParts) -> Result<LengthGraph, String> {
        let width = self.cfg.node_features();
        if !g.node_features.len().is_multiple_of(width) {
            return Err(format!(
                "{} node attributes are not rows of {width}",
                g.node_features.len()
            ));
        }
        let n = g.node_features.len() / width;
        if g.edges.len() != g.length_m.len() {
            return Err(format!(
                "{} edges, {} lengths",
                g.edges.len(),
                g.length_m.len()
            ));
        }
        if let Some(&(a, b)) = g.edges.iter().find(|&&(a, b)| a >= n || b >= n || a == b) {
            return Err(format!("edge ({a}, {b}) in a graph of {n} nodes"));
        }
        if let Some(l) = g.length_m.iter().find(|l| !l.is_finite() || **l < 0.0) {
            return Err(format!("an edge {l} m long"));
        }
        let edges: Vec<_> = g
            .edges
            .iter()
            .zip(&g.length_m)
            .map(|(&(a, b), &l)| (a, b, l))
            .collect();
        Ok(LengthGraph::from_edges(
            g.node_features.clone(),
            width,
            &edges,
        ))
    }
}
