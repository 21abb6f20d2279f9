//! GCN-GM's and DGMC's inference under shared masks (Eq. 8: one dropout
//! mask over psi_1's hidden channels per sample, the same for every node
//! of both graphs), in plain Rust: what [`super::model::PublishedNet`]
//! computes through the tensors (the reference it is held equal to, and
//! what training and per-node masks use), for one pair and its `T`
//! samples.
//!
//! What is done differently, exactly up to float rounding:
//! - psi_1's second layer multiplies only the hidden channels a sample
//!   keeps (the mask's value folded into the kept rows of its weights,
//!   gathered once per matcher), and a graph's embedding does not depend
//!   on its partner, so the MC shell keeps it for the
//!   graph's other pairs;
//! - every normalisation is Sinkhorn in the scaling domain, in f64
//!   ([`sinkhorn_probabilities`]: one `exp` per entry instead of two per
//!   entry and iteration), the same iterations as the log-domain tensor
//!   version up to its f32 rounding;
//! - DGMC's consensus MLP's first layer is linear before its bias, so
//!   `(o_s,i - o_t,j) W = o_s,i W - o_t,j W`: `n1 + n2` products per
//!   sample and step instead of `n1 n2`; psi_2 runs on every sample's
//!   indicators in one product per layer, its last layer folded into
//!   that first MLP layer, and the target graph's first product is the
//!   source's carried over by `S^T` ([`PlainConsensus`]);
//! - neighbours are mixed along the edges, not through a dense matrix.

use crate::matching::deep::graph::{KERNEL, LengthGraph};
use crate::matching::deep::kernels::lanes::{
    PlainLinear, add_pair_terms, relu, similarity, transport,
};
use crate::matching::deep::kernels::matmul;
use crate::matching::deep::kernels::sinkhorn::sinkhorn_probabilities;
use crate::matching::deep::kernels::spline;

/// A graph's edges grouped by destination, each group in edge order:
/// the source and its two knots' basis weights over the destination's
/// in-degree.
pub(crate) type Incoming = spline::Incoming<2>;

/// `g`'s [`Incoming`] edges on knots up to `scale_m`, as the tensor
/// path's mixing matrix weighs them.
fn incoming(g: &LengthGraph, scale_m: f64) -> Incoming {
    spline::Incoming::new(g.n, &g.weighted_edges(scale_m))
}

/// `buf` holding `len` values, for a product that overwrites them all: a
/// buffer reused across calls is only zeroed where it grows.
fn sized(buf: &mut Vec<f32>, len: usize) -> &mut [f32] {
    buf.truncate(len);
    buf.resize(len, 0.0);
    buf
}

/// Buffers a network's products reuse from one call to the next.
#[derive(Default)]
pub(crate) struct Buffers {
    y: Vec<f32>,
    h1: Vec<f32>,
    h2: Vec<f32>,
    joined: Vec<f32>,
}

/// Every buffer of an inference: kept per thread from one pair to the
/// next, so that a pair's products land in memory that is already there
/// (no allocation, no zeroing, no page faults).
#[derive(Default)]
struct Scratch {
    cnn: Buffers,
    /// A graph's first-layer output and its masked copy per sample.
    first: Vec<f32>,
    masked: Vec<f32>,
    r_t: Vec<f32>,
    y_s: Vec<f32>,
    y_t: Vec<f32>,
    /// The target rows' MLP projections transposed (`consensus_update`).
    b_t: Vec<f32>,
    a: Vec<f32>,
    b: Vec<f32>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::default();
}

/// A 1-D spline convolution as plain numbers: the root's and each knot's
/// weights side by side, `[in, (1 + KERNEL) out]`, and the bias.
pub(crate) struct Conv1d {
    d_in: usize,
    d_out: usize,
    joined: Vec<f32>,
    bias: Vec<f32>,
}

