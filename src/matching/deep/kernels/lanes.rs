//! Lane kernels of the plain inference paths: linear layers as plain
//! numbers, ReLU, sums in interleaved lanes (so that the compiler
//! vectorises them), soft-correspondence products and the pair terms the
//! consensus adds. The networks' plain paths (`ours`, `published`) share
//! them.

/// A linear layer as plain numbers: `y = x W + b`, `W` `[in, out]`
/// row-major (burn's layout).
pub(crate) struct PlainLinear {
    pub(crate) d_in: usize,
    pub(crate) d_out: usize,
    pub(crate) weight: Vec<f32>,
    pub(crate) bias: Vec<f32>,
}

impl PlainLinear {
    /// `x W` of one input row into `out` (before the bias).
    pub(crate) fn product(&self, x: &[f32], out: &mut [f32]) {
        out.fill(0.0);
        for (f, &v) in x.iter().enumerate().take(self.d_in) {
            let row = &self.weight[f * self.d_out..(f + 1) * self.d_out];
            for (o, w) in out.iter_mut().zip(row) {
                *o += v * w;
            }
        }
    }

    /// `relu(x W + b)` of one input row into `out`.
    pub(crate) fn relu_row(&self, x: &[f32], out: &mut [f32]) {
        self.product(x, out);
        for (o, b) in out.iter_mut().zip(&self.bias) {
            *o = relu(*o + b);
        }
    }
}

/// burn's ReLU (NaN passes through).
pub(crate) fn relu(x: f32) -> f32 {
    if x.is_nan() || x > 0.0 { x } else { 0.0 }
}

/// Lanes of the reductions below: independent partial sums the compiler
/// keeps in one vector register.
pub(crate) const LANES: usize = 8;

/// `sum_k f(a_k, b_k, w_k)` over three slices of one length, in
/// [`LANES`] interleaved partial sums.
#[inline(always)]
pub(crate) fn lane_sum(a: &[f32], b: &[f32], w: &[f32], f: impl Fn(f32, f32, f32) -> f32) -> f32 {
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
pub(crate) fn product_rows(l: &PlainLinear, x: &[f32], out: &mut [f32]) {
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
pub(crate) fn transport(
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
pub(crate) fn add_pair_terms(
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
pub(crate) fn similarity(h1: &[f32], h2: &[f32], [t, n1, n2]: [usize; 3]) -> Vec<f32> {
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
