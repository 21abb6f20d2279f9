//! The paper's tables from the test runs of `coid eval`: what each run
//! contributes ([`RunEval`], pooled within the run), and Table 1 (P/R/F1 per
//! method), Table 2 (F1 before and after uncertainty thresholding), Table 3
//! (uncertainty types), the paired differences against the strongest
//! baseline (bootstrap intervals over runs), the lambda sweep (Fig. 8a), the case study and the
//! consistency across vehicles, each metric as the mean over runs with its
//! 95% interval. Table 1, the case study, calibration and consistency see
//! the decided matches (synchronised with `multi_vehicle =
//! "synchronized"`); Tables 2 and 3 and the sweep re-decide each pair's own
//! distribution at every threshold, so they stay pairwise.
//!
//! One job per file: `record` (the per-run record and its typed keys),
//! `grid` (the lambda grid), `columns` (a table from typed rows, each
//! column named once), `paper` (Tables 1-3, the sweep, the case study),
//! `paired` (differences against the strongest baseline),
//! `calibration` (calibration and consistency), `precision_recall`
//! (average precision and the precision-recall curves), `errors` (displacement
//! errors, fusion from every view), `plots` (the plots' data). This file:
//! what every table is made from ([`Inputs`]) and the tables together.

use std::collections::BTreeMap;

use crate::config::Settings;
use crate::fusion::FusionVariant;
use crate::matching::deep::decision::{Decision, UncertaintyKind};
use crate::matching::{Inputs as MethodInputs, Method, MethodKind, MethodLambdas};
use crate::report::{RowKey, Table};
use crate::sensor::PoseNoiseLabel;

mod calibration;
mod columns;
mod errors;
mod grid;
mod paired;
mod paper;
mod plots;
mod precision_recall;
mod record;
mod seeds;

pub use grid::lambda_grid;
pub use plots::plot_data;
pub use precision_recall::average_precision;
pub use record::{DecidedPair, MethodLevel, RuleKey, RunEval, ThresholdKey};

/// The paper's tables over the test runs.
pub struct EvalTables {
    /// The methods that see the paper's inputs only (and the oracle).
    pub table1: Table,
    /// The methods that see the reported poses too (and the oracle).
    pub table1b: Table,
    /// Each method's F1 minus the strongest baseline's, paired by run,
    /// with a bootstrap interval.
    pub paired: Table,
    pub table2: Table,
    pub table3: Table,
    pub lambda_sweep: Table,
    pub case_study: Table,
    /// Every method's displacement errors on the common object set.
    pub errors: Table,
    pub calibration: Table,
    /// Every method's average precision (its pairs ranked by the
    /// probability it reports, down to its operating point).
    pub precision_recall: Table,
    /// Every method's precision-recall curve at 101 recall levels.
    pub pr_curve: Table,
    pub consistency: Table,
    pub views: Table,
}

impl EvalTables {
    /// The tables with their file names, empty ones left out.
    pub fn files(&self) -> Vec<(&'static str, &Table)> {
        let mut files = vec![
            ("table1.csv", &self.table1),
            ("table1b.csv", &self.table1b),
            ("paired.csv", &self.paired),
            ("table2.csv", &self.table2),
            ("table3.csv", &self.table3),
            ("lambda_sweep.csv", &self.lambda_sweep),
            ("case_study.csv", &self.case_study),
            ("errors.csv", &self.errors),
            ("calibration.csv", &self.calibration),
            ("precision_recall.csv", &self.precision_recall),
            ("pr_curve.csv", &self.pr_curve),
            ("consistency.csv", &self.consistency),
            ("views.csv", &self.views),
        ];
        files.retain(|(_, t)| !t.columns.is_empty());
        files
    }
}

