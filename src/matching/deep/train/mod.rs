//! Training of the deep matchers (burn autodiff on the `flex` CPU backend):
//! Adam over batches of pairs (padded to a common size, one tensor pass),
//! a warm-up then cosine learning-rate schedule, `mc_samples` dropout
//! samples per pair whose mean E[Y] the losses see, and early stopping on a
//! multi-sample validation loss; seeded initial weights, shuffling and
//! masks. Labels come from the true correspondences, which the caller
//! supplies (the oracle's pairs, in the [`Example`]s of `examples`,
//! re-exported here): nothing here reads ground truth itself.

use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

pub mod augment;
pub(crate) mod backend;
pub(crate) mod examples;
pub(crate) mod init;
mod loss;
pub(crate) mod masks;
pub(crate) mod ours_net;
#[cfg(test)]
mod ours_tests;
pub(crate) mod published;
pub(crate) mod published_net;
#[cfg(test)]
mod published_tests;
#[cfg(test)]
pub(crate) mod reference;
pub(crate) mod sinkhorn;
pub(crate) mod spline;
mod weights;

use self::backend::device;
use self::init::Init;
use self::loss::{LabelTensors, loss};
use self::masks::{Masks, draw_masks};
use self::ours_net::{OursNet, PairTensors};
use self::published::{PublishedTrainer, TrainPair};
use self::spline::GraphTensors;
use self::weights::to_bytes;
use super::arch::{
    Architecture, Backbone, LossTerms, MaskScope, NetworkShape, NoMatchWeights, PairLoss,
    PublishedConfig,
};
use super::features::PairInput;
use super::graph::OffsetGraph;
use super::params::Params;
use crate::matching::{Method, MethodKind};
use crate::rng::{self, Purpose};

pub use self::examples::{EdgeStats, Example, OwnedView, Prepared, example};
pub use self::weights::published_weights;

/// The weights of an untrained network of `method` whose gates are open
/// (as after the first training steps): for tests of everything the
/// learned parts touch, without training.
#[cfg(test)]
pub(crate) fn opened_weights(method: Method, seed: u64) -> Vec<u8> {
    let device = device();
    match method.backbone().expect("a deep method") {
        Backbone::Likelihood(arch) => {
            let net = OursNet::new(&arch, Init::Seeded(seed), &device).with_gates(1.0);
            to_bytes(&net).expect("weights")
        }
        Backbone::Published(cfg) => {
            let net = published_net::PublishedNet::new(&cfg, Init::Seeded(seed), &device);
            weights::module_bytes(&net).expect("weights")
        }
    }
}

/// `[train]`: which runs make the training set and how to fit.
#[derive(Clone, PartialEq)]
pub struct TrainSettings {
    /// SUMO seeds of the training runs (the sensor seed of run k is the
    /// same number). Must not overlap the evaluation's test seeds: train
    /// and test instances never come from the same run.
    pub traffic_seeds: Vec<u64>,
    /// Seeds of the validation runs, from the same pool, disjoint from the
    /// training and test runs: every choice (lambda) is made on them.
    pub validation_seeds: Vec<u64>,
    pub methods: Vec<Method>,
    /// At most this many epochs (the learning rate decays over them).
    pub epochs: usize,
    /// Peak learning rate (Adam).
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
    /// Early stopping: epochs without a lower validation loss before
    /// training stops (0 = off).
    pub patience: usize,
    /// The pair term of the loss.
    pub loss: PairLoss,
    /// MC-dropout samples per training pair (losses on their mean).
    pub mc_samples: usize,
    /// How the project's network's training dropout masks are drawn (per
    /// node, or Eq. 8's one mask per sample over each layer's input units).
    pub dropout_masks: MaskScope,
    /// The same for the paper's method and its ablations (DGMC's network).
    pub paper_dropout_masks: MaskScope,
    /// Pairs per optimiser step.
    pub batch_size: usize,
    /// Training pairs are sampled at most this often per vehicle pair
    /// (simulated seconds; the scenario's own `sample_every_s` if that is
    /// longer): consecutive instances differ little, so long runs of busy
    /// scenarios give more variety per training step this way.
    pub sample_every_s: f64,
    /// How the published networks weigh "no match" against true pairs.
    pub no_match: NoMatchWeights,
    /// Whether the deep networks read a dataset's appearance vectors (when
    /// it has vectors that its validation runs found telling).
    pub appearance_vectors: bool,
    /// A models folder whose weights of each method start its training
    /// (fine-tuning weights trained elsewhere, say on simulated scenes);
    /// `None`: a seeded start.
    pub start_from: Option<std::path::PathBuf>,
    /// The graph the published networks (the paper's method, its
    /// ablations, DGMC, GCN-GM) convolve over and their indicator width
    /// (`graph`, `consensus_dim`); the project's network keeps its own.
    pub network: NetworkShape,
    /// The published networks' training pairs perturbed anew each epoch
    /// (`node_dropout`, `position_jitter_m`; zero: not at all).
    pub augment: augment::Augment,
}

