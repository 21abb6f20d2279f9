//! Fitting the published networks (burn autodiff, Adam), as DGMC's code
//! does: the negative log-likelihood of the true correspondences under
//! `S_0` plus the same under `S_L` (DGMC), each dropout sample a draw of
//! its own. Graphs only partly overlap, so the dustbins carry labels too:
//! a node with no true partner should go to its dustbin (DGMC's code,
//! which has no dustbin, leaves such nodes out of the loss). The paper's
//! method and its ablations add its Eq. 12 (`L_non`) and Eq. 13 (`L_unc`)
//! on the mean over the samples of the network's answer (`S_L`).

use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::prelude::*;
use rand_chacha::ChaCha8Rng;

use super::examples::Example;
use super::init::Init;
use super::loss::{non_term, unc_term};
use super::published_net::{PublishedNet, draw_training_masks};
use super::spline::GraphTensors;
use super::weights::module_bytes;
use crate::matching::deep::arch::{
    LossTerms, MaskScope, NoMatchWeights, PairLoss, PublishedConfig,
};
use crate::matching::deep::graph::LengthGraph;
use crate::rng::{self, Purpose};

/// A labelled training pair: two graphs and the true partner in `second`
/// of each node of `first` (`None`: not seen by the second vehicle).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct TrainPair {
    pub(crate) first: LengthGraph,
    pub(crate) second: LengthGraph,
    pub(crate) partner: Vec<Option<usize>>,
}

impl TrainPair {
    /// The paper's inputs of a labelled pair: both vehicles' graphs (body
    /// frames, appearance, edge lengths) and the true partners; the
    /// reported poses are left behind.
    /// (`cfg`: the network's graph and appearance width.)
    pub(crate) fn of(e: &Example, cfg: &PublishedConfig) -> Self {
        let mut partner = vec![None; e.first.detections.len()];
        for &(a, b) in &e.true_pairs {
            partner[a] = Some(b);
        }
        let graph = |s: &super::examples::OwnedView| {
            LengthGraph::lengths(&s.detections, &s.graph, cfg.graph, cfg.appearance_width)
        };
        Self {
            first: graph(&e.first),
            second: graph(&e.second),
            partner,
        }
    }
}

/// `[B, N1, N2]` of Eq. 12 and 13: 1 where row i or column j is a
/// non-covisible object, and 1 for every entry between real nodes; and
/// `[B]` the real entries of each pair.
fn covisibility(
    batch: &[&TrainPair],
    [n1, n2]: [usize; 2],
    device: &Device,
) -> (Tensor<3>, Tensor<3>, Tensor<1>) {
    let b = batch.len();
    let (mut non, mut real) = (vec![0f32; b * n1 * n2], vec![0f32; b * n1 * n2]);
    let mut counts = Vec::with_capacity(b);
    for (k, p) in batch.iter().enumerate() {
        let mut col_has = vec![false; p.second.n];
        p.partner.iter().flatten().for_each(|&j| col_has[j] = true);
        for i in 0..p.first.n {
            for (j, &has) in col_has.iter().enumerate() {
                let at = k * n1 * n2 + i * n2 + j;
                real[at] = 1.0;
                if p.partner[i].is_none() || !has {
                    non[at] = 1.0;
                }
            }
        }
        counts.push(((p.first.n * p.second.n) as f32).max(1.0));
    }
    let t3 = |v: Vec<f32>| Tensor::<3>::from_data(TensorData::new(v, [b, n1, n2]), device);
    let n_real = Tensor::<1>::from_data(TensorData::new(counts, [b]), device);
    (t3(non), t3(real), n_real)
}

impl TrainPair {
    /// The padded cost of the pair, for grouping pairs of similar size.
    pub(crate) fn padded_size(&self) -> usize {
        self.first.n.max(self.second.n)
    }
}

