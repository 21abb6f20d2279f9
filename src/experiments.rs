//! Multi-run experiments built on the pipeline: collecting training pairs
//! from the training runs, and training the deep matchers. No file IO here
//! (the caller saves through `output` and `matching::deep::model`).

use crate::config::{PoseNoiseLabel, Settings};
use crate::matching::deep::model::Network;
use crate::matching::deep::train::{self, Example, TrainOptions, TrainReport};
use crate::matching::{MatchView, Method};
use crate::pipeline::{self, Progress, RunError};

/// The settings of run `seed`: traffic and sensor seeds both set to it.
pub fn settings_for_seed(settings: &Settings, seed: u64) -> Settings {
    let mut s = settings.clone();
    s.seeds.traffic = seed;
    s.seeds.sensor = seed;
    s
}

/// Labelled pairs from every training run, at the `gps` pose-noise level
/// (the matcher uses the reported heading only; headings are equally noisy
/// at every level). `progress(run, runs, examples so far)`.
pub fn collect_examples(
    settings: &Settings,
    mut progress: impl FnMut(usize, usize, usize),
) -> Result<Vec<Example>, RunError> {
    let level = settings
        .pose_noise
        .iter()
        .find(|l| l.label == PoseNoiseLabel::Gps)
        .or(settings.pose_noise.last())
        .copied()
        .expect("validated: at least one pose-noise level");
    let seeds = &settings.train.traffic_seeds;
    let mut examples = Vec::new();
    for (k, &seed) in seeds.iter().enumerate() {
        let run = settings_for_seed(settings, seed);
        pipeline::simulate(
            &run,
            |_: Progress| {},
            |inst| {
                let step = inst.frame.step;
                let first = MatchView {
                    detections: &inst.a.obs.detections,
                    graph: &inst.a.graph,
                    pose_reported: inst.a.reported_pose(seed, step, &level),
                    pose_noise: level,
                };
                let second = MatchView {
                    detections: &inst.b.obs.detections,
                    graph: &inst.b.graph,
                    pose_reported: inst.b.reported_pose(seed, step, &level),
                    pose_noise: level,
                };
                examples.extend(train::example(&first, &second));
                Ok(())
            },
        )?;
        progress(k + 1, seeds.len(), examples.len());
    }
    Ok(examples)
}

/// Trains one deep method on the collected examples.
pub fn train_method(
    settings: &Settings,
    method: Method,
    examples: &[Example],
    progress: impl FnMut(usize, usize, f32),
) -> Result<(Network, TrainReport), String> {
    let opts = TrainOptions {
        epochs: settings.train.epochs,
        learning_rate: settings.train.learning_rate,
        seed: settings.train.seed,
    };
    train::train(method, examples, &opts, progress)
}