/// As derived, but `no_match`, `appearance_vectors`, `start_from` and
/// `network` are shown only when they differ from `entries`, `true`, none
/// and the default shape: a
/// config's digest hashes this text.
impl std::fmt::Debug for TrainSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("TrainSettings");
        d.field("traffic_seeds", &self.traffic_seeds)
            .field("validation_seeds", &self.validation_seeds)
            .field("methods", &self.methods)
            .field("epochs", &self.epochs)
            .field("learning_rate", &self.learning_rate)
            .field("seed", &self.seed)
            .field("scenarios", &self.scenarios)
            .field("validation_scenarios", &self.validation_scenarios)
            .field("runs_per_scenario", &self.runs_per_scenario)
            .field("patience", &self.patience)
            .field("loss", &self.loss)
            .field("mc_samples", &self.mc_samples)
            .field("dropout_masks", &self.dropout_masks)
            .field("paper_dropout_masks", &self.paper_dropout_masks)
            .field("batch_size", &self.batch_size)
            .field("sample_every_s", &self.sample_every_s);
        if self.no_match != NoMatchWeights::Entries {
            d.field("no_match", &self.no_match);
        }
        if !self.appearance_vectors {
            d.field("appearance_vectors", &self.appearance_vectors);
        }
        if let Some(dir) = &self.start_from {
            d.field("start_from", dir);
        }
        if self.network != NetworkShape::default() {
            d.field("network", &self.network);
        }
        if !self.augment.is_off() {
            d.field("augment", &self.augment);
        }
        d.finish()
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainOptions {
    /// At most this many epochs.
    pub epochs: usize,
    /// Peak learning rate.
    pub learning_rate: f64,
    pub seed: u64,
    /// Early stopping: stop after this many epochs without a lower
    /// validation loss and keep the weights of the lowest; 0 = off (every
    /// epoch runs, the last weights are kept, no validation loss).
    pub patience: usize,
    /// The pair term of the loss.
    pub loss: PairLoss,
    /// MC-dropout samples per pair: the losses are taken on their mean
    /// assignment E[Y] (Eq. 11-13).
    pub samples: usize,
    /// How the dropout masks are drawn.
    pub masks: MaskScope,
    pub batch_size: usize,
    /// The likelihood's gate on the squared Mahalanobis distance.
    pub gate_chi2: f64,
    /// The width of the appearance vectors the network reads (a dataset's
    /// learned features; 0: none).
    pub appearance_width: crate::sensor::AppearanceWidth,
    /// How the published networks weigh "no match" against true pairs.
    pub no_match: NoMatchWeights,
    /// The published networks' graph and indicator width.
    pub network: NetworkShape,
    /// How the published networks' training pairs are perturbed each
    /// epoch.
    pub augment: augment::Augment,
}

/// MC-dropout samples of the validation loss.
pub const VALIDATION_SAMPLES: usize = 4;

/// Steps of linear warm-up before the cosine decay.
const WARMUP_STEPS: usize = 200;

