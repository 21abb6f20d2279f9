//! Training of the deep matchers (burn autodiff on the `flex` CPU backend):
//! Adam over single pairs, one dropout sample per step (the MC expectation
//! is taken over steps), seeded initial weights, shuffling and masks.
//! Labels come from the true correspondences, which the caller supplies
//! (the oracle's pairs): nothing here reads ground truth itself.

use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::features::{self, GraphInput, graph_input};
use super::model::{self, Architecture, GraphTensors, Init, LossTerms, Masks, Network};
use super::{draw_masks, variant};
use crate::matching::{Correspondence, MatchView, Method};
use crate::rng::{self, Purpose};

/// `[train]`: which runs make the training set and how to fit.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainSettings {
    /// SUMO seeds of the training runs (the sensor seed of run k is the
    /// same number). Must not overlap the evaluation's test seeds: train
    /// and test instances never come from the same run.
    pub traffic_seeds: Vec<u64>,
    /// Seeds of the validation runs, from the same pool, disjoint from the
    /// training and test runs: every choice (lambda) is made on them.
    pub validation_seeds: Vec<u64>,
    pub methods: Vec<Method>,
    pub epochs: usize,
    pub learning_rate: f64,
    /// Weight initialisation, shuffling and training dropout.
    pub seed: u64,
    /// More scenarios (config files) to train on, each on the first
    /// `runs_per_scenario` training seeds; disjoint from the validation and
    /// test scenarios.
    pub scenarios: Vec<std::path::PathBuf>,
    /// Scenarios held out for validation, each on the first
    /// `runs_per_scenario` validation seeds.
    pub validation_scenarios: Vec<std::path::PathBuf>,
    pub runs_per_scenario: usize,
    /// Early stopping on the validation runs' loss (0 = off).
    pub patience: usize,
    /// Supervise "no match" (the dustbin term of the loss).
    pub dustbin_loss: bool,
    /// MC-dropout samples per training step (losses on their mean).
    pub mc_samples: usize,
    /// Training pairs are sampled at most this often per vehicle pair
    /// (simulated seconds; the scenario's own `sample_every_s` if that is
    /// longer): consecutive instances differ little, so long runs of busy
    /// scenarios give more variety per training step this way.
    pub sample_every_s: f64,
}

/// One training pair with its labels.
#[derive(Clone, Debug, PartialEq)]
pub struct Example {
    pub g1: GraphInput,
    pub g2: GraphInput,
    /// `n1 x n2`: 1 for true correspondences.
    pub y_star: Vec<f32>,
    /// `n1 x n2`: 1 where row i or column j is a non-covisible object (a
    /// false positive counts as non-covisible).
    pub non: Vec<f32>,
    pub n_true: usize,
    /// `n1 x n2` GPS position cost (see `features::position_cost`).
    pub position_cost: Vec<f32>,
}

/// Labels a pair with its true correspondences (`true_pairs`: detection
/// `a` of the first vehicle is detection `b` of the second); `None` when a
/// side is empty or nothing is shared (such a pair teaches nothing about
/// matching).
pub fn example(
    first: &MatchView,
    second: &MatchView,
    true_pairs: &[Correspondence],
) -> Option<Example> {
    let (n1, n2) = (first.detections.len(), second.detections.len());
    if n1 == 0 || n2 == 0 || true_pairs.is_empty() {
        return None;
    }
    let mut row_partner: Vec<Option<usize>> = vec![None; n1];
    let mut col_has = vec![false; n2];
    for c in true_pairs {
        row_partner[c.a] = Some(c.b);
        col_has[c.b] = true;
    }
    let mut y_star = vec![0f32; n1 * n2];
    let mut non = vec![0f32; n1 * n2];
    for i in 0..n1 {
        if let Some(j) = row_partner[i] {
            y_star[i * n2 + j] = 1.0;
        }
        for j in 0..n2 {
            if row_partner[i].is_none() || !col_has[j] {
                non[i * n2 + j] = 1.0;
            }
        }
    }
    Some(Example {
        g1: graph_input(first.detections, first.graph, &first.pose_reported),
        g2: graph_input(second.detections, second.graph, &second.pose_reported),
        y_star,
        non,
        n_true: true_pairs.len(),
        position_cost: super::features::position_cost(first, second),
    })
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainOptions {
    pub epochs: usize,
    pub learning_rate: f64,
    pub seed: u64,
    /// Early stopping: stop after this many epochs without a lower
    /// validation loss and keep the weights of the lowest; 0 = off (every
    /// epoch runs, the last weights are kept, no validation loss).
    pub patience: usize,
    /// Add the dustbin ("no match") term to the method's losses.
    pub dustbin_loss: bool,
    /// MC-dropout samples per training step: the losses are taken on their
    /// mean assignment E[Y] (Eq. 11-13); 1 = one sample per step.
    pub samples: usize,
}

/// Mean loss per epoch.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrainReport {
    pub epoch_losses: Vec<f64>,
    pub steps: usize,
    /// With early stopping: the mean validation loss before training, then
    /// after each epoch; empty without.
    pub validation_losses: Vec<f64>,
    /// With early stopping: the epoch whose weights were kept (0 = none
    /// improved on the initial weights).
    pub best_epoch: Option<usize>,
    /// The edges the network saw: see [`EdgeStats`].
    pub edges: EdgeStats,
}

