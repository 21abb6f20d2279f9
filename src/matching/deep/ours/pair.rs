//! The pair part of the network at inference under shared masks
//! ([`crate::matching::deep::arch::MaskScope::Shared`]), in plain Rust: what
//! training's `OursNet::pair` computes through the tensors (the
//! reference it is held equal to), for one pair and its `T` samples,
//! without a tensor, an allocation per operation or a padded batch.
//!
//! Two identities cut arithmetic exactly (up to float rounding):
//! - the consensus MLP's first layer is linear before its bias, so
//!   `(z1_i - z2_j) W = z1_i W - z2_j W`: `n1 + n2` products per sample
//!   instead of `n1 n2`;
//! - under shared masks the MLP's dropout mask is one per sample and unit,
//!   so a dropped hidden unit is skipped for every pair entry.
//!
//! The consensus spline convolution runs as the plain second layer does
//! ([`SharedMaskConv`] with every unit kept): all samples' propagated
//! indicators in one product, then mixed along the edges.

use super::second_layer::{PlainSpline, SharedMaskConv};
use crate::matching::deep::features::PairInput;
use crate::matching::deep::graph::OffsetGraph;
use crate::matching::deep::kernels::lanes::{
    PlainLinear, add_pair_terms, product_rows, similarity, transport,
};
use crate::matching::deep::kernels::sinkhorn::BLOCKED;

/// `exp(x)`, with the values whose f32 exponential is 0 (below about
/// -103.97) answered without the library's underflow path: the same bits.
fn exp_or_zero(x: f32) -> f32 {
    if x < -104.0 { 0.0 } else { x.exp() }
}

/// The scalar parameters that combine the shared likelihood with what the
/// network learned: score = `scale` ll + `gate` residual; a node's "no
/// match" score = `dustbin` + `dust_gate` (its learned score). At
/// initialisation scale is 1 and both gates 0: the scores are the shared
/// likelihood itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Combination {
    pub(crate) scale: f32,
    pub(crate) gate: f32,
    pub(crate) dustbin: f32,
    pub(crate) dust_gate: f32,
}

/// The pair part's parameters.
pub(crate) struct PairWeights {
    pub(crate) pair_in: PlainLinear,
    pub(crate) pair_out: PlainLinear,
    pub(crate) dust_in: PlainLinear,
    pub(crate) dust_out: PlainLinear,
    /// The consensus conv and MLP, when the network has consensus.
    pub(crate) consensus: Option<(PlainSpline, PlainLinear, PlainLinear)>,
    pub(crate) combination: Combination,
}

/// The consensus step.
struct Consensus {
    /// The spline convolution, every unit kept (one "sample").
    conv: SharedMaskConv,
    phi_in: PlainLinear,
    phi_out: PlainLinear,
    /// Under shared masks, per sample, the kept hidden units of `phi_in`
    /// and the mask's value on them; `None`: masks per pair entry, given
    /// with each pair.
    kept: Option<Vec<Vec<(usize, f32)>>>,
}

/// The pair part with `T` samples.
pub(crate) struct PlainPair {
    /// The MLPs and scalars (its consensus moved into `consensus`).
    w: PairWeights,
    consensus: Option<Consensus>,
    samples: usize,
}

/// What the pair part says of one pair: the residual of every pair entry
/// in every sample, `[T, n1, n2]`, and each node's learned "no match"
/// score before its gate, per vehicle.
pub(crate) struct PairResidual {
    pub(crate) residual: Vec<f32>,
    pub(crate) dust: [Vec<f32>; 2],
}

impl PlainPair {
    /// The pair part with `phi_mask` (`[T, R]`: each sample's consensus
    /// MLP mask, 0 or the sample's scale, shared by every pair entry;
    /// `None`: masks per pair entry, given with each pair; ignored without
    /// consensus).
    pub(crate) fn new(mut w: PairWeights, samples: usize, phi_mask: Option<&[f32]>) -> Self {
        let consensus = w.consensus.take().map(|(conv, phi_in, phi_out)| {
            let r = conv.d_out;
            let kept = phi_mask.map(|phi_mask| {
                (0..samples)
                    .map(|t| {
                        let m = &phi_mask[t * r..(t + 1) * r];
                        (0..r).filter(|&u| m[u] != 0.0).map(|u| (u, m[u])).collect()
                    })
                    .collect()
            });
            Consensus {
                conv: SharedMaskConv::new(&conv, &vec![1.0; conv.d_in], &vec![1.0; r]),
                phi_in,
                phi_out,
                kept,
            }
        });
        Self {
            w,
            consensus,
            samples,
        }
    }

