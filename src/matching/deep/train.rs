//! Training of the deep matchers (burn autodiff on the `flex` CPU backend):
//! Adam over single pairs, one dropout sample per step (the MC expectation
//! is taken over steps), seeded shuffling and masks.

use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use rand::seq::SliceRandom;

use super::features::{GraphInput, graph_input};
use super::model::{self, GraphTensors, Network};
use super::{draw_masks, variant};
use crate::matching::{MatchView, Method};
use crate::rng::{self, Purpose};

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

/// Labels a pair from the detections' true ids; `None` when a side is empty
/// or nothing is shared (such a pair teaches nothing about matching).
pub fn example(first: &MatchView, second: &MatchView) -> Option<Example> {
    let (n1, n2) = (first.detections.len(), second.detections.len());
    if n1 == 0 || n2 == 0 {
        return None;
    }
    let partner_of = |id: &Option<String>, others: &[crate::sensor::Detection]| {
        id.as_ref()
            .and_then(|id| others.iter().position(|d| d.truth_id.as_ref() == Some(id)))
    };
    let row_partner: Vec<Option<usize>> = first
        .detections
        .iter()
        .map(|d| partner_of(&d.truth_id, second.detections))
        .collect();
    let col_has: Vec<bool> = second
        .detections
        .iter()
        .map(|d| partner_of(&d.truth_id, first.detections).is_some())
        .collect();
    let mut y_star = vec![0f32; n1 * n2];
    let mut non = vec![0f32; n1 * n2];
    let mut n_true = 0;
    for i in 0..n1 {
        if let Some(j) = row_partner[i] {
            y_star[i * n2 + j] = 1.0;
            n_true += 1;
        }
        for j in 0..n2 {
            if row_partner[i].is_none() || !col_has[j] {
                non[i * n2 + j] = 1.0;
            }
        }
    }
    if n_true == 0 {
        return None;
    }
    Some(Example {
        g1: graph_input(first.detections, first.graph, &first.pose_reported),
        g2: graph_input(second.detections, second.graph, &second.pose_reported),
        y_star,
        non,
        n_true,
        position_cost: super::features::position_cost(first, second),
    })
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainOptions {
    pub epochs: usize,
    pub learning_rate: f64,
    pub seed: u64,
}

/// Mean loss per epoch.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrainReport {
    pub epoch_losses: Vec<f64>,
    pub steps: usize,
}

/// Trains a deep method on `examples`. `progress(step, total, loss)` is
/// called after every step.
pub fn train(
    method: Method,
    examples: &[Example],
    opts: &TrainOptions,
    mut progress: impl FnMut(usize, usize, f32),
) -> Result<(Network, TrainReport), String> {
    let (arch, terms) =
        variant(method).ok_or_else(|| format!("{} is not a deep method", method.as_str()))?;
    if examples.is_empty() {
        return Err("no training examples (no instance with a covisible object)".into());
    }
    let device = Device::flex().autodiff();
    device.seed(opts.seed);
    let mut net = Network::new(&arch, &device);
    let mut optim = AdamConfig::new().init();
    let mut order: Vec<usize> = (0..examples.len()).collect();
    let mut stream = rng::stream(opts.seed, Purpose::Training, &[method as u64]);
    let total = opts.epochs * examples.len();
    let mut report = TrainReport::default();
    for _ in 0..opts.epochs {
        order.shuffle(&mut stream);
        let mut sum = 0.0;
        for &k in &order {
            let ex = &examples[k];
            let (n1, n2) = (ex.g1.n, ex.g2.n);
            let g1 = GraphTensors::new(&ex.g1, &device);
            let g2 = GraphTensors::new(&ex.g2, &device);
            let masks = draw_masks(&mut stream, &arch, 1, n1, n2, &device);
            let cost = Tensor::<3>::from_data(
                TensorData::new(ex.position_cost.clone(), [1, n1, n2]),
                &device,
            );
            let log_p = net.forward(&g1, &g2, masks, cost, arch.sinkhorn_iters);
            let y = Tensor::<2>::from_data(TensorData::new(ex.y_star.clone(), [n1, n2]), &device);
            let non = Tensor::<2>::from_data(TensorData::new(ex.non.clone(), [n1, n2]), &device);
            let loss = model::loss(log_p, y, non, ex.n_true, terms);
            let value = loss.clone().into_scalar::<f32>();
            if !value.is_finite() {
                return Err(format!(
                    "training diverged at step {} (loss {value})",
                    report.steps
                ));
            }
            let grads = GradientsParams::from_grads(loss.backward(), &net);
            net = optim.step(opts.learning_rate, net, grads);
            sum += f64::from(value);
            report.steps += 1;
            progress(report.steps, total, value);
        }
        report.epoch_losses.push(sum / examples.len() as f64);
    }
    Ok((net, report))
}