/// How the training graphs' edge vectors fill the pseudo-coordinate range
/// (`features::MAX_EDGE_M` per axis): the median and 95th percentile of
/// each edge's larger absolute world-axis component, and the share of
/// edges beyond the range (clipped onto its border).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EdgeStats {
    pub median_m: f64,
    pub p95_m: f64,
    pub clipped_share: f64,
}

impl EdgeStats {
    pub fn of(examples: &[Example]) -> Self {
        let mut m: Vec<f64> = examples
            .iter()
            .flat_map(|e| e.g1.edge_world_m.iter().chain(&e.g2.edge_world_m))
            .map(|v| f64::from(v[0].abs().max(v[1].abs())))
            .collect();
        if m.is_empty() {
            return Self::default();
        }
        m.sort_by(f64::total_cmp);
        let at = |q: f64| m[((m.len() - 1) as f64 * q).round() as usize];
        let clipped = m.iter().filter(|&&x| x > features::MAX_EDGE_M).count();
        Self {
            median_m: at(0.5),
            p95_m: at(0.95),
            clipped_share: clipped as f64 / m.len() as f64,
        }
    }
}

/// A network being trained, with its optimizer and random stream.
pub struct Trainer {
    arch: Architecture,
    terms: LossTerms,
    device: Device,
    net: Network,
    optim: ModuleOptimizer,
    /// Shuffling and dropout masks: `(seed, Training, hash(method label))`.
    stream: ChaCha8Rng,
    learning_rate: f64,
    seed: u64,
    samples: usize,
}

impl Trainer {
    /// A fresh network of `method` (initial weights from `opts.seed`).
    pub fn new(method: Method, opts: &TrainOptions) -> Result<Self, String> {
        let (arch, mut terms) =
            variant(method).ok_or_else(|| format!("{} is not a deep method", method.as_str()))?;
        terms.dustbin = opts.dustbin_loss;
        let device = Device::flex().autodiff();
        Ok(Self {
            arch,
            terms,
            net: Network::new(&arch, Init::Seeded(opts.seed), &device),
            device,
            optim: AdamConfig::new().init(),
            stream: rng::stream(
                opts.seed,
                Purpose::Training,
                &[rng::hash_str(method.as_str())],
            ),
            learning_rate: opts.learning_rate,
            seed: opts.seed,
            samples: opts.samples.max(1),
        })
    }

    /// Shuffles an epoch's order from the trainer's stream.
    pub fn shuffle(&mut self, order: &mut [usize]) {
        order.shuffle(&mut self.stream);
    }