    /// The residual and raw "no match" scores of one pair: `h1` `[T, n1,
    /// out]` and `h2` `[T, n2, out]` the two vehicles' embeddings, `g1`
    /// and `g2` their graphs, `indicators` `[n1, R]` the pair's random
    /// node indicators (unused without consensus), `phi` `[T, n1, n2, R]`
    /// the consensus MLP's masks per pair entry when they are not shared.
    pub(crate) fn forward(
        &self,
        (h1, g1): (&[f32], &OffsetGraph),
        (h2, g2): (&[f32], &OffsetGraph),
        input: &PairInput,
        [indicators, phi]: [&[f32]; 2],
    ) -> PairResidual {
        let (n1, n2, t) = (input.n1, input.n2, self.samples);
        let w = &self.w;
        // Once per pair: the pair MLP and the "no match" MLP.
        let mlp = |a: &PlainLinear, b: &PlainLinear, x: &[f32], hidden: &mut Vec<f32>| {
            hidden.resize(a.d_out, 0.0);
            a.relu_row(x, hidden);
            let mut out = [0f32];
            b.product(hidden, &mut out);
            out[0] + b.bias[0]
        };
        let mut hidden = Vec::new();
        let fp = w.pair_in.d_in;
        let pair_term: Vec<f32> = (0..n1 * n2)
            .map(|k| {
                let x = &input.pair_features[k * fp..(k + 1) * fp];
                mlp(&w.pair_in, &w.pair_out, x, &mut hidden)
            })
            .collect();
        let fd = w.dust_in.d_in;
        let dust = [0, 1].map(|g| {
            let n = [n1, n2][g];
            (0..n)
                .map(|i| {
                    let x = &input.dust_features[g][i * fd..(i + 1) * fd];
                    mlp(&w.dust_in, &w.dust_out, x, &mut hidden)
                })
                .collect::<Vec<f32>>()
        });
        // Per sample: the similarity H1 H2^T plus the pair term.
        let mut residual = similarity(h1, h2, [t, n1, n2]);
        for (r, p) in residual.iter_mut().zip(pair_term.iter().cycle()) {
            *r += p;
        }
        if let Some(c) = &self.consensus {
            let draws = [indicators, phi];
            self.consensus(c, [g1, g2], input, draws, &dust[0], &mut residual);
        }
        PairResidual { residual, dust }
    }

