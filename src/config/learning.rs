//! Validation of `[train]` and `[eval]`: seed lists in SUMO's range and
//! disjoint between training, validation and test runs, the fitting
//! settings, and the scenario lists of each role.

use super::ConfigError;
use super::check::{Checker, field};
use super::lists::scenario_lists;
use super::raw::{RawEval, RawTrain};
use crate::evaluate::EvalSettings;
use crate::matching::MethodKind;
use crate::matching::deep::arch::NetworkShape;
use crate::matching::deep::train::TrainSettings;
use crate::matching::deep::train::augment::Augment;

/// More MC-dropout samples per training pair than this are refused.
const MAX_TRAIN_MC_SAMPLES: usize = 100;
pub(super) fn train_and_eval(
    c: &Checker,
    t: RawTrain,
    e: RawEval,
) -> Result<(TrainSettings, EvalSettings), ConfigError> {
    if t.traffic_seeds.is_empty() {
        return Err(c.invalid("train.traffic_seeds", "need at least one run".into()));
    }
    c.seed_list("train.traffic_seeds", &t.traffic_seeds)?;
    c.seed_list("train.validation_seeds", &t.validation_seeds)?;
    c.seed_list("eval.traffic_seeds", &e.traffic_seeds)?;
    let (train, validation, test) = (
        ("train.traffic_seeds", &t.traffic_seeds),
        ("train.validation_seeds", &t.validation_seeds),
        ("eval.traffic_seeds", &e.traffic_seeds),
    );
    for ((key, a), (other, b)) in [(train, test), (validation, test), (validation, train)] {
        if let Some(s) = a.iter().find(|s| b.contains(s)) {
            let (blamed, with) = c.blame(key, other);
            return Err(c.invalid(
                blamed,
                format!(
                    "seed {s} is in both {blamed} and {with}: training, validation and test \
                     runs must be disjoint"
                ),
            ));
        }
    }
    if t.validation_seeds.is_empty() {
        return Err(c.invalid("train.validation_seeds", "need at least one run".into()));
    }
    fitting(c, &t)?;
    if e.traffic_seeds.is_empty() {
        return Err(c.invalid("eval.traffic_seeds", "need at least one run".into()));
    }
    let runs = runs_per_scenario(c, &t)?;
    let lists = scenario_lists(c, &t, &e)?;
    let train = TrainSettings {
        traffic_seeds: t.traffic_seeds,
        validation_seeds: t.validation_seeds,
        methods: c.distinct("train.methods", t.methods)?,
        epochs: t.epochs,
        learning_rate: t.learning_rate,
        seed: t.seed,
        scenarios: lists.train,
        validation_scenarios: lists.validation,
        runs_per_scenario: runs,
        patience: t.patience,
        loss: t.loss,
        mc_samples: t.mc_samples,
        dropout_masks: t.dropout_masks,
        paper_dropout_masks: t.paper_dropout_masks,
        batch_size: t.batch_size,
        sample_every_s: t.sample_every_s,
        no_match: t.no_match,
        appearance_vectors: t.appearance_vectors,
        start_from: (!t.start_from.as_os_str().is_empty()).then(|| c.resolve(&t.start_from)),
        network: NetworkShape {
            graph: t.graph,
            consensus_dim: t.consensus_dim,
            edge_scale_m: t.edge_scale_m,
        },
        augment: Augment {
            node_dropout: t.node_dropout,
            position_jitter_m: t.position_jitter_m,
        },
    };
    Ok((
        train,
        EvalSettings {
            traffic_seeds: e.traffic_seeds,
            scenarios: lists.test,
            training_seeds: training_seeds(c, e.training_seeds)?,
        },
    ))
}

/// `[eval] training_seeds`: weight seeds, none twice.
fn training_seeds(c: &Checker, seeds: Vec<u64>) -> Result<Vec<u64>, ConfigError> {
    for (k, s) in seeds.iter().enumerate() {
        if seeds[..k].contains(s) {
            return Err(c.invalid("eval.training_seeds", format!("seed {s} is listed twice")));
        }
    }
    Ok(seeds)
}

/// `[train]`'s methods and fitting settings.
fn fitting(c: &Checker, t: &RawTrain) -> Result<(), ConfigError> {
    if t.methods
        .iter()
        .any(|m| !matches!(m.kind(), MethodKind::Deep))
    {
        return Err(c.invalid(
            "train.methods",
            "only deep methods (coid, coid+non, coid+unc, dgmc, gcn-gm, ours and the +gps ones) \
             are trained"
                .into(),
        ));
    }
    if let Some(m) = t.methods.iter().find(|m| m.is_variant()) {
        return Err(c.invalid(
            "train.methods",
            format!(
                "'{}' runs the weights of '{}': train '{}'",
                m.as_str(),
                m.weights_owner().as_str(),
                m.weights_owner().as_str()
            ),
        ));
    }
    if t.epochs == 0 {
        return Err(c.invalid("train.epochs", "need at least one epoch".into()));
    }
    if !(1..=MAX_TRAIN_MC_SAMPLES).contains(&t.mc_samples) {
        return Err(c.invalid(
            "train.mc_samples",
            format!(
                "must be 1 to {MAX_TRAIN_MC_SAMPLES} samples per pair, got {}",
                t.mc_samples
            ),
        ));
    }
    if !(0.0..=0.9).contains(&t.node_dropout) {
        return Err(c.invalid(
            "train.node_dropout",
            format!("must be a share from 0 to 0.9, got {}", t.node_dropout),
        ));
    }
    if !(0.0..=10.0).contains(&t.position_jitter_m) {
        return Err(c.invalid(
            "train.position_jitter_m",
            format!("must be 0 to 10 m, got {}", t.position_jitter_m),
        ));
    }
    if !(t.edge_scale_m >= 1.0 && t.edge_scale_m <= 1000.0) {
        return Err(c.invalid(
            "train.edge_scale_m",
            format!("must be 1 to 1000 m, got {}", t.edge_scale_m),
        ));
    }
    if !(1..=1024).contains(&t.consensus_dim) {
        return Err(c.invalid(
            "train.consensus_dim",
            format!("must be 1-1024 indicators, got {}", t.consensus_dim),
        ));
    }
    if !(1..=1024).contains(&t.batch_size) {
        return Err(c.invalid(
            "train.batch_size",
            format!("must be 1-1024 pairs, got {}", t.batch_size),
        ));
    }
    c.positive(field!("train", t.learning_rate))?;
    c.positive(field!("train", t.sample_every_s))
}

/// `[train] runs_per_scenario`, checked against the seeds it takes from.
fn runs_per_scenario(c: &Checker, t: &RawTrain) -> Result<usize, ConfigError> {
    let runs = t.runs_per_scenario;
    let too_many = (!t.scenarios.is_empty() && runs > t.traffic_seeds.len())
        || (!t.validation_scenarios.is_empty() && runs > t.validation_seeds.len());
    if runs == 0 || too_many {
        return Err(c.invalid(
            "train.runs_per_scenario",
            format!(
                "must be between 1 and the number of training (validation) seeds that listed \
                 training (validation) scenarios run, got {runs}"
            ),
        ));
    }
    Ok(runs)
}
