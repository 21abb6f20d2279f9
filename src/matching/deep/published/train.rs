//! Fitting the published networks (burn autodiff, Adam), as DGMC's code
//! does: the negative log-likelihood of the true correspondences under
//! `S_0` plus the same under `S_L` (DGMC), each dropout sample a draw of
//! its own. Graphs only partly overlap, so the dustbins carry labels too:
//! a node with no true partner should go to its dustbin (DGMC's code,
//! which has no dustbin, leaves such nodes out of the loss).

use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::conv::GraphTensors;
use super::graph::PaperGraph;
use super::model::{PublishedConfig, PublishedNet, draw_masks};
use crate::matching::deep::init::Init;
use crate::rng::{self, Purpose};

/// A labelled training pair: two graphs and the true partner in `second`
/// of each node of `first` (`None`: not seen by the second vehicle).
#[derive(Clone, Debug, PartialEq)]
pub struct TrainPair {
    pub first: PaperGraph,
    pub second: PaperGraph,
    pub partner: Vec<Option<usize>>,
}

/// `[B, 1, N1 + 1, N2 + 1]` weights of the labelled entries (true pairs,
/// and the dustbin entry of every real node without a partner), each
/// pair's weights summing to 1.
fn label_weights(batch: &[&TrainPair], [n1, n2]: [usize; 2], device: &Device) -> Tensor<4> {
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
        let total: f32 = block.iter().sum();
        block.iter_mut().for_each(|v| *v /= total.max(1.0));
    }
    Tensor::from_data(TensorData::new(w, [batch.len(), 1, rows, cols]), device)
}

/// The mean negative log-likelihood of the labels under log assignments
/// `[B, T, N1 + 1, N2 + 1]`, over pairs and samples.
fn nll(log_p: Tensor<4>, weights: &Tensor<4>) -> Tensor<1> {
    let [b, t, _, _] = log_p.dims();
    -(log_p * weights.clone()).sum() / (b * t) as f32
}

/// A published network being trained, with its optimiser and stream.
pub struct PublishedTrainer {
    pub cfg: PublishedConfig,
    net: PublishedNet,
    optim: ModuleOptimizer,
    device: Device,
    /// Shuffling, dropout masks and indicators: `(seed, Training,
    /// hash("published"), hash(kind))`.
    stream: ChaCha8Rng,
}

impl PublishedTrainer {
    /// A fresh network (initial weights from `seed`).
    pub fn new(cfg: PublishedConfig, seed: u64) -> Self {
        let device = Device::flex().autodiff();
        let kind = format!("{:?}", cfg.kind);
        Self {
            net: PublishedNet::new(&cfg, Init::Seeded(seed), &device),
            cfg,
            optim: AdamConfig::new().init(),
            device,
            stream: rng::stream(
                seed,
                Purpose::Training,
                &[rng::hash_str("published"), rng::hash_str(&kind)],
            ),
        }
    }

    /// The loss of `batch`: NLL under `S_0`, plus under `S_L` with
    /// consensus.
    fn loss(&mut self, batch: &[&TrainPair]) -> Tensor<1> {
        let scale = self.cfg.edge_scale_m;
        let firsts: Vec<&PaperGraph> = batch.iter().map(|p| &p.first).collect();
        let seconds: Vec<&PaperGraph> = batch.iter().map(|p| &p.second).collect();
        let g1 = GraphTensors::new(&firsts, scale, &self.device);
        let g2 = GraphTensors::new(&seconds, scale, &self.device);
        let (n1, n2) = (g1.n(), g2.n());
        let masks = draw_masks(
            &mut self.stream,
            &self.cfg,
            [batch.len(), 1, n1, n2],
            true,
            &self.device,
        );
        let weights = label_weights(batch, [n1, n2], &self.device);
        let out = self.net.forward(&self.cfg, [&g1, &g2], masks);
        let mut loss = nll(out.initial, &weights);
        if let Some(refined) = out.refined {
            loss = loss + nll(refined, &weights);
        }
        loss
    }

    /// One Adam step on `batch` at learning rate `lr`; the loss before it.
    pub fn step(&mut self, batch: &[&TrainPair], lr: f64) -> Result<f32, String> {
        let loss = self.loss(batch);
        let value = loss.clone().into_scalar::<f32>();
        if !value.is_finite() {
            return Err(format!("training diverged (loss {value})"));
        }
        let grads = GradientsParams::from_grads(loss.backward(), &self.net);
        self.net = self.optim.step(lr, self.net.clone(), grads);
        Ok(value)
    }

    /// `epochs` passes over `pairs` in shuffled batches of `batch_size` at
    /// learning rate `lr`; each epoch's mean loss.
    pub fn fit(
        &mut self,
        pairs: &[TrainPair],
        epochs: usize,
        batch_size: usize,
        lr: f64,
    ) -> Result<Vec<f32>, String> {
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

    /// The trained network for inference (no autodiff).
    pub fn network(&self) -> PublishedNet {
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
        let device = Device::flex();
        let graph = |n: usize| PaperGraph {
            n,
            node_features: vec![0.0; n * crate::matching::deep::features::NODE_FEATURES],
            src: vec![],
            dst: vec![],
            length_m: vec![],
        };
        let pair = TrainPair {
            first: graph(2),
            second: graph(2),
            partner: vec![Some(1), None],
        };
        let w: Vec<f32> = label_weights(&[&pair], [3, 2], &device)
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
    }
}