/// The learning rate at `step` of `total`: a linear warm-up to `peak`,
/// then a cosine decay to a twentieth of it at the end.
pub fn learning_rate(peak: f64, step: usize, total: usize) -> f64 {
    let warmup = WARMUP_STEPS.min(total / 10).max(1);
    if step < warmup {
        return peak * (step + 1) as f64 / warmup as f64;
    }
    let progress = (step - warmup) as f64 / (total.saturating_sub(warmup)).max(1) as f64;
    let floor = peak / 20.0;
    floor + 0.5 * (peak - floor) * (1.0 + (std::f64::consts::PI * progress.min(1.0)).cos())
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

/// A batch of prepared pairs as tensors.
struct BatchTensors {
    graphs: [GraphTensors; 2],
    pair: PairTensors,
    labels: LabelTensors,
}

impl BatchTensors {
    fn new(batch: &[&Prepared], device: &Device) -> Self {
        let g1: Vec<&OffsetGraph> = batch.iter().map(|p| &p.g1).collect();
        let g2: Vec<&OffsetGraph> = batch.iter().map(|p| &p.g2).collect();
        let graphs = [
            GraphTensors::new(&g1, device),
            GraphTensors::new(&g2, device),
        ];
        let (n1, n2) = (graphs[0].n(), graphs[1].n());
        let pairs: Vec<&PairInput> = batch.iter().map(|p| &p.pair).collect();
        let pair = PairTensors::new(&pairs, [n1, n2], device);
        let b = batch.len();
        let (mut y, mut non, mut real) = (
            vec![0f32; b * n1 * n2],
            vec![0f32; b * n1 * n2],
            vec![0f32; b * n1 * n2],
        );
        let (mut f1, mut f2) = (vec![0f32; b * n1], vec![0f32; b * n2]);
        let mut counts = [Vec::new(), Vec::new(), Vec::new()];
        for (k, p) in batch.iter().enumerate() {
            let (m1, m2) = (p.pair.n1, p.pair.n2);
            for i in 0..m1 {
                let (src, dst) = (i * m2, k * n1 * n2 + i * n2);
                y[dst..dst + m2].copy_from_slice(&p.y[src..src + m2]);
                non[dst..dst + m2].copy_from_slice(&p.non[src..src + m2]);
                real[dst..dst + m2].fill(1.0);
            }
            f1[k * n1..k * n1 + m1].copy_from_slice(&p.free[0]);
            f2[k * n2..k * n2 + m2].copy_from_slice(&p.free[1]);
            let sum = |v: &[f32]| v.iter().sum::<f32>().max(1.0);
            counts[0].push(sum(&p.y));
            counts[1].push((sum(&p.free[0]) + p.free[1].iter().sum::<f32>()).max(1.0));
            counts[2].push((m1 * m2) as f32);
        }
        let t3 = |v: Vec<f32>| Tensor::<3>::from_data(TensorData::new(v, [b, n1, n2]), device);
        let t2 = |v: Vec<f32>, n: usize| Tensor::<2>::from_data(TensorData::new(v, [b, n]), device);
        let labels = LabelTensors {
            y: t3(y),
            free: [t2(f1, n1), t2(f2, n2)],
            non: t3(non),
            real: t3(real),
            counts: counts.map(|c| Tensor::<1>::from_data(TensorData::new(c, [b]), device)),
        };
        Self {
            graphs,
            pair,
            labels,
        }
    }
}

/// The batches of one pass over `n` pairs: shuffled, then grouped by size
/// within windows of a few batches (less padding), the batch order
/// shuffled again. `sizes[k]`: the padded cost of pair k.
pub(crate) fn batches(
    sizes: &[usize],
    batch_size: usize,
    stream: Option<&mut ChaCha8Rng>,
) -> Vec<Vec<usize>> {
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    let batch_size = batch_size.max(1);
    match stream {
        Some(s) => {
            order.shuffle(s);
            for window in order.chunks_mut(batch_size * 16) {
                window.sort_by_key(|&k| sizes[k]);
            }
            let mut out: Vec<Vec<usize>> = order.chunks(batch_size).map(<[_]>::to_vec).collect();
            out.shuffle(s);
            out
        }
        None => {
            order.sort_by_key(|&k| sizes[k]);
            order.chunks(batch_size).map(<[_]>::to_vec).collect()
        }
    }
}

/// A network being trained, with its optimizer and random stream.
pub struct Trainer {
    arch: Architecture,
    terms: LossTerms,
    device: Device,
    net: OursNet,
    optim: ModuleOptimizer,
    /// Shuffling and dropout masks: `(seed, Training, hash(method label))`.
    stream: ChaCha8Rng,
    opts: TrainOptions,
}

impl Trainer {
    /// A fresh network of `method` (initial weights from `opts.seed`).
    pub fn new(method: Method, opts: &TrainOptions) -> Result<Self, String> {
        if method.kind() != MethodKind::Deep {
            return Err(format!("{} is not a deep method", method.as_str()));
        }
        let Some(arch) = method
            .architecture()
            .map(|a| a.with_appearance(opts.appearance_width))
        else {
            return Err(format!(
                "{} is a published network (see published::PublishedTrainer)",
                method.as_str()
            ));
        };
        let terms = method.loss_terms_with(opts.loss);
        let device = device().autodiff();
        Ok(Self {
            arch,
            terms,
            net: OursNet::new(&arch, Init::Seeded(opts.seed), &device),
            device,
            optim: AdamConfig::new().init(),
            stream: rng::stream(
                opts.seed,
                Purpose::Training,
                &[rng::hash_str(method.as_str())],
            ),
            opts: *opts,
        })
    }

    /// The network's inputs and labels of `examples`.
    pub fn prepare(&self, examples: &[Example]) -> Vec<Prepared> {
        examples
            .iter()
            .map(|e| e.prepare(&self.arch, self.opts.gate_chi2))
            .collect()
    }

    /// The batches of one training epoch over `prepared`.
    pub fn epoch_batches(&mut self, prepared: &[Prepared]) -> Vec<Vec<usize>> {
        let sizes: Vec<usize> = prepared.iter().map(padded_size).collect();
        batches(&sizes, self.opts.batch_size, Some(&mut self.stream))
    }

    /// The mean loss of `batch` with `samples` dropout samples per pair,
    /// masks from `stream`, on the network `net` and `device`.
    fn loss(
        &self,
        net: &OursNet,
        device: &Device,
        batch: &[&Prepared],
        samples: usize,
        stream: &mut ChaCha8Rng,
    ) -> Tensor<1> {
        let tensors = BatchTensors::new(batch, device);
        let [g1, g2] = &tensors.graphs;
        let dims = [batch.len(), samples, g1.n(), g2.n()];
        let masks: Masks = draw_masks(stream, &self.arch, dims, self.opts.masks, device);
        let log_p = net.forward([g1, g2], &tensors.pair, masks, self.arch.sinkhorn_iters);
        loss(log_p, &tensors.labels, self.terms)
    }

    /// Starts from the weights `bytes` (a `.bpk` of this network) instead
    /// of the seeded start.
    pub fn start_from(&mut self, bytes: &[u8]) -> Result<(), String> {
        let specs = crate::matching::deep::ours::spec(&self.arch);
        let params = Params::from_bytes(bytes, &specs)
            .map_err(|e| format!("the starting weights do not fit the network ({e})"))?;
        self.net = OursNet::from_params(&self.arch, &params, &specs, &self.device);
        Ok(())
    }

    /// One Adam step on one batch at learning rate `lr`; returns the loss
    /// before the step.
    pub fn step(&mut self, batch: &[&Prepared], lr: f64) -> Result<f32, String> {
        let mut stream = self.stream.clone();
        let loss = self.loss(
            &self.net,
            &self.device,
            batch,
            self.opts.samples,
            &mut stream,
        );
        self.stream = stream;
        descend(&mut self.optim, &mut self.net, loss, lr)
    }

    /// The mean loss over `prepared` without changing the network:
    /// [`VALIDATION_SAMPLES`] dropout samples per pair from a stream that
    /// is the same at every call, so that values of different epochs
    /// compare.
    pub fn validation_loss(&self, prepared: &[Prepared]) -> f64 {
        let mut stream = rng::stream(
            self.opts.seed,
            Purpose::Training,
            &[rng::hash_str("validation")],
        );
        let net = self.net.valid();
        let device = device();
        let sizes: Vec<usize> = prepared.iter().map(padded_size).collect();
        let mut sum = 0.0;
        for batch in batches(&sizes, self.opts.batch_size, None) {
            let batch: Vec<&Prepared> = batch.iter().map(|&k| &prepared[k]).collect();
            let loss = self.loss(&net, &device, &batch, VALIDATION_SAMPLES, &mut stream);
            sum += f64::from(loss.into_scalar::<f32>()) * batch.len() as f64;
        }
        sum / prepared.len().max(1) as f64
    }

    /// The trained weights as bytes (what a `.bpk` file holds).
    pub fn weights(&self) -> Result<Vec<u8>, String> {
        to_bytes(&self.net)
    }
}

/// One optimiser step of `net` down the gradient of `loss` at learning
/// rate `lr`; the loss before it (an error when it is not finite).
pub(crate) fn descend<M: burn::module::Module>(
    optim: &mut ModuleOptimizer,
    net: &mut M,
    loss: Tensor<1>,
    lr: f64,
) -> Result<f32, String> {
    let value = loss.clone().into_scalar::<f32>();
    if !value.is_finite() {
        return Err(format!("training diverged (loss {value})"));
    }
    let grads = GradientsParams::from_grads(loss.backward(), net);
    *net = optim.step(lr, net.clone(), grads);
    Ok(value)
}

/// The padded cost of a pair, for grouping pairs of similar size.
fn padded_size(p: &Prepared) -> usize {
    p.pair.n1.max(p.pair.n2)
}

/// What training reports as it goes: after every step, and after every
/// epoch (its mean training loss and, with early stopping, the validation
/// loss).
pub trait TrainProgress {
    fn step(&mut self, step: usize, total: usize, loss: f32);
    fn epoch(&mut self, epoch: usize, train_loss: f64, validation_loss: Option<f64>);
}

/// A network being fitted, as the training loop drives it: its own
/// training and validation pairs, by index.
trait Fit {
    /// The batches of one epoch over the training pairs.
    fn epoch_batches(&mut self) -> Vec<Vec<usize>>;
    /// One optimiser step on these training pairs; the loss before it.
    fn step(&mut self, batch: &[usize], lr: f64) -> Result<f32, String>;
    /// The mean loss over the validation pairs.
    fn validation_loss(&self) -> f64;
    fn weights(&self) -> Result<Vec<u8>, String>;
}

/// The project's network with its prepared pairs.
struct LikelihoodFit {
    trainer: Trainer,
    train: Vec<Prepared>,
    validation: Vec<Prepared>,
}

impl Fit for LikelihoodFit {
    fn epoch_batches(&mut self) -> Vec<Vec<usize>> {
        self.trainer.epoch_batches(&self.train)
    }

    fn step(&mut self, batch: &[usize], lr: f64) -> Result<f32, String> {
        let batch: Vec<&Prepared> = batch.iter().map(|&k| &self.train[k]).collect();
        self.trainer.step(&batch, lr)
    }

    fn validation_loss(&self) -> f64 {
        self.trainer.validation_loss(&self.validation)
    }

    fn weights(&self) -> Result<Vec<u8>, String> {
        self.trainer.weights()
    }
}

/// A published network with its pairs on the paper's inputs.
struct PublishedFit<'a> {
    trainer: PublishedTrainer,
    cfg: PublishedConfig,
    examples: &'a [Example],
    train: Vec<TrainPair>,
    sizes: Vec<usize>,
    validation: Vec<TrainPair>,
    opts: TrainOptions,
    /// The epoch running (1-based), whose draws perturb its pairs.
    epoch: u64,
}