/// `[B, 1, N1 + 1, N2 + 1]` weights of the labelled entries (true pairs,
/// and the dustbin entry of every real node without a partner), each
/// pair's weights summing to 1: every entry alike, or the true pairs and
/// the dustbins each a half (a half without entries is left out, as
/// `ours`'s loss leaves it at 0).
fn label_weights(
    batch: &[&TrainPair],
    [n1, n2]: [usize; 2],
    no_match: NoMatchWeights,
    device: &Device,
) -> Tensor<4> {
    let (rows, cols) = (n1 + 1, n2 + 1);
    let mut w = vec![0f32; batch.len() * rows * cols];
    for (k, p) in batch.iter().enumerate() {
        let block = &mut w[k * rows * cols..(k + 1) * rows * cols];
        let mut taken = vec![false; p.second.n];
        for (i, partner) in p.partner.iter().enumerate() {
            match *partner {
                Some(j) => {
                    block[i * cols + j] = 1.0;
                    taken[j] = true;
                }
                None => block[i * cols + n2] = 1.0,
            }
        }
        for (j, _) in taken.iter().enumerate().filter(|(_, t)| !**t) {
            block[n1 * cols + j] = 1.0;
        }
        match no_match {
            NoMatchWeights::Entries => {
                let total: f32 = block.iter().sum();
                block.iter_mut().for_each(|v| *v /= total.max(1.0));
            }
            NoMatchWeights::Halves => {
                let dustbin = |at: usize| at / cols == n1 || at % cols == n2;
                let count = |bin: bool| {
                    let labelled = block
                        .iter()
                        .enumerate()
                        .filter(|&(at, v)| *v > 0.0 && dustbin(at) == bin);
                    labelled.count().max(1) as f32
                };
                let (pairs, bins) = (count(false), count(true));
                for (at, v) in block.iter_mut().enumerate() {
                    *v *= 0.5 / if dustbin(at) { bins } else { pairs };
                }
            }
        }
    }
    Tensor::from_data(TensorData::new(w, [batch.len(), 1, rows, cols]), device)
}

/// `[B, N1, N2]` 1 for each true pair, and `[B]` the true pairs of each
/// pair of graphs (at least 1).
fn true_pairs(
    batch: &[&TrainPair],
    [n1, n2]: [usize; 2],
    device: &Device,
) -> (Tensor<3>, Tensor<1>) {
    let b = batch.len();
    let mut y = vec![0f32; b * n1 * n2];
    let mut counts = Vec::with_capacity(b);
    for (k, p) in batch.iter().enumerate() {
        let mut n = 0usize;
        for (i, j) in p.partner.iter().enumerate() {
            if let Some(j) = *j {
                y[k * n1 * n2 + i * n2 + j] = 1.0;
                n += 1;
            }
        }
        counts.push(n.max(1) as f32);
    }
    (
        Tensor::from_data(TensorData::new(y, [b, n1, n2]), device),
        Tensor::from_data(TensorData::new(counts, [b]), device),
    )
}

/// The mean negative log-likelihood of the labels under log assignments
/// `[B, T, N1 + 1, N2 + 1]`, over pairs and samples.
fn nll(log_p: Tensor<4>, weights: &Tensor<4>) -> Tensor<1> {
    let [b, t, _, _] = log_p.dims();
    -(log_p * weights.clone()).sum() / (b * t) as f32
}

/// A published network being trained, with its optimiser and stream.
pub(crate) struct PublishedTrainer {
    pub(crate) cfg: PublishedConfig,
    /// Eq. 12 and 13 on top of the NLL (the pair term is the NLL).
    terms: LossTerms,
    /// Dropout samples per training pair.
    samples: usize,
    /// How the NLL weighs "no match" against true pairs.
    pub(crate) no_match: NoMatchWeights,
    /// How the dropout masks are drawn.
    masks: MaskScope,
    net: PublishedNet,
    optim: ModuleOptimizer,
    device: Device,
    /// Shuffling, dropout masks and indicators: `(seed, Training,
    /// hash("published"), hash(kind))`.
    stream: ChaCha8Rng,
}

impl PublishedTrainer {
    /// A fresh network (initial weights from `seed`) trained on the NLL
    /// alone, one dropout sample per pair (as published).
    #[cfg(test)]
    pub(crate) fn new(cfg: PublishedConfig, seed: u64) -> Self {
        let terms = LossTerms {
            pairs: PairLoss::Likelihood,
            non: false,
            unc: false,
        };
        Self::with_terms(cfg, terms, 1, MaskScope::PerNode, seed, "")
    }