impl Conv1d {
    /// From the layer's `root` `[in, out]`, `weight` `[in, KERNEL out]`
    /// and `bias` `[out]`.
    pub(crate) fn new(root: &[f32], weight: &[f32], bias: Vec<f32>) -> Self {
        let d_out = bias.len();
        let d_in = root.len() / d_out.max(1);
        let mut joined = Vec::with_capacity(d_in * (1 + KERNEL) * d_out);
        for u in 0..d_in {
            joined.extend_from_slice(&root[u * d_out..(u + 1) * d_out]);
            joined.extend_from_slice(&weight[u * KERNEL * d_out..(u + 1) * KERNEL * d_out]);
        }
        Self {
            d_in,
            d_out,
            joined,
            bias,
        }
    }

    /// The layer on the input rows `kept` only, each row of weights times
    /// `scale`: a dropout mask over the input folded in.
    fn kept(&self, kept: &[usize], scale: f32) -> Self {
        let width = (1 + KERNEL) * self.d_out;
        let joined = kept
            .iter()
            .flat_map(|&u| {
                self.joined[u * width..(u + 1) * width]
                    .iter()
                    .map(|w| w * scale)
            })
            .collect();
        Self {
            d_in: kept.len(),
            d_out: self.d_out,
            joined,
            bias: self.bias.clone(),
        }
    }

    /// `relu(root x_i + sum_edges w x_j W_knot + bias)` of `blocks`
    /// stacked copies of a graph (`inc`), rows `x` (`[rows, in]`), into
    /// `out` (`[rows, out]`); `y` a reused buffer.
    fn relu_forward(
        &self,
        x: &[f32],
        (inc, blocks): (&Incoming, usize),
        y: &mut Vec<f32>,
        out: &mut Vec<f32>,
    ) {
        let rows = blocks * inc.n;
        let width = (1 + KERNEL) * self.d_out;
        let y = sized(y, rows * width);
        if rows > 0 && self.d_in > 0 {
            matmul(rows, self.d_in, width, x, &self.joined, y);
        } else {
            y.fill(0.0);
        }
        let out = sized(out, rows * self.d_out);
        mix_relu(y, width, (inc, blocks), &self.bias, out);
    }
}

/// The spline convolution's neighbourhood sum and ReLU: row `r` of `out`
/// is `relu((root_r + m_r) + bias)`, `m_r` the sum, from 0 in edge order,
/// of `w y_j,knot` over the edges into `r` (`y`: rows of `width >= (1 +
/// KERNEL) out` values that start with the root's and each knot's
/// products side by side).
#[multiversion::multiversion(targets("x86_64+avx+avx2"))]
fn mix_relu(
    y: &[f32],
    width: usize,
    (inc, blocks): (&Incoming, usize),
    bias: &[f32],
    out: &mut [f32],
) {
    let d = bias.len();
    for block in 0..blocks {
        for i in 0..inc.n {
            let mut c = 0;
            while c + 32 <= d {
                mix_columns::<32>(y, width, (inc, block, i), c, bias, out);
                c += 32;
            }
            while c < d {
                mix_columns::<1>(y, width, (inc, block, i), c, bias, out);
                c += 1;
            }
        }
    }
}

/// [`mix_relu`] for the `C` columns from `c` of node `i` of copy `block`:
/// the sum held in registers.
#[inline(always)]
fn mix_columns<const C: usize>(
    y: &[f32],
    width: usize,
    (inc, block, i): (&Incoming, usize, usize),
    c: usize,
    bias: &[f32],
    out: &mut [f32],
) {
    let (n, d) = (inc.n, bias.len());
    let mut m = [0f32; C];
    for &(j, cells) in inc.into(i) {
        let src = (block * n + j) * width + c;
        for (knot, w) in cells {
            let at = src + (1 + knot) * d;
            for (a, v) in m.iter_mut().zip(&y[at..at + C]) {
                *a += w * v;
            }
        }
    }
    let r = block * n + i;
    let root = &y[r * width + c..r * width + c + C];
    for (((o, &yv), &mv), &b) in out[r * d + c..r * d + c + C]
        .iter_mut()
        .zip(root)
        .zip(&m)
        .zip(&bias[c..c + C])
    {
        *o = relu((yv + mv) + b);
    }
}