impl Fit for PublishedFit<'_> {
    fn epoch_batches(&mut self) -> Vec<Vec<usize>> {
        self.epoch += 1;
        self.trainer
            .epoch_batches(&self.sizes, self.opts.batch_size)
    }

    fn step(&mut self, batch: &[usize], lr: f64) -> Result<f32, String> {
        let a = self.opts.augment;
        if a.is_off() {
            let batch: Vec<&TrainPair> = batch.iter().map(|&k| &self.train[k]).collect();
            return self.trainer.step(&batch, lr);
        }
        // Each pair's draws from its own stream (seed, epoch, index): the
        // same whatever the batch order or thread count.
        let drawn: Vec<Option<TrainPair>> = batch
            .iter()
            .map(|&k| {
                let parts = [rng::hash_str("augment"), self.epoch, k as u64];
                let mut stream = rng::stream(self.opts.seed, Purpose::Training, &parts);
                augment::augmented(&self.examples[k], a, &mut stream)
                    .map(|e| TrainPair::of(&e, &self.cfg))
            })
            .collect();
        let batch: Vec<&TrainPair> = batch
            .iter()
            .zip(&drawn)
            .map(|(&k, d)| d.as_ref().unwrap_or(&self.train[k]))
            .collect();
        self.trainer.step(&batch, lr)
    }

    fn validation_loss(&self) -> f64 {
        self.trainer
            .validation_loss(&self.validation, self.opts.seed, self.opts.batch_size)
    }

    fn weights(&self) -> Result<Vec<u8>, String> {
        self.trainer.weights()
    }
}

