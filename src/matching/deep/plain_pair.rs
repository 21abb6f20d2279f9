//! The pair part of the network at inference under shared masks
//! ([`super::arch::MaskScope::Shared`]), in plain Rust: what
//! [`super::network::Network::pair`] computes through the tensors (the
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

use super::features::{GraphInput, PairInput};
use super::network::Combination;
use super::shared_conv::{PlainSpline, SharedMaskConv};
use super::sinkhorn::BLOCKED;

/// A linear layer as plain numbers: `y = x W + b`, `W` `[in, out]`
/// row-major (burn's layout).
pub(super) struct PlainLinear {
    pub d_in: usize,
    pub d_out: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

impl PlainLinear {
    /// `x W` of one input row into `out` (before the bias).
    fn product(&self, x: &[f32], out: &mut [f32]) {
        out.fill(0.0);
        for (f, &v) in x.iter().enumerate().take(self.d_in) {
            let row = &self.weight[f * self.d_out..(f + 1) * self.d_out];
            for (o, w) in out.iter_mut().zip(row) {
                *o += v * w;
            }
        }
    }

    /// `relu(x W + b)` of one input row into `out`.
    fn relu_row(&self, x: &[f32], out: &mut [f32]) {
        self.product(x, out);
        for (o, b) in out.iter_mut().zip(&self.bias) {
            *o = relu(*o + b);
        }
    }
}

/// burn's ReLU (NaN passes through).
pub(super) fn relu(x: f32) -> f32 {
    if x.is_nan() || x > 0.0 { x } else { 0.0 }
}

/// Lanes of the reductions below: independent partial sums the compiler
/// keeps in one vector register.
pub(super) const LANES: usize = 8;

/// `sum_k f(a_k, b_k, w_k)` over three slices of one length, in
/// [`LANES`] interleaved partial sums.
#[inline(always)]
pub(super) fn lane_sum(a: &[f32], b: &[f32], w: &[f32], f: impl Fn(f32, f32, f32) -> f32) -> f32 {
    let mut acc = [0f32; LANES];
    let (ca, ra) = a.as_chunks::<LANES>();
    let (cb, rb) = b.as_chunks::<LANES>();
    let (cw, rw) = w.as_chunks::<LANES>();
    for ((x, y), z) in ca.iter().zip(cb).zip(cw) {
        for l in 0..LANES {
            acc[l] += f(x[l], y[l], z[l]);
        }
    }
    for (l, ((x, y), z)) in ra.iter().zip(rb).zip(rw).enumerate() {
        acc[l] += f(*x, *y, *z);
    }
    acc.iter().sum()
}

/// `x W` (before the bias) of every `d_in`-wide row of `x` into the rows
/// of `out`, each as [`PlainLinear::product`] sums it.
#[multiversion::multiversion(targets("x86_64+avx+avx2"))]
fn product_rows(l: &PlainLinear, x: &[f32], out: &mut [f32]) {
    for (x, y) in x.chunks(l.d_in.max(1)).zip(out.chunks_mut(l.d_out.max(1))) {
        l.product(x, y);
    }
}

/// `dst = S^T src` per sample: `S` the `n1 x n2` block of each sample's
/// assignment in `p` (samples of `(n1 + bins) x (n2 +
/// bins)`, a dustbin row and column when `bins` is 1), `src` rows of
/// `width` values, sample `s`'s `n1` rows from `s * src_sample` (0: one
/// `src` for every sample), `dst` `[T n2, width]`. Each value summed from
/// 0 in order of `i`, 32 columns at a time held in registers.
#[multiversion::multiversion(targets("x86_64+avx+avx2"))]
pub(super) fn transport(
    p: &[f32],
    bins: usize,
    src: &[f32],
    [width, src_sample]: [usize; 2],
    [t, n1, n2]: [usize; 3],
    dst: &mut [f32],
) {
    let (rows, cols) = (n1 + bins, n2 + bins);
    for s in 0..t {
        let p = &p[s * rows * cols..(s + 1) * rows * cols];
        let src = &src[s * src_sample..s * src_sample + n1 * width];
        for j in 0..n2 {
            let dst = &mut dst[(s * n2 + j) * width..(s * n2 + j + 1) * width];
            let mut c = 0;
            while c + 32 <= width {
                transport_columns::<32>(p, src, [cols, j, width, c], dst);
                c += 32;
            }
            while c < width {
                transport_columns::<1>(p, src, [cols, j, width, c], dst);
                c += 1;
            }
        }
    }
}

/// [`transport`] for columns `c..c + C` of target `j` in one sample: `p`
/// the sample's assignment (rows of `cols`), `src` its `[n1, width]`
/// rows, `dst` the target's row.
#[inline(always)]
fn transport_columns<const C: usize>(
    p: &[f32],
    src: &[f32],
    [cols, j, width, c]: [usize; 4],
    dst: &mut [f32],
) {
    let mut acc = [0f32; C];
    for (i, row) in src.chunks_exact(width).enumerate() {
        let w = p[i * cols + j];
        for (a, v) in acc.iter_mut().zip(&row[c..c + C]) {
            *a += w * v;
        }
    }
    dst[c..c + C].copy_from_slice(&acc);
}

/// One sample's consensus pair terms on its kept hidden units (`q` =
/// `w.len()` of them, maybe none): `rows[i n2 + j] += lane_sum(a_i, b_j,
/// w, relu(x - y) w) + b_out`, `a` `[n1, q]` and `b` `[n2, q]`; eight
/// targets at a time through [`pair_sums`] (`b` transposed into `b_t`, a
/// reused buffer).
#[multiversion::multiversion(targets("x86_64+avx+avx2"))]
pub(super) fn add_pair_terms(
    a: &[f32],
    b: &[f32],
    w: &[f32],
    [n1, n2]: [usize; 2],
    b_out: f32,
    rows: &mut [f32],
    b_t: &mut Vec<f32>,
) {
    let q = w.len();
    // Targets padded to a multiple of 8 (the padding's sums unused).
    let padded = n2.div_ceil(8) * 8;
    b_t.clear();
    b_t.resize(q * padded, 0.0);
    for j in 0..n2 {
        for (k, v) in b[j * q..(j + 1) * q].iter().enumerate() {
            b_t[k * padded + j] = *v;
        }
    }
    for i in 0..n1 {
        let ai = &a[i * q..(i + 1) * q];
        let row = &mut rows[i * n2..(i + 1) * n2];
        for j in (0..n2).step_by(8) {
            let sums = pair_sums(ai, &b_t[j..], padded, w);
            for (out, s) in row[j..].iter_mut().zip(sums) {
                *out += s + b_out;
            }
        }
    }
}

/// The consensus sums of `ai` with the 8 targets whose transposed rows
/// start `b_t` (`stride` apart), `w` the output weights: `lane_sum(ai,
/// b_j, w, |x, y, w| relu(x - y) * w)` for each, bit for bit (the same
/// partial sums in the same order).
#[inline(always)]
fn pair_sums(ai: &[f32], b_t: &[f32], stride: usize, w: &[f32]) -> [f32; 8] {
    let h = ai.len();
    let mut acc = [[0f32; 8]; LANES];
    let chunks = h / LANES;
    // relu(d) as a select: d where !(d <= 0) (positive or NaN), else 0.
    let term = |x: f32, bk: &[f32], wk: f32, lane: &mut [f32; 8]| {
        let mut v = *lane;
        for (a, y) in v.iter_mut().zip(bk) {
            let d = x - y;
            *a += if d <= 0.0 { 0.0 } else { d } * wk;
        }
        *lane = v;
    };
    for c in 0..chunks {
        for (l, lane) in acc.iter_mut().enumerate() {
            let k = c * LANES + l;
            term(ai[k], &b_t[k * stride..k * stride + 8], w[k], lane);
        }
    }
    for (l, lane) in acc.iter_mut().enumerate().take(h - chunks * LANES) {
        let k = chunks * LANES + l;
        term(ai[k], &b_t[k * stride..k * stride + 8], w[k], lane);
    }
    std::array::from_fn(|q| acc.iter().map(|lane| lane[q]).sum())
}

/// Each sample's similarity `H1 H2^T` of two graphs' embeddings `h1`
/// (`[T, n1, d]`) and `h2` (`[T, n2, d]`): `[T, n1, n2]`.
pub(super) fn similarity(h1: &[f32], h2: &[f32], [t, n1, n2]: [usize; 3]) -> Vec<f32> {
    let d = (h1.len() / (t * n1).max(1)).max(1);
    let mut out = Vec::with_capacity(t * n1 * n2);
    for (a, b) in h1
        .chunks((n1 * d).max(1))
        .zip(h2.chunks((n2 * d).max(1)))
        .take(t)
    {
        for ai in a.chunks(d) {
            out.extend(b.chunks(d).map(|bj| lane_sum(ai, bj, bj, |x, y, _| x * y)));
        }
    }
    out
}

/// `exp(x)`, with the values whose f32 exponential is 0 (below about
/// -103.97) answered without the library's underflow path: the same bits.
fn exp_or_zero(x: f32) -> f32 {
    if x < -104.0 { 0.0 } else { x.exp() }
}

/// The pair part's parameters (as [`super::network::Network`] holds them).
pub(super) struct PairWeights {
    pub pair_in: PlainLinear,
    pub pair_out: PlainLinear,
    pub dust_in: PlainLinear,
    pub dust_out: PlainLinear,
    /// The consensus conv and MLP, when the network has consensus.
    pub consensus: Option<(PlainSpline, PlainLinear, PlainLinear)>,
    pub combination: Combination,
}

/// The consensus step under one set of shared masks.
struct Consensus {
    /// The spline convolution, every unit kept (one "sample").
    conv: SharedMaskConv,
    phi_in: PlainLinear,
    phi_out: PlainLinear,
    /// Per sample, the kept hidden units of `phi_in` and the mask's value
    /// on them.
    kept: Vec<Vec<(usize, f32)>>,
}

/// The pair part under `T` shared masks.
pub(super) struct PlainPair {
    /// The MLPs and scalars (its consensus moved into `consensus`).
    w: PairWeights,
    consensus: Option<Consensus>,
    samples: usize,
}

/// What the pair part says of one pair: the residual of every pair entry
/// in every sample, `[T, n1, n2]`, and each node's learned "no match"
/// score before its gate, per vehicle.
pub(super) struct PairResidual {
    pub residual: Vec<f32>,
    pub dust: [Vec<f32>; 2],
}

impl PlainPair {
    /// The pair part with `phi_mask` (`[T, R]`: each sample's consensus
    /// MLP mask, 0 or the sample's scale; ignored without consensus).
    pub(super) fn new(mut w: PairWeights, samples: usize, phi_mask: &[f32]) -> Self {
        let consensus = w.consensus.take().map(|(conv, phi_in, phi_out)| {
            let r = conv.d_out;
            let kept = (0..samples)
                .map(|t| {
                    let m = &phi_mask[t * r..(t + 1) * r];
                    (0..r).filter(|&u| m[u] != 0.0).map(|u| (u, m[u])).collect()
                })
                .collect();
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
    /// node indicators (unused without consensus).
    pub(super) fn forward(
        &self,
        (h1, g1): (&[f32], &GraphInput),
        (h2, g2): (&[f32], &GraphInput),
        input: &PairInput,
        indicators: &[f32],
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
            self.consensus(c, [g1, g2], input, indicators, &dust[0], &mut residual);
        }
        PairResidual { residual, dust }
    }

    /// Adds DGMC's consensus term (Eq. 3) to `residual` (`[T, n1, n2]`,
    /// the similarity and pair term so far).
    fn consensus(
        &self,
        c: &Consensus,
        [g1, g2]: [&GraphInput; 2],
        input: &PairInput,
        indicators: &[f32],
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
        let per_sample: Vec<(&[f32], &GraphInput)> = r2.chunks(n2 * r).map(|x| (x, g2)).collect();
        let z2: Vec<Vec<f32>> = c.conv.forward_many(&per_sample);
        // phi(z1_i - z2_j) = phi_out(relu(z1_i W - z2_j W + b) m).
        let project = |z: &[f32], n: usize| -> Vec<f32> {
            let mut out = vec![0f32; n * r];
            product_rows(&c.phi_in, z, &mut out);
            out
        };
        let a = project(&z1, n1);
        // Per sample, the kept hidden units side by side: z1 W + b and z2 W
        // at them, and the output weight times the mask's value.
        let (mut a_kept, mut b_kept, mut w_kept, mut b_t) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (s, z2) in z2.iter().enumerate() {
            let b = project(z2, n2);
            let kept = &c.kept[s];
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