    /// The loss of one pair under `masks` (the losses use the mean over
    /// their samples).
    fn loss(&self, ex: &Example, masks: Masks) -> Tensor<1> {
        let (n1, n2) = (ex.g1.n, ex.g2.n);
        let device = &self.device;
        let g1 = GraphTensors::new(&ex.g1, device);
        let g2 = GraphTensors::new(&ex.g2, device);
        let matrix =
            |v: &[f32]| Tensor::<2>::from_data(TensorData::new(v.to_vec(), [n1, n2]), device);
        let cost = matrix(&ex.position_cost).unsqueeze::<3>();
        let log_p = self
            .net
            .forward(&g1, &g2, masks, cost, self.arch.sinkhorn_iters);
        model::loss(
            log_p,
            matrix(&ex.y_star),
            matrix(&ex.non),
            ex.n_true,
            self.terms,
        )
    }

    /// One Adam step on one pair; returns the loss before the step.
    pub fn step(&mut self, ex: &Example) -> Result<f32, String> {
        let (n1, n2) = (ex.g1.n, ex.g2.n);
        let masks = draw_masks(
            &mut self.stream,
            &self.arch,
            self.samples,
            n1,
            n2,
            &self.device,
        );
        let loss = self.loss(ex, masks);
        let value = loss.clone().into_scalar::<f32>();
        if !value.is_finite() {
            return Err(format!("training diverged (loss {value})"));
        }
        let grads = GradientsParams::from_grads(loss.backward(), &self.net);
        self.net = self.optim.step(self.learning_rate, self.net.clone(), grads);
        Ok(value)
    }

    /// The mean loss over `examples` without changing the network: one
    /// dropout sample per pair from a stream that is the same at every
    /// call, so that values of different epochs compare.
    pub fn validation_loss(&self, examples: &[Example]) -> f64 {
        let mut stream = rng::stream(self.seed, Purpose::Training, &[rng::hash_str("validation")]);
        let sum: f64 = examples
            .iter()
            .map(|ex| {
                let masks = draw_masks(&mut stream, &self.arch, 1, ex.g1.n, ex.g2.n, &self.device);
                f64::from(self.loss(ex, masks).into_scalar::<f32>())
            })
            .sum();
        sum / examples.len().max(1) as f64
    }

    /// The trained weights as bytes (what a `.bpk` file holds).
    pub fn weights(&self) -> Result<Vec<u8>, String> {
        model::to_bytes(&self.net)
    }
}