    /// A fresh network trained with `terms` on `samples` dropout samples
    /// per pair, masks drawn as `masks` says; `name` (the method's label)
    /// keys its stream.
    pub(crate) fn with_terms(
        cfg: PublishedConfig,
        terms: LossTerms,
        samples: usize,
        masks: MaskScope,
        seed: u64,
        name: &str,
    ) -> Self {
        let device = crate::matching::deep::train::backend::device().autodiff();
        let kind = format!("{:?}{name}", cfg.kind);
        Self {
            net: PublishedNet::new(&cfg, Init::Seeded(seed), &device),
            cfg,
            terms,
            samples: samples.max(1),
            no_match: NoMatchWeights::Entries,
            masks,
            optim: AdamConfig::new().init(),
            device,
            stream: rng::stream(
                seed,
                Purpose::Training,
                &[rng::hash_str("published"), rng::hash_str(&kind)],
            ),
        }
    }

    /// Starts from the weights `bytes` (a `.bpk` of this network) instead
    /// of the seeded start.
    pub(crate) fn start_from(&mut self, bytes: &[u8]) -> Result<(), String> {
        let specs = crate::matching::deep::published::spec(&self.cfg);
        let params = crate::matching::deep::params::Params::from_bytes(bytes, &specs)
            .map_err(|e| format!("the starting weights do not fit the network ({e})"))?;
        self.net = PublishedNet::from_params(&self.cfg, &params, &specs, &self.device);
        Ok(())
    }

    /// The loss of `batch` on `net` with masks from `stream`: NLL under
    /// `S_0`, plus under `S_L` with consensus, plus Eq. 12 and 13 on the
    /// mean answer when the terms have them.
    fn loss(
        &self,
        net: &PublishedNet,
        device: &Device,
        batch: &[&TrainPair],
        stream: &mut ChaCha8Rng,
    ) -> Tensor<1> {
        let scale = self.cfg.edge_scale_m;
        let firsts: Vec<&LengthGraph> = batch.iter().map(|p| &p.first).collect();
        let seconds: Vec<&LengthGraph> = batch.iter().map(|p| &p.second).collect();
        let g1 = GraphTensors::lengths(&firsts, scale, device);
        let g2 = GraphTensors::lengths(&seconds, scale, device);
        let (n1, n2) = (g1.n(), g2.n());
        let b = batch.len();
        let masks = draw_training_masks(
            stream,
            &self.cfg,
            [b, self.samples, n1, n2],
            self.masks,
            device,
        );
        let out = net.forward(&self.cfg, [&g1, &g2], masks);
        let refined = out.refined.is_some();
        let last = out.refined.clone().unwrap_or_else(|| out.initial.clone());
        // P = E[Y]: the mean over the samples of the network's answer,
        // its real block.
        let p = last
            .clone()
            .exp()
            .mean_dim(1)
            .reshape([b, n1 + 1, n2 + 1])
            .slice([0..b, 0..n1, 0..n2]);
        let mut loss = match self.terms.pairs {
            PairLoss::Likelihood => {
                let weights = label_weights(batch, [n1, n2], self.no_match, device);
                let mut l = nll(out.initial, &weights);
                if refined {
                    l = l + nll(last, &weights);
                }
                l
            }
            PairLoss::Paper => {
                // Eq. 11 on E[Y]: -log(sum(P o Y*) / n_true), n_true
                // in place of the paper's n n' (a constant per pair).
                let (y, n_true) = true_pairs(batch, [n1, n2], device);
                let matched = (p.clone() * y).sum_dims_squeeze::<1, usize>(&[1, 2]) / n_true;
                -matched.clamp_min(1e-9).log().mean()
            }
        };
        if self.terms.non || self.terms.unc {
            let (non, real, n_real) = covisibility(batch, [n1, n2], device);
            if self.terms.non {
                loss = loss + non_term(p.clone(), &non, &real, n_real.clone()).mean();
            }
            if self.terms.unc {
                loss = loss + unc_term(p, &real, n_real).mean();
            }
        }
        loss
    }

    /// One Adam step on `batch` at learning rate `lr`; the loss before it.
    pub(crate) fn step(&mut self, batch: &[&TrainPair], lr: f64) -> Result<f32, String> {
        let mut stream = self.stream.clone();
        let loss = self.loss(&self.net, &self.device, batch, &mut stream);
        self.stream = stream;
        crate::matching::deep::train::descend(&mut self.optim, &mut self.net, loss, lr)
    }