/// The tables, each deep method thresholded at its own lambda.
pub fn eval_tables(settings: &Settings, runs: &[RunEval], lambdas: &MethodLambdas) -> EvalTables {
    let inp = Inputs::new(settings, runs, lambdas);
    let with_ours = inp.deep_methods().contains(&Method::Ours);
    let if_ours = |f: fn(&Inputs) -> Table| {
        if with_ours { f(&inp) } else { Table::default() }
    };
    let seeing = |inputs: MethodInputs| {
        let only = inp.only(|m| m.inputs() == inputs || m.kind() == MethodKind::Oracle);
        let has_rows = only.methods.iter().any(|m| m.inputs() == inputs);
        if has_rows {
            paper::table1(&only)
        } else {
            Table::default()
        }
    };
    let lambda_sweep = if paper::table3_methods(&inp).is_empty() {
        Table::default()
    } else {
        paper::sweep(&inp)
    };
    let table3 = if paper::table3_methods(&inp).is_empty() {
        Table::default()
    } else {
        paper::table3(&inp)
    };
    EvalTables {
        table1: seeing(MethodInputs::Paper),
        table1b: seeing(MethodInputs::V2xPoses),
        paired: paired::paired(&inp),
        table2: paper::table2(&inp),
        table3,
        lambda_sweep,
        case_study: if_ours(paper::case_study),
        errors: errors::errors(&inp),
        calibration: calibration::calibration(&inp),
        precision_recall: precision_recall::precision_recall(&inp),
        pr_curve: precision_recall::pr_curve(&inp),
        consistency: calibration::consistency(&inp),
        views: errors::views(&inp),
    }
}

/// Everything the tables are made from.
#[derive(Clone)]
struct Inputs<'a> {
    runs: &'a [RunEval],
    levels: Vec<PoseNoiseLabel>,
    /// Methods of Table 1 (those the runs evaluated), in table order.
    methods: Vec<Method>,
    /// Each deep method's lambda of each uncertainty type as an index
    /// into the grid, and the grid.
    at: BTreeMap<(Method, UncertaintyKind), usize>,
    grid: Vec<f64>,
    kind: UncertaintyKind,
    variants: Vec<FusionVariant>,
}

impl<'a> Inputs<'a> {
    fn new(settings: &Settings, runs: &'a [RunEval], lambdas: &MethodLambdas) -> Self {
        let mut methods: Vec<Method> = runs
            .first()
            .map(|r| r.table1.keys().map(|k| k.method).collect())
            .unwrap_or_default();
        methods.dedup();
        let grid = lambda_grid(lambdas.values());
        let at = lambdas
            .iter()
            .flat_map(|(&m, l)| {
                UncertaintyKind::VARIANTS_ARRAY.map(|k| ((m, k), grid::grid_index(&grid, l.get(k))))
            })
            .collect();
        Inputs {
            runs,
            levels: settings.pose_noise.iter().map(|l| l.label).collect(),
            methods,
            at,
            grid,
            kind: settings.matching.uncertainty,
            variants: settings.fusion.variants.clone(),
        }
    }

    /// The same inputs with only the methods `keep` keeps.
    fn only(&self, keep: impl Fn(Method) -> bool) -> Self {
        let mut only = self.clone();
        only.methods.retain(|&m| keep(m));
        only
    }

    /// The per-run values of a metric (runs without it left out).
    fn per_run(&self, f: impl Fn(&RunEval) -> Option<f64>) -> Vec<f64> {
        self.runs.iter().filter_map(f).collect()
    }

    /// A deep method's lambda index of uncertainty `kind` (0 when it has
    /// none).
    fn at(&self, m: Method, kind: UncertaintyKind) -> usize {
        self.at.get(&(m, kind)).copied().unwrap_or(0)
    }

    /// A deep method's own decision rule, as it ran.
    fn decision(&self, m: Method) -> Decision {
        self.runs
            .iter()
            .find_map(|r| r.decisions.get(&m).copied())
            .unwrap_or(Decision::Assignment)
    }

    fn deep_methods(&self) -> Vec<Method> {
        self.methods
            .iter()
            .copied()
            .filter(|m| matches!(m.kind(), MethodKind::Deep))
            .collect()
    }

    /// `m` at level `l` under its own decision rule.
    fn rule(&self, m: Method, l: PoseNoiseLabel) -> RuleKey {
        MethodLevel::new(m, l).rule(self.decision(m))
    }

    /// `m` at level `l` under its own decision rule, thresholded at its own
    /// lambda on the uncertainty `kind`.
    fn own_threshold(&self, m: Method, l: PoseNoiseLabel, kind: UncertaintyKind) -> ThresholdKey {
        self.rule(m, l).threshold(kind, self.at(m, kind))
    }

    /// Every method at every level, in table order.
    fn method_levels(&self) -> impl Iterator<Item = MethodLevel> + '_ {
        self.methods
            .iter()
            .flat_map(|&m| self.levels.iter().map(move |&l| MethodLevel::new(m, l)))
    }

    /// Every method at every level with every fusion variant, in table
    /// order.
    fn rows(&self) -> impl Iterator<Item = RowKey> + '_ {
        self.method_levels()
            .flat_map(|at| self.variants.iter().map(move |&v| at.row(v)))
    }
}

#[cfg(test)]
mod tests;