/// `x W + b` of the stacked rows `x` (`[rows, in]`), into `out`.
fn linear_rows(l: &PlainLinear, x: &[f32], rows: usize, out: &mut Vec<f32>) {
    let out = sized(out, rows * l.d_out);
    if rows > 0 {
        matmul(rows, l.d_in, l.d_out, x, &l.weight, out);
    } else {
        out.fill(0.0);
    }
    for row in out.chunks_mut(l.d_out) {
        for (o, b) in row.iter_mut().zip(&l.bias) {
            *o += b;
        }
    }
}

/// DGMC's `SplineCNN` as plain numbers: two spline convolutions, then a
/// linear layer (psi_1: on the second's output; psi_2: on the input and
/// both outputs side by side).
pub(crate) struct PlainCnn {
    pub(crate) conv1: Conv1d,
    pub(crate) conv2: Conv1d,
    pub(crate) last: PlainLinear,
}

/// `a b` of `a` (`[rows, k]`) and `b.weight` (`[k, b.d_out]`), summed in
/// f64 and rounded once: a product of two weight matrices, folded once
/// per matcher.
fn fold(a: &[f32], rows: usize, b: &PlainLinear) -> Vec<f32> {
    let (k, n) = (b.d_in, b.d_out);
    let mut out = Vec::with_capacity(rows * n);
    for r in 0..rows {
        let row = &a[r * k..(r + 1) * k];
        out.extend((0..n).map(|c| {
            row.iter()
                .enumerate()
                .map(|(q, &v)| f64::from(v) * f64::from(b.weight[q * n + c]))
                .sum::<f64>() as f32
        }));
    }
    out
}

/// DGMC's consensus step (psi_2 with `cat`, then the MLP `rnd -> rnd -> 1`
/// on `o_s,i - o_t,j`) as plain numbers, reassociated; the same function
/// up to float rounding:
/// - psi_2's last layer and the MLP's first are both linear, so `o W_in =
///   x (W_x W_in) + [h1, h2] (W_h W_in) + b_last W_in` (`W_x`, `W_h` the
///   last layer's rows on the input and on the two convolutions), and
///   `b_last W_in` cancels in `o_s,i W_in - o_t,j W_in`;
/// - `x (W_x W_in)` rides in psi_2's first product as extra columns,
///   `x [root | knots | W_x W_in]`;
/// - the target's input is `S^T r_s`, so its first product is `S^T (r_s
///   J)`, the source's product carried over: `n1` multiply-adds per value
///   instead of `rnd`, taken when the source graph has at most `rnd`
///   nodes.
pub(crate) struct PlainConsensus {
    /// `[rnd, width]`: per input unit psi_2's first root and knot weights,
    /// then its row of `W_x W_in`.
    first: Vec<f32>,
    width: usize,
    rnd: usize,
    /// The most source nodes whose first product the target carries over
    /// (`rnd`: whichever multiplies less).
    carry_max: usize,
    conv1_bias: Vec<f32>,
    conv2: Conv1d,
    /// `[h1 + h2, mlp]`: `W_h W_in`.
    hidden_in: Vec<f32>,
    /// `b_in`, added to the source rows only.
    mlp_bias: Vec<f32>,
    pub(crate) mlp_out: PlainLinear,
}