/// Trains a deep method on `examples`; returns its weights (bytes) and the
/// loss curve. With `opts.patience > 0` and `validation` examples, stops
/// early on the validation loss and returns the best weights.
/// `progress(step, total, loss)` is called after every step.
pub fn train(
    method: Method,
    examples: &[Example],
    validation: &[Example],
    opts: &TrainOptions,
    mut progress: impl FnMut(usize, usize, f32),
) -> Result<(Vec<u8>, TrainReport), String> {
    let mut trainer = Trainer::new(method, opts)?;
    if examples.is_empty() {
        return Err("no training examples (no instance with a covisible object)".into());
    }
    let stopping = opts.patience > 0 && !validation.is_empty();
    let mut report = TrainReport {
        edges: EdgeStats::of(examples),
        ..TrainReport::default()
    };
    let mut best = None;
    if stopping {
        report
            .validation_losses
            .push(trainer.validation_loss(validation));
        best = Some((0, report.validation_losses[0], trainer.weights()?));
    }
    let mut order: Vec<usize> = (0..examples.len()).collect();
    let total = opts.epochs * examples.len();
    for epoch in 1..=opts.epochs {
        trainer.shuffle(&mut order);
        let mut sum = 0.0;
        for &k in &order {
            let value = trainer
                .step(&examples[k])
                .map_err(|e| format!("{e} at step {}", report.steps))?;
            sum += f64::from(value);
            report.steps += 1;
            progress(report.steps, total, value);
        }
        report.epoch_losses.push(sum / examples.len() as f64);
        if let Some((best_epoch, best_loss, weights)) = &mut best {
            let loss = trainer.validation_loss(validation);
            report.validation_losses.push(loss);
            if loss < *best_loss {
                (*best_epoch, *best_loss, *weights) = (epoch, loss, trainer.weights()?);
            } else if epoch - *best_epoch >= opts.patience {
                break;
            }
        }
    }
    match best {
        Some((epoch, _, weights)) => {
            report.best_epoch = Some(epoch);
            Ok((weights, report))
        }
        None => Ok((trainer.weights()?, report)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::testkit::{self, Side};

    fn pairs(p: &[(usize, usize)]) -> Vec<Correspondence> {
        p.iter()
            .map(|&(a, b)| Correspondence {
                a,
                b,
                probability: 1.0,
                uncertainty: 0.0,
            })
            .collect()
    }

    #[test]
    fn labels_mark_true_pairs_and_non_covisible_rows_and_columns() {
        let objects = testkit::world_objects();
        let a = Side::of(testkit::POSE_A, &objects, &[0, 1, 2], testkit::EXACT);
        let b = Side::of(testkit::POSE_B, &objects, &[2, 0], testkit::EXACT);
        let ex = example(&a.view(), &b.view(), &pairs(&[(0, 1), (2, 0)])).unwrap();
        assert_eq!(ex.n_true, 2);
        assert_eq!(ex.y_star, vec![0., 1., 0., 0., 1., 0.]);
        // Row 1 (object 1) is seen by the first vehicle only.
        assert_eq!(ex.non, vec![0., 0., 1., 1., 0., 0.]);
        assert!(example(&a.view(), &b.view(), &[]).is_none());
    }

    /// Real training on a small set: the loss falls, and the same seed
    /// gives the same weights, byte for byte.
    #[test]
    fn training_lowers_the_loss_and_is_reproducible() {
        let (a, b) = testkit::moved_copy();
        let all: Vec<(usize, usize)> = (0..a.detections.len())
            .map(|i| {
                (
                    i,
                    b.objects.iter().position(|&o| o == a.objects[i]).unwrap(),
                )
            })
            .collect();
        let ex = example(&a.view(), &b.view(), &pairs(&all)).unwrap();
        let opts = TrainOptions {
            epochs: 30,
            learning_rate: 1e-3,
            seed: 3,
            patience: 0,
            dustbin_loss: false,
            samples: 1,
        };
        let examples = vec![ex];
        let (w1, report) = train(Method::GcnGm, &examples, &[], &opts, |_, _, _| {}).unwrap();
        let first = report.epoch_losses[0];
        let last = *report.epoch_losses.last().unwrap();
        assert!(last < 0.5 * first, "loss {first} -> {last}");
        let (w2, _) = train(Method::GcnGm, &examples, &[], &opts, |_, _, _| {}).unwrap();
        assert_eq!(w1, w2);
        assert!(report.validation_losses.is_empty() && report.best_epoch.is_none());
        // Early stopping: the validation loss before training and after
        // each epoch; the kept epoch has the lowest, below the initial one;
        // training stops `patience` epochs after it at the latest; the
        // training stream is untouched, so the kept weights are those of
        // plain training stopped at that epoch.
        let stopping = TrainOptions {
            patience: 3,
            ..opts
        };
        let (kept, report) =
            train(Method::GcnGm, &examples, &examples, &stopping, |_, _, _| {}).unwrap();
        let v = &report.validation_losses;
        let best = report.best_epoch.unwrap();
        assert_eq!(v.len(), report.epoch_losses.len() + 1);
        assert!(v.iter().all(|&l| l >= v[best]) && v[best] < v[0], "{v:?}");
        assert!(v.len() - 1 - best <= 3, "{v:?}");
        let plain = TrainOptions {
            epochs: best,
            ..opts
        };
        let (same, _) = train(Method::GcnGm, &examples, &[], &plain, |_, _, _| {}).unwrap();
        assert_eq!(kept, same);
        // Several MC samples per step (losses on their mean, as Eq. 13):
        // the loss still falls, reproducibly, and the weights differ from
        // one-sample training.
        let mc = TrainOptions { samples: 4, ..opts };
        let (m1, report) = train(Method::Ours, &examples, &[], &mc, |_, _, _| {}).unwrap();
        let (m2, _) = train(Method::Ours, &examples, &[], &mc, |_, _, _| {}).unwrap();
        let (one, _) = train(Method::Ours, &examples, &[], &opts, |_, _, _| {}).unwrap();
        let (first, last) = (report.epoch_losses[0], *report.epoch_losses.last().unwrap());
        assert!(last < 0.5 * first, "loss {first} -> {last}");
        assert_eq!(m1, m2);
        assert_ne!(m1, one);
    }
}