/// Trains a deep method on `examples`, from the weights `start` (the
/// bytes of a `.bpk` of the same network) or a seeded start; returns its
/// weights (bytes) and the loss curve. With `opts.patience > 0` and
/// `validation` examples, stops early on the validation loss and returns
/// the best weights. The published networks see the examples' paper
/// inputs only.
pub fn train(
    method: Method,
    examples: &[Example],
    validation: &[Example],
    opts: &TrainOptions,
    start: Option<&[u8]>,
    progress: &mut impl TrainProgress,
) -> Result<(Vec<u8>, TrainReport), String> {
    let Some(backbone) = method.backbone() else {
        return Err(format!("{} is not a deep method", method.as_str()));
    };
    if examples.is_empty() {
        return Err("no training examples (no instance with a covisible object)".into());
    }
    let stopping = opts.patience > 0 && !validation.is_empty();
    let report = TrainReport {
        edges: EdgeStats::of(examples),
        ..TrainReport::default()
    };
    match backbone
        .with_appearance(opts.appearance_width)
        .with_shape(opts.network)
    {
        Backbone::Likelihood(_) => {
            let mut trainer = Trainer::new(method, opts)?;
            if let Some(bytes) = start {
                trainer.start_from(bytes)?;
            }
            let fit = LikelihoodFit {
                train: trainer.prepare(examples),
                validation: trainer.prepare(validation),
                trainer,
            };
            fit_loop(fit, examples.len(), stopping, opts, progress, report)
        }
        Backbone::Published(cfg) => {
            let label = method.as_str();
            let mut trainer = PublishedTrainer::with_terms(
                cfg,
                method.loss_terms_with(opts.loss),
                opts.samples,
                opts.masks,
                opts.seed,
                label,
            );
            trainer.no_match = opts.no_match;
            if let Some(bytes) = start {
                trainer.start_from(bytes)?;
            }
            let train: Vec<TrainPair> = examples.iter().map(|e| TrainPair::of(e, &cfg)).collect();
            let fit = PublishedFit {
                sizes: train.iter().map(TrainPair::padded_size).collect(),
                train,
                validation: validation.iter().map(|e| TrainPair::of(e, &cfg)).collect(),
                trainer,
                cfg,
                examples,
                opts: *opts,
                epoch: 0,
            };
            fit_loop(fit, examples.len(), stopping, opts, progress, report)
        }
    }
}