impl PlainConsensus {
    /// psi_2 (`cat`) and the MLP's two layers.
    ///
    /// # Panics
    /// When the layers' widths do not chain (a network built wrong, not
    /// a weights file: those are checked against the shapes on loading).
    pub(crate) fn new(psi2: PlainCnn, mlp_in: &PlainLinear, mlp_out: PlainLinear) -> Self {
        let (rnd, h1) = (psi2.conv1.d_in, psi2.conv1.d_out);
        let hh = h1 + psi2.conv2.d_out;
        assert!(
            psi2.last.d_in == rnd + hh && psi2.last.d_out == mlp_in.d_in,
            "psi_2 with cat: its last layer reads [x, h1, h2] and feeds the MLP"
        );
        let mlp = mlp_in.d_out;
        let w_x = fold(&psi2.last.weight[..rnd * psi2.last.d_out], rnd, mlp_in);
        let hidden_in = fold(&psi2.last.weight[rnd * psi2.last.d_out..], hh, mlp_in);
        let conv_width = (1 + KERNEL) * h1;
        let width = conv_width + mlp;
        let mut first = Vec::with_capacity(rnd * width);
        for u in 0..rnd {
            first.extend_from_slice(&psi2.conv1.joined[u * conv_width..(u + 1) * conv_width]);
            first.extend_from_slice(&w_x[u * mlp..(u + 1) * mlp]);
        }
        Self {
            first,
            width,
            rnd,
            carry_max: rnd,
            conv1_bias: psi2.conv1.bias,
            conv2: psi2.conv2,
            hidden_in,
            mlp_bias: mlp_in.bias.clone(),
            mlp_out,
        }
    }

    /// Whether the target's first product is carried over from the
    /// source's (`S^T (r_s J)`) rather than multiplied anew (`(S^T r_s)
    /// J`): whichever multiplies less.
    fn carries(&self, n1: usize) -> bool {
        n1 <= self.carry_max
    }

    /// The MLP's first layer before its ReLU, `o W_in (+ b_in)`, of
    /// `blocks` stacked copies of a graph (`inc`) from their first
    /// products `y` (`[rows, width]`), into `out` (`[rows, mlp]`).
    fn project(
        &self,
        y: &[f32],
        g: (&Incoming, usize),
        source: bool,
        buf: &mut Buffers,
        out: &mut Vec<f32>,
    ) {
        let (inc, blocks) = g;
        let rows = inc.n * blocks;
        let h1 = self.conv1_bias.len();
        let h1_out = sized(&mut buf.h1, rows * h1);
        mix_relu(y, self.width, (inc, blocks), &self.conv1_bias, h1_out);
        self.conv2.relu_forward(&buf.h1, g, &mut buf.y, &mut buf.h2);
        let h2 = self.conv2.d_out;
        buf.joined.clear();
        for r in 0..rows {
            buf.joined.extend_from_slice(&buf.h1[r * h1..(r + 1) * h1]);
            buf.joined.extend_from_slice(&buf.h2[r * h2..(r + 1) * h2]);
        }
        let mlp = self.mlp_bias.len();
        let out = sized(out, rows * mlp);
        if rows > 0 {
            matmul(rows, h1 + h2, mlp, &buf.joined, &self.hidden_in, out);
        }
        let skip = self.width - mlp;
        for (o, yr) in out.chunks_mut(mlp).zip(y.chunks(self.width)) {
            for ((v, x), b) in o.iter_mut().zip(&yr[skip..]).zip(&self.mlp_bias) {
                *v += x;
                if source {
                    *v += b;
                }
            }
        }
    }
}

/// The network's parameters as plain numbers.
pub(crate) struct PlainWeights {
    pub(crate) psi1: PlainCnn,
    /// psi_2 and the consensus MLP (DGMC).
    pub(crate) consensus: Option<(PlainCnn, PlainLinear, PlainLinear)>,
    pub(crate) dustbin: f32,
}

/// The network with `T` samples per pair.
pub(crate) struct PlainPublished {
    psi1: PlainCnn,
    samples: usize,
    /// Under shared masks, psi_1's second layer per sample on the kept
    /// hidden channels.
    conv2_kept: Vec<(Vec<usize>, Conv1d)>,
    consensus: Option<PlainConsensus>,
    dustbin: f32,
    steps: usize,
    iters: usize,
    scale_m: f64,
}