    /// Adds DGMC's consensus term (Eq. 3) to `residual` (`[T, n1, n2]`,
    /// the similarity and pair term so far).
    fn consensus(
        &self,
        c: &Consensus,
        [g1, g2]: [&OffsetGraph; 2],
        input: &PairInput,
        [indicators, phi]: [&[f32]; 2],
        dust1: &[f32],
        residual: &mut [f32],
    ) {
        let (n1, n2, t) = (input.n1, input.n2, self.samples);
        let r = c.phi_in.d_in;
        let k = self.w.combination;
        // The soft correspondence: each first-graph row's softmax over the
        // full scores and its "no match" score.
        let bin: Vec<f32> = dust1.iter().map(|&d| k.dustbin + d * k.dust_gate).collect();
        let mut soft = vec![0f32; t * n1 * n2];
        let mut row = vec![0f32; n2 + 1];
        for s in 0..t {
            for i in 0..n1 {
                for (j, x) in row.iter_mut().take(n2).enumerate() {
                    let at = i * n2 + j;
                    *x = match input.log_likelihood[at] {
                        Some(ll) => (ll as f32) * k.scale + residual[s * n1 * n2 + at] * k.gate,
                        None => BLOCKED,
                    };
                }
                row[n2] = bin[i];
                let max = row
                    .iter()
                    .fold(f32::NEG_INFINITY, |m, &x| if x > m { x } else { m });
                let mut sum = 0f32;
                for x in row.iter_mut() {
                    *x = exp_or_zero(*x - max);
                    sum += *x;
                }
                let inv = 1.0 / sum;
                let out = &mut soft[(s * n1 + i) * n2..(s * n1 + i + 1) * n2];
                for (o, x) in out.iter_mut().zip(&row) {
                    *o = x * inv;
                }
            }
        }
        // The indicators pushed through it: r2[s] = soft[s]^T r1, [n2, R].
        let mut r2 = vec![0f32; t * n2 * r];
        transport(&soft, 0, indicators, [r, 0], [t, n1, n2], &mut r2);
        // Both sides embedded by the consensus conv: z1 once, z2 per sample
        // (all samples in one product).
        let z1 = c.conv.forward_many(&[(indicators, g1)]).remove(0);
        let per_sample: Vec<(&[f32], &OffsetGraph)> = r2.chunks(n2 * r).map(|x| (x, g2)).collect();
        let z2: Vec<Vec<f32>> = c.conv.forward_many(&per_sample);
        // phi(z1_i - z2_j) = phi_out(relu(z1_i W - z2_j W + b) m).
        let project = |z: &[f32], n: usize| -> Vec<f32> {
            let mut out = vec![0f32; n * r];
            product_rows(&c.phi_in, z, &mut out);
            out
        };
        let a = project(&z1, n1);
        let Some(kept) = &c.kept else {
            for (s, z2) in z2.iter().enumerate() {
                let b = project(z2, n2);
                let rows = &mut residual[s * n1 * n2..(s + 1) * n1 * n2];
                let masks = &phi[s * n1 * n2 * r..(s + 1) * n1 * n2 * r];
                per_entry_terms(c, [&a, &b], masks, [n1, n2], rows);
            }
            return;
        };
        // Per sample, the kept hidden units side by side: z1 W + b and z2 W
        // at them, and the output weight times the mask's value.
        let (mut a_kept, mut b_kept, mut w_kept, mut b_t) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (s, z2) in z2.iter().enumerate() {
            let b = project(z2, n2);
            let kept = &kept[s];
            a_kept.clear();
            for ai in a.chunks(r) {
                a_kept.extend(kept.iter().map(|&(u, _)| ai[u] + c.phi_in.bias[u]));
            }
            b_kept.clear();
            for bj in b.chunks(r) {
                b_kept.extend(kept.iter().map(|&(u, _)| bj[u]));
            }
            w_kept.clear();
            w_kept.extend(kept.iter().map(|&(u, m)| m * c.phi_out.weight[u]));
            let rows = &mut residual[s * n1 * n2..(s + 1) * n1 * n2];
            add_pair_terms(
                &a_kept,
                &b_kept,
                &w_kept,
                [n1, n2],
                c.phi_out.bias[0],
                rows,
                &mut b_t,
            );
        }
    }
}

/// The consensus MLP's term of every pair entry of one sample under masks
/// per entry and unit: `phi_out(relu(a_i + b_in - b_j) m_ij)`, `a` and
/// `b` both sides' `phi_in` products (`[n1, R]`, `[n2, R]`, no bias),
/// `masks` `[n1, n2, R]`.
fn per_entry_terms(
    c: &Consensus,
    [a, b]: [&[f32]; 2],
    masks: &[f32],
    [n1, n2]: [usize; 2],
    rows: &mut [f32],
) {
    let r = c.phi_in.d_out;
    let (bias, w_out) = (&c.phi_in.bias, &c.phi_out.weight);
    for i in 0..n1 {
        let ai = &a[i * r..(i + 1) * r];
        for j in 0..n2 {
            let bj = &b[j * r..(j + 1) * r];
            let m = &masks[(i * n2 + j) * r..(i * n2 + j + 1) * r];
            let mut sum = 0f32;
            for u in 0..r {
                let hidden = (ai[u] + bias[u] - bj[u]).max(0.0) * m[u];
                sum += hidden * w_out[u];
            }
            rows[i * n2 + j] += sum + c.phi_out.bias[0];
        }
    }
}