/// The epochs of a fit: a warm-up then cosine learning rate, and early
/// stopping on the validation loss when `stopping`.
fn fit_loop(
    mut fit: impl Fit,
    n_examples: usize,
    stopping: bool,
    opts: &TrainOptions,
    progress: &mut impl TrainProgress,
    mut report: TrainReport,
) -> Result<(Vec<u8>, TrainReport), String> {
    let mut best = None;
    if stopping {
        report.validation_losses.push(fit.validation_loss());
        best = Some((0, report.validation_losses[0], fit.weights()?));
    }
    let per_epoch = n_examples.div_ceil(opts.batch_size.max(1));
    let total = opts.epochs * per_epoch;
    for epoch in 1..=opts.epochs {
        let mut sum = 0.0;
        for batch in fit.epoch_batches() {
            let lr = learning_rate(opts.learning_rate, report.steps, total);
            let value = fit
                .step(&batch, lr)
                .map_err(|e| format!("{e} at step {}", report.steps))?;
            sum += f64::from(value) * batch.len() as f64;
            report.steps += 1;
            progress.step(report.steps, total, value);
        }
        let train_loss = sum / n_examples as f64;
        report.epoch_losses.push(train_loss);
        let Some((best_epoch, best_loss, weights)) = &mut best else {
            progress.epoch(epoch, train_loss, None);
            continue;
        };
        let loss = fit.validation_loss();
        report.validation_losses.push(loss);
        progress.epoch(epoch, train_loss, Some(loss));
        if loss < *best_loss {
            (*best_epoch, *best_loss, *weights) = (epoch, loss, fit.weights()?);
        } else if epoch - *best_epoch >= opts.patience {
            break;
        }
    }
    match best {
        Some((epoch, _, weights)) => {
            report.best_epoch = Some(epoch);
            Ok((weights, report))
        }
        None => Ok((fit.weights()?, report)),
    }
}