impl PlainPublished {
    /// `w` with `samples` samples per pair, under the shared psi_1 masks
    /// `shared` (`[T, hidden]`, each value 0 or the sample's scale) or
    /// masks per node given with each graph ([`Self::embed_per_node`]),
    /// `steps` consensus steps (0 for GCN-GM), `iters` Sinkhorn
    /// iterations and knots up to `scale_m`.
    pub(crate) fn new(
        w: PlainWeights,
        samples: usize,
        shared: Option<&[f32]>,
        [steps, iters]: [usize; 2],
        scale_m: f64,
    ) -> Self {
        let hidden = w.psi1.conv1.d_out;
        let conv2_kept = shared
            .unwrap_or_default()
            .chunks(hidden.max(1))
            .map(|m| {
                let kept: Vec<usize> = (0..hidden).filter(|&u| m[u] != 0.0).collect();
                let scale = kept.first().map_or(0.0, |&u| m[u]);
                let layer = w.psi1.conv2.kept(&kept, scale);
                (kept, layer)
            })
            .collect();
        Self {
            psi1: w.psi1,
            samples,
            conv2_kept,
            consensus: w
                .consensus
                .map(|(psi2, mlp_in, mlp_out)| PlainConsensus::new(psi2, &mlp_in, mlp_out)),
            dustbin: w.dustbin,
            steps,
            iters,
            scale_m,
        }
    }

    /// The target's first product always multiplied anew, `(S^T r_s) J`
    /// (tests: the branch large source graphs take).
    #[cfg(test)]
    pub(crate) fn never_carry(&mut self) {
        if let Some(c) = &mut self.consensus {
            c.carry_max = 0;
        }
    }

    /// Samples this network draws.
    pub(crate) fn samples(&self) -> usize {
        self.samples
    }

    /// `relu(conv1(x))` of `g` into `h1` (`[n, hidden]`, the same in
    /// every sample), and `g`'s edges.
    fn first_layer(&self, g: &LengthGraph, buf: &mut Buffers, h1: &mut Vec<f32>) -> Incoming {
        let inc = incoming(g, self.scale_m);
        self.psi1
            .conv1
            .relu_forward(&g.node_features, (&inc, 1), &mut buf.y, h1);
        inc
    }

    /// psi_1's embedding of `g` in every sample under masks per node and
    /// hidden channel (`mask`: `[T, n, hidden]`), `[T, n, out]`: every
    /// sample's rows in one product per layer.
    pub(crate) fn embed_per_node(&self, g: &LengthGraph, mask: &[f32]) -> Vec<f32> {
        SCRATCH.with_borrow_mut(|s| {
            let inc = self.first_layer(g, &mut s.cnn, &mut s.first);
            let hidden = self.psi1.conv1.d_out;
            s.masked.clear();
            if hidden > 0 && !s.first.is_empty() {
                for (m, h) in mask.chunks(hidden).zip(s.first.chunks(hidden).cycle()) {
                    s.masked.extend(h.iter().zip(m).map(|(v, m)| v * m));
                }
            }
            self.psi1.conv2.relu_forward(
                &s.masked,
                (&inc, self.samples),
                &mut s.cnn.y,
                &mut s.cnn.h2,
            );
            let mut out = Vec::new();
            linear_rows(&self.psi1.last, &s.cnn.h2, self.samples * g.n, &mut out);
            out
        })
    }

    /// psi_1's embedding of `g` in every sample under the shared masks,
    /// `[T, n, out]`.
    pub(crate) fn embed(&self, g: &LengthGraph) -> Vec<f32> {
        let n = g.n;
        SCRATCH.with_borrow_mut(|s| {
            let inc = self.first_layer(g, &mut s.cnn, &mut s.first);
            let hidden = self.psi1.conv1.d_out;
            let mut out = Vec::with_capacity(self.samples() * n * self.psi1.last.d_out);
            for (kept, layer) in &self.conv2_kept {
                s.masked.clear();
                for row in s.first.chunks(hidden) {
                    s.masked.extend(kept.iter().map(|&u| row[u]));
                }
                layer.relu_forward(&s.masked, (&inc, 1), &mut s.cnn.y, &mut s.cnn.h2);
                linear_rows(&self.psi1.last, &s.cnn.h2, n, &mut s.a);
                out.extend_from_slice(&s.a);
            }
            out
        })
    }