    /// `epochs` passes over `pairs` in shuffled batches of `batch_size` at
    /// learning rate `lr`; each epoch's mean loss.
    #[cfg(test)]
    pub(crate) fn fit(
        &mut self,
        pairs: &[TrainPair],
        epochs: usize,
        batch_size: usize,
        lr: f64,
    ) -> Result<Vec<f32>, String> {
        use rand::seq::SliceRandom;
        let mut losses = Vec::with_capacity(epochs);
        let mut order: Vec<usize> = (0..pairs.len()).collect();
        for _ in 0..epochs {
            order.shuffle(&mut self.stream);
            let mut sum = 0.0;
            for chunk in order.chunks(batch_size.max(1)) {
                let batch: Vec<&TrainPair> = chunk.iter().map(|&k| &pairs[k]).collect();
                sum += self.step(&batch, lr)? * batch.len() as f32;
            }
            losses.push(sum / pairs.len().max(1) as f32);
        }
        Ok(losses)
    }

    /// The batches of one training epoch over pairs of these padded sizes
    /// (shuffled, grouped by size as the project's trainer does).
    pub(crate) fn epoch_batches(&mut self, sizes: &[usize], batch_size: usize) -> Vec<Vec<usize>> {
        crate::matching::deep::train::batches(sizes, batch_size, Some(&mut self.stream))
    }

    /// The mean loss over `pairs` without changing the network: masks from
    /// a stream that is the same at every call, so that values of
    /// different epochs compare.
    pub(crate) fn validation_loss(&self, pairs: &[TrainPair], seed: u64, batch_size: usize) -> f64 {
        let mut stream = rng::stream(seed, Purpose::Training, &[rng::hash_str("validation")]);
        let net = self.net.valid();
        let device = crate::matching::deep::train::backend::device();
        let sizes: Vec<usize> = pairs.iter().map(TrainPair::padded_size).collect();
        let mut sum = 0.0;
        for batch in crate::matching::deep::train::batches(&sizes, batch_size, None) {
            let batch: Vec<&TrainPair> = batch.iter().map(|&k| &pairs[k]).collect();
            let loss = self.loss(&net, &device, &batch, &mut stream);
            sum += f64::from(loss.into_scalar::<f32>()) * batch.len() as f64;
        }
        sum / pairs.len().max(1) as f64
    }

    /// The weights as bytes (what a `.bpk` file holds).
    pub(crate) fn weights(&self) -> Result<Vec<u8>, String> {
        module_bytes(&self.net)
    }

    /// The trained network for inference (no autodiff).
    #[cfg(test)]
    pub(crate) fn network(&self) -> PublishedNet {
        self.net.valid()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Labelled entries: true pairs and the dustbins of nodes without a
    /// partner, on both sides, padding left out; each pair's weights sum
    /// to 1.
    #[test]
    fn labels_cover_true_pairs_and_both_dustbins() {
        let device = crate::matching::deep::train::backend::device();
        let graph = |n: usize| LengthGraph {
            n,
            node_features: vec![0.0; n * crate::matching::deep::features::NODE_FEATURES],
            node_width: crate::matching::deep::features::NODE_FEATURES,
            src: vec![],
            dst: vec![],
            edge_m: vec![],
        };
        let pair = TrainPair {
            first: graph(2),
            second: graph(2),
            partner: vec![Some(1), None],
        };
        let w: Vec<f32> = label_weights(&[&pair], [3, 2], NoMatchWeights::Entries, &device)
            .try_into_vec_as::<f32>()
            .unwrap();
        // 4 x 3: rows 0, 1 real, 2 padding, 3 dustbin; 3 labels.
        let mut expected = vec![0f32; 12];
        expected[1] = 1.0 / 3.0; // (0, 1)
        expected[3 + 2] = 1.0 / 3.0; // row 1 -> dustbin
        expected[9] = 1.0 / 3.0; // column 0 -> dustbin
        assert_eq!(w.len(), 12);
        for (k, (g, e)) in w.iter().zip(&expected).enumerate() {
            assert!((g - e).abs() < 1e-7, "entry {k}: {g} vs {e}");
        }
        // Halves: the one true pair a half, the two dustbins a quarter each.
        let w: Vec<f32> = label_weights(&[&pair], [3, 2], NoMatchWeights::Halves, &device)
            .try_into_vec_as::<f32>()
            .unwrap();
        expected[1] = 0.5;
        expected[3 + 2] = 0.25;
        expected[9] = 0.25;
        for (k, (g, e)) in w.iter().zip(&expected).enumerate() {
            assert!((g - e).abs() < 1e-7, "halves, entry {k}: {g} vs {e}");
        }
    }
}