    /// The soft assignments of the samples, each `(n1 + 1) x (n2 + 1)`:
    /// `h1` and `h2` the two graphs' embeddings ([`Self::embed`]),
    /// `indicators` one `[T, n1, rnd_dim]` draw per consensus step.
    pub(crate) fn assignments(
        &self,
        [(h1, g1), (h2, g2)]: [(&[f32], &LengthGraph); 2],
        indicators: &[Vec<f32>],
    ) -> Vec<Vec<f32>> {
        let (n1, n2, t) = (g1.n, g2.n, self.samples());
        let mut s_hat = similarity(h1, h2, [t, n1, n2]);
        let mut p = self.normalise(&s_hat, [t, n1, n2]);
        if let Some(c) = &self.consensus {
            let (inc1, inc2) = (incoming(g1, self.scale_m), incoming(g2, self.scale_m));
            let (w, rnd) = (c.width, c.rnd);
            SCRATCH.with_borrow_mut(|s| {
                for r_s in indicators.iter().take(self.steps) {
                    let y_s = sized(&mut s.y_s, t * n1 * w);
                    if !y_s.is_empty() {
                        matmul(t * n1, rnd, w, r_s, &c.first, y_s);
                    }
                    // The target's first product from its indicators
                    // S^T r_s per sample, S the real block of the current
                    // assignment.
                    let y_t = sized(&mut s.y_t, t * n2 * w);
                    if c.carries(n1) {
                        transport(&p, 1, &s.y_s, [w, n1 * w], [t, n1, n2], y_t);
                    } else {
                        let r_t = sized(&mut s.r_t, t * n2 * rnd);
                        transport(&p, 1, r_s, [rnd, n1 * rnd], [t, n1, n2], r_t);
                        if !y_t.is_empty() {
                            matmul(t * n2, rnd, w, r_t, &c.first, y_t);
                        }
                    }
                    c.project(&s.y_s, (&inc1, t), true, &mut s.cnn, &mut s.a);
                    c.project(&s.y_t, (&inc2, t), false, &mut s.cnn, &mut s.b);
                    consensus_update(&s.a, &s.b, &c.mlp_out, [t, n1, n2], &mut s_hat, &mut s.b_t);
                    p = self.normalise(&s_hat, [t, n1, n2]);
                }
            });
        }
        p.chunks_exact((n1 + 1) * (n2 + 1))
            .map(<[f32]>::to_vec)
            .collect()
    }

    /// Dustbin Sinkhorn of the scores, every node's and the corner's "no
    /// match" score the learned one.
    fn normalise(&self, s_hat: &[f32], [t, n1, n2]: [usize; 3]) -> Vec<f32> {
        let scores: Vec<f64> = s_hat.iter().map(|&v| f64::from(v)).collect();
        let bin = f64::from(self.dustbin);
        let (d1, d2) = (vec![bin; n1], vec![bin; n2]);
        sinkhorn_probabilities(&scores, [t, n1, n2], [&d1, &d2], bin, self.iters)
    }
}

/// `S_hat_ij += mlp_out(relu(a_i - b_j))` per sample: `a` the source
/// rows' projections with the first layer's bias, `b` the target rows'
/// ([`add_pair_terms`] per sample, `b_t` its reused buffer).
fn consensus_update(
    a: &[f32],
    b: &[f32],
    mlp_out: &PlainLinear,
    [t, n1, n2]: [usize; 3],
    s_hat: &mut [f32],
    b_t: &mut Vec<f32>,
) {
    let h = mlp_out.d_in;
    for s in 0..t {
        add_pair_terms(
            &a[s * n1 * h..(s + 1) * n1 * h],
            &b[s * n2 * h..(s + 1) * n2 * h],
            &mlp_out.weight,
            [n1, n2],
            mlp_out.bias[0],
            &mut s_hat[s * n1 * n2..(s + 1) * n1 * n2],
            b_t,
        );
    }
}
