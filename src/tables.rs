//! The paper's tables from the test runs of `coid eval`: what each run
//! contributes ([`RunEval`], pooled within the run), and Table 1 (P/R/F1 per
//! method), Table 2 (F1 before and after uncertainty thresholding), Table 3
//! (uncertainty types), the lambda sweep (Fig. 8a), the case study and the
//! consistency across vehicles, each metric as the mean over runs with its
//! 95% interval. Table 1, the case study, calibration and consistency see
//! the decided matches (synchronised with `multi_vehicle =
//! "synchronized"`); Tables 2 and 3 and the sweep re-decide each pair's own
//! distribution at every threshold, so they stay pairwise.

use std::collections::BTreeMap;

use crate::config::Settings;
use crate::evaluate::{Consistency, MethodEval, PairCounts, ViewEstimate, count_pairs, is_correct};
use crate::fusion::FusionVariant;
use crate::matching::deep::decision::{Decision, MatchDistribution, UncertaintyKind};
use crate::matching::synchronize::TripleCounts;
use crate::matching::{Method, MethodKind};
use crate::report::{
    ObjectErrors, PlotData, ScoredPair, Table, ViewSums, brier_score, expected_calibration_error,
    mean_ci95, reliability, seen_by_group, seen_by_label, uncertainty_auroc,
};
use crate::sensor::{ObservationTruth, PoseNoiseLabel};

/// The uncertainty types of Table 3, in its order.
const TABLE3_KINDS: [UncertaintyKind; 3] = [
    UncertaintyKind::Epistemic,
    UncertaintyKind::Aleatoric,
    UncertaintyKind::Total,
];

/// The threshold grid of the lambda sweep (binary entropy in bits): 0 to 1
/// by 0.05, the methods' own lambdas, and "no threshold" (infinite) last.
pub fn lambda_grid<'a>(lambdas: impl IntoIterator<Item = &'a f64>) -> Vec<f64> {
    let mut g: Vec<f64> = (0..=20).map(|k| f64::from(k) / 20.0).collect();
    g.extend(lambdas.into_iter().filter(|l| l.is_finite()));
    g.sort_by(f64::total_cmp);
    g.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    g.push(f64::INFINITY);
    g
}

/// The index of `lambda` in `grid` (the same value, else the nearest).
fn grid_index(grid: &[f64], lambda: f64) -> usize {
    if let Some(k) = grid.iter().position(|&g| g == lambda) {
        return k;
    }
    (0..grid.len())
        .filter(|&k| grid[k].is_finite())
        .min_by(|&a, &b| {
            (grid[a] - lambda)
                .abs()
                .total_cmp(&(grid[b] - lambda).abs())
        })
        .unwrap_or(0)
}

/// The uncertainty types, in the order of [`RunEval::thresholded`]'s counts.
const KINDS: [UncertaintyKind; 3] = [
    UncertaintyKind::Total,
    UncertaintyKind::Epistemic,
    UncertaintyKind::Aleatoric,
];

/// What one test run contributes to the tables.
#[derive(Clone, Debug, Default)]
pub struct RunEval {
    /// Table 1: each method with its default decision.
    pub table1: BTreeMap<(Method, PoseNoiseLabel), PairCounts>,
    /// Deep methods without thresholding, per decision rule.
    pub unthresholded: BTreeMap<(Method, PoseNoiseLabel, Decision), PairCounts>,
    /// Deep methods thresholded: (method, level, decision rule, kind,
    /// index into [`lambda_grid`]).
    pub thresholded:
        BTreeMap<(Method, PoseNoiseLabel, Decision, UncertaintyKind, usize), PairCounts>,
    /// Each deep method's own decision rule, as it ran.
    pub decisions: BTreeMap<Method, Decision>,
    /// With [`RunEval::keeping_pairs`]: every decided pair of the deep
    /// methods under each rule, before any threshold (validation).
    pub decided: Option<BTreeMap<(Method, PoseNoiseLabel, Decision), Vec<DecidedPair>>>,
    /// Displacement errors per (method, level, fusion) over the object
    /// sets of the protocol.
    pub errors: BTreeMap<(Method, PoseNoiseLabel, FusionVariant), ObjectErrors>,
    /// Every object's single and fused error of the full method (`ours`),
    /// for the error CDFs.
    pub ours_errors: BTreeMap<(PoseNoiseLabel, FusionVariant), (Vec<f64>, Vec<f64>)>,
    /// Every identified pair of each method (its default decision), for
    /// calibration.
    pub scored: BTreeMap<(Method, PoseNoiseLabel), Vec<ScoredPair>>,
    /// Consistency across vehicles of each method's decided matches.
    pub consistency: BTreeMap<(Method, PoseNoiseLabel), Consistency>,
    /// Fusion from every view per (method, level, fusion, seen-by group).
    pub views: BTreeMap<(Method, PoseNoiseLabel, FusionVariant, usize), ViewSums>,
    pub instances: usize,
}

/// One pair a deep method's rule decided on, before any threshold: what
/// validation needs to calibrate and threshold it afresh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecidedPair {
    /// E[Y] of the pair (uncalibrated).
    pub p: f32,
    /// Its aleatoric uncertainty (bits).
    pub aleatoric: f32,
    pub correct: bool,
}

impl RunEval {
    /// An empty run that also keeps every decided pair (validation).
    pub fn keeping_pairs() -> Self {
        Self {
            decided: Some(BTreeMap::new()),
            ..Self::default()
        }
    }

    /// Adds one method's all-view estimates of one frame at one level.
    pub fn record_views(
        &mut self,
        method: Method,
        level: PoseNoiseLabel,
        views: &[(FusionVariant, Vec<ViewEstimate>)],
    ) {
        for (variant, est) in views {
            for v in est {
                let key = (method, level, *variant, seen_by_group(v.seen_by));
                self.views.entry(key).or_default().add(v);
            }
        }
    }

    /// Adds one method's consistency on one frame at one level.
    pub fn record_consistency(&mut self, method: Method, level: PoseNoiseLabel, c: Consistency) {
        self.consistency.entry((method, level)).or_default().add(c);
    }

    /// Counts one distribution's pairs under `decision` without a
    /// threshold and at every threshold of `grid` and every uncertainty
    /// type.
    fn record_thresholds(
        &mut self,
        method: Method,
        level: PoseNoiseLabel,
        (ta, tb): (&ObservationTruth, &ObservationTruth),
        (dist, decision): (&MatchDistribution, Decision),
        grid: &[f64],
    ) {
        let pairs = dist.decide_with(decision, None);
        let before = count_pairs(ta, tb, &pairs);
        let key = (method, level, decision);
        self.unthresholded.entry(key).or_default().add(before);
        let correct: Vec<bool> = pairs.iter().map(|c| is_correct(ta, tb, c)).collect();
        if let Some(decided) = &mut self.decided {
            decided
                .entry((method, level, decision))
                .or_default()
                .extend(pairs.iter().zip(&correct).map(|(c, &correct)| DecidedPair {
                    p: dist.p(c.a, c.b),
                    aleatoric: dist.aleatoric[c.a * dist.n2 + c.b],
                    correct,
                }));
        }
        for kind in KINDS {
            let u: Vec<f64> = pairs
                .iter()
                .map(|c| dist.uncertainty(c.a, c.b, kind))
                .collect();
            for (k, &lambda) in grid.iter().enumerate() {
                let kept = u.iter().zip(&correct).filter(|&(&u, _)| u < lambda);
                let counts = PairCounts {
                    identified: kept.clone().count(),
                    correct: kept.filter(|&(_, &c)| c).count(),
                    ground_truth: before.ground_truth,
                };
                self.thresholded
                    .entry((method, level, decision, kind, k))
                    .or_default()
                    .add(counts);
            }
        }
    }

    /// Adds one method's evaluation of one instance at one level; deep
    /// methods also count every threshold of `grid` and every uncertainty
    /// type on the same distribution.
    pub fn record(
        &mut self,
        e: &MethodEval,
        level: PoseNoiseLabel,
        truths: (&ObservationTruth, &ObservationTruth),
        grid: &[f64],
    ) {
        let (ta, tb) = truths;
        if let Some(dist) = &e.identification.distribution {
            self.decisions.insert(e.method, dist.decision);
            for decision in [Decision::Assignment, Decision::Mutual] {
                self.record_thresholds(e.method, level, (ta, tb), (dist, decision), grid);
            }
        }
        self.table1
            .entry((e.method, level))
            .or_default()
            .add(e.counts);
        let scored = e.identification.matches.iter().map(|c| ScoredPair {
            probability: c.probability,
            uncertainty: c.uncertainty,
            correct: is_correct(ta, tb, c),
        });
        self.scored
            .entry((e.method, level))
            .or_default()
            .extend(scored);
        for (variant, est) in &e.fused {
            if e.method == Method::Ours {
                let o = self.ours_errors.entry((level, *variant)).or_default();
                o.0.extend(est.iter().map(|x| x.single_error_m()));
                o.1.extend(est.iter().map(|x| x.fused_error_m()));
            }
            self.errors
                .entry((e.method, level, *variant))
                .or_default()
                .record(est);
        }
    }
}

/// The paper's tables over the test runs.
pub struct EvalTables {
    pub table1: Table,
    pub table2: Table,
    pub table3: Table,
    pub lambda_sweep: Table,
    pub case_study: Table,
    /// Every method's displacement errors on the common object set.
    pub errors: Table,
    pub calibration: Table,
    pub consistency: Table,
    pub views: Table,
}

impl EvalTables {
    /// The tables with their file names, empty ones left out.
    pub fn files(&self) -> Vec<(&'static str, &Table)> {
        let mut files = vec![
            ("table1.csv", &self.table1),
            ("table2.csv", &self.table2),
            ("table3.csv", &self.table3),
            ("lambda_sweep.csv", &self.lambda_sweep),
            ("case_study.csv", &self.case_study),
            ("errors.csv", &self.errors),
            ("calibration.csv", &self.calibration),
            ("consistency.csv", &self.consistency),
            ("views.csv", &self.views),
        ];
        files.retain(|(_, t)| !t.columns.is_empty());
        files
    }
}

/// Everything the tables are made from.
struct Inputs<'a> {
    runs: &'a [RunEval],
    levels: Vec<PoseNoiseLabel>,
    /// Methods of Table 1 (those the runs evaluated), in table order.
    methods: Vec<Method>,
    /// Each deep method's lambda as an index into the grid, and the grid.
    at: BTreeMap<Method, usize>,
    grid: Vec<f64>,
    kind: UncertaintyKind,
    variants: Vec<FusionVariant>,
}

impl Inputs<'_> {
    /// The per-run values of a metric (runs without it left out).
    fn per_run(&self, f: impl Fn(&RunEval) -> Option<f64>) -> Vec<f64> {
        self.runs.iter().filter_map(f).collect()
    }

    /// A deep method's lambda index (0 when it has none).
    fn at(&self, m: Method) -> usize {
        self.at.get(&m).copied().unwrap_or(0)
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
            .filter(|m| matches!(m.kind(), MethodKind::Deep(_)))
            .collect()
    }
}

fn inputs<'a>(
    settings: &Settings,
    runs: &'a [RunEval],
    lambdas: &BTreeMap<Method, f64>,
) -> Inputs<'a> {
    let mut methods: Vec<Method> = runs
        .first()
        .map(|r| r.table1.keys().map(|k| k.0).collect())
        .unwrap_or_default();
    methods.dedup();
    let grid = lambda_grid(lambdas.values());
    let at = lambdas
        .iter()
        .map(|(&m, &l)| (m, grid_index(&grid, l)))
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

/// The tables, each deep method thresholded at its own lambda.
pub fn eval_tables(
    settings: &Settings,
    runs: &[RunEval],
    lambdas: &BTreeMap<Method, f64>,
) -> EvalTables {
    let inp = inputs(settings, runs, lambdas);
    let with_ours = inp.deep_methods().contains(&Method::Ours);
    let if_ours = |f: fn(&Inputs) -> Table| {
        if with_ours { f(&inp) } else { Table::default() }
    };
    EvalTables {
        table1: table1(&inp),
        table2: table2(&inp),
        table3: if_ours(table3),
        lambda_sweep: if_ours(sweep),
        case_study: if_ours(case_study),
        errors: errors(&inp),
        calibration: calibration(&inp),
        consistency: consistency(&inp),
        views: views(&inp),
    }
}

/// Fusion from every view: per method, level, fusion variant and number
/// of vehicles that see the object (1, 2, 3, 4+), the displacement error
/// of the same (ego, object) set single, fused pairwise (mean over the
/// ego's peers that see the object) and fused from every matched view;
/// means over the
/// runs with their 95% intervals, the object count summed.
fn views(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut names, mut noise, mut fusion, mut seen) = (vec![], vec![], vec![], vec![]);
    let mut n = vec![];
    let mut de: [Vec<Vec<f64>>; 3] = Default::default();
    for &m in &inp.methods {
        for &l in &inp.levels {
            for &v in &inp.variants {
                for group in 1..=4 {
                    let get = |run: &RunEval| run.views.get(&(m, l, v, group)).copied();
                    let total: usize = inp.runs.iter().filter_map(get).map(|s| s.n).sum();
                    if total == 0 {
                        continue;
                    }
                    names.push(m.as_str().to_owned());
                    noise.push(l.as_str().to_owned());
                    fusion.push(v.as_str().to_owned());
                    seen.push(seen_by_label(group));
                    n.push(total as u64);
                    de[0].push(inp.per_run(|run| get(run).map(|s| s.means().0)));
                    de[1].push(inp.per_run(|run| get(run).map(|s| s.means().1)));
                    de[2].push(inp.per_run(|run| get(run).map(|s| s.means().2)));
                }
            }
        }
    }
    t.text("method", names);
    t.text("pose_noise", noise);
    t.text("fusion", fusion);
    t.text("seen_by", seen);
    t.count("n_objects", n);
    t.stat("de_single_m", &de[0]);
    t.stat("de_fused_pairwise_m", &de[1]);
    t.stat("de_fused_all_views_m", &de[2]);
    t
}

/// Consistency across vehicles of each method's decided matches: triple
/// chains and the share the third pair contradicts (pooled over the runs),
/// and the implied objects as a clustering (precision, recall, F1: mean
/// over the runs with a 95% interval).
fn consistency(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut names, mut noise, mut chains, mut share) = (vec![], vec![], vec![], vec![]);
    let (mut p, mut r, mut f) = (vec![], vec![], vec![]);
    for &m in &inp.methods {
        for &l in &inp.levels {
            names.push(m.as_str().to_owned());
            noise.push(l.as_str().to_owned());
            let get = |run: &RunEval| run.consistency.get(&(m, l)).copied();
            let mut pooled = TripleCounts::default();
            for c in inp.runs.iter().filter_map(get) {
                pooled.add(c.triples);
            }
            chains.push(pooled.chains as u64);
            share.push(pooled.share());
            p.push(inp.per_run(|run| get(run).map(|c| c.objects.precision())));
            r.push(inp.per_run(|run| get(run).map(|c| c.objects.recall())));
            f.push(inp.per_run(|run| get(run).map(|c| c.objects.f1())));
        }
    }
    t.text("method", names);
    t.text("pose_noise", noise);
    t.count("triple_chains", chains);
    t.number("inconsistent_triple_share", share);
    t.stat("object_precision", &p);
    t.stat("object_recall", &r);
    t.stat("object_f1", &f);
    t
}

/// Every identified pair of `m` at `l`, pooled over the runs.
fn pooled(inp: &Inputs, m: Method, l: PoseNoiseLabel) -> Vec<ScoredPair> {
    inp.runs
        .iter()
        .filter_map(|r| r.scored.get(&(m, l)))
        .flatten()
        .copied()
        .collect()
}

/// Calibration of each method's probabilities on its identified pairs,
/// pooled over the runs: ECE (15 bins), Brier score, and the AUROC of the
/// uncertainty for telling wrong pairs from right ones.
fn calibration(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut names, mut noise, mut n) = (vec![], vec![], vec![]);
    let (mut ece, mut brier, mut auroc) = (vec![], vec![], vec![]);
    for &m in &inp.methods {
        for &l in &inp.levels {
            let pairs = pooled(inp, m, l);
            names.push(m.as_str().to_owned());
            noise.push(l.as_str().to_owned());
            n.push(pairs.len() as u64);
            ece.push(expected_calibration_error(&pairs));
            brier.push(brier_score(&pairs));
            auroc.push(uncertainty_auroc(&pairs));
        }
    }
    t.text("method", names);
    t.text("pose_noise", noise);
    t.count("n_pairs", n);
    t.number("ece", ece);
    t.number("brier", brier);
    t.number("auroc", auroc);
    t
}

fn table1(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut names, mut noise, mut p, mut r, mut f) = (vec![], vec![], vec![], vec![], vec![]);
    for &m in &inp.methods {
        for &l in &inp.levels {
            names.push(m.as_str().to_owned());
            noise.push(l.as_str().to_owned());
            let get = |run: &RunEval| run.table1.get(&(m, l)).copied();
            p.push(inp.per_run(|run| get(run).map(|c| c.precision())));
            r.push(inp.per_run(|run| get(run).map(|c| c.recall())));
            f.push(inp.per_run(|run| get(run).map(|c| c.f1())));
        }
    }
    t.text("method", names);
    t.text("pose_noise", noise);
    t.stat("precision", &p);
    t.stat("recall", &r);
    t.stat("f1", &f);
    t.count("n_runs", vec![inp.runs.len() as u64; p.len()]);
    t.defined("n_runs_precision", &p);
    t
}

fn table2(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut names, mut noise, mut before, mut after) = (vec![], vec![], vec![], vec![]);
    for m in inp.deep_methods() {
        for &l in &inp.levels {
            names.push(m.as_str().to_owned());
            noise.push(l.as_str().to_owned());
            let d = inp.decision(m);
            before.push(inp.per_run(|run| run.unthresholded.get(&(m, l, d)).map(|c| c.f1())));
            let key = (m, l, d, inp.kind, inp.at(m));
            after.push(inp.per_run(|run| run.thresholded.get(&key).map(|c| c.f1())));
        }
    }
    t.text("method", names);
    t.text("pose_noise", noise);
    t.stat("f1_before", &before);
    t.stat("f1_after", &after);
    t
}

fn table3(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut kinds, mut noise, mut f) = (vec![], vec![], vec![]);
    for &l in &inp.levels {
        for k in TABLE3_KINDS {
            kinds.push(k.as_str().to_owned());
            noise.push(l.as_str().to_owned());
            let key = (
                Method::Ours,
                l,
                inp.decision(Method::Ours),
                k,
                inp.at(Method::Ours),
            );
            f.push(inp.per_run(|run| run.thresholded.get(&key).map(|c| c.f1())));
        }
    }
    t.text("uncertainty", kinds);
    t.text("pose_noise", noise);
    t.stat("f1", &f);
    t
}

fn sweep(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut lam, mut noise, mut p, mut r, mut f) = (vec![], vec![], vec![], vec![], vec![]);
    for &l in &inp.levels {
        for (k, &g) in inp.grid.iter().enumerate() {
            lam.push(g);
            noise.push(l.as_str().to_owned());
            let get = |run: &RunEval| {
                let d = inp.decision(Method::Ours);
                run.thresholded
                    .get(&(Method::Ours, l, d, inp.kind, k))
                    .copied()
            };
            p.push(inp.per_run(|run| get(run).map(|c| c.precision())));
            r.push(inp.per_run(|run| get(run).map(|c| c.recall())));
            f.push(inp.per_run(|run| get(run).map(|c| c.f1())));
        }
    }
    t.number("lambda", lam);
    t.text("pose_noise", noise);
    t.stat("precision", &p);
    t.stat("recall", &r);
    t.stat("f1", &f);
    t.defined("n_runs_precision", &p);
    t
}

/// The case study of `ours` (the paper's last table): precision, recall and
/// displacement errors over the common object set and its covisible part,
/// with oracle fusion on the same set for reference.
fn case_study(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut noise, mut fusion, mut p, mut r) = (vec![], vec![], vec![], vec![]);
    let mut de: [Vec<Vec<f64>>; 5] = Default::default();
    for &l in &inp.levels {
        for &v in &inp.variants {
            noise.push(l.as_str().to_owned());
            fusion.push(v.as_str().to_owned());
            let counts = |run: &RunEval| run.table1.get(&(Method::Ours, l)).copied();
            p.push(inp.per_run(|run| counts(run).map(|c| c.precision())));
            r.push(inp.per_run(|run| counts(run).map(|c| c.recall())));
            let mean = |m: Method, f: fn(&ObjectErrors) -> f64| {
                inp.per_run(|run| run.errors.get(&(m, l, v)).map(f))
            };
            de[0].push(mean(Method::Ours, |e| e.all.mean_single_m()));
            de[1].push(mean(Method::Ours, |e| e.all.mean_fused_m()));
            de[2].push(mean(Method::Ours, |e| e.covisible.mean_single_m()));
            de[3].push(mean(Method::Ours, |e| e.covisible.mean_fused_m()));
            de[4].push(mean(Method::Oracle, |e| e.all.mean_fused_m()));
        }
    }
    t.text("pose_noise", noise);
    t.text("fusion", fusion);
    t.stat("precision", &p);
    t.stat("recall", &r);
    let names = [
        "de_single_m",
        "de_fused_m",
        "de_single_covis_m",
        "de_fused_covis_m",
        "de_fused_oracle_m",
    ];
    for (name, samples) in names.iter().zip(&de) {
        t.stat(name, samples);
    }
    t
}

/// Every method's displacement errors per pose-noise level and fusion
/// variant: over the common object set (every real object an ego
/// detects, the same set for every method: fused where the method
/// matched, single elsewhere) and over its covisible part; means over
/// runs with 95% intervals.
fn errors(inp: &Inputs) -> Table {
    let mut t = Table::default();
    let (mut names, mut noise, mut fusion) = (vec![], vec![], vec![]);
    let mut de: [Vec<Vec<f64>>; 4] = Default::default();
    for &m in &inp.methods {
        for &l in &inp.levels {
            for &v in &inp.variants {
                names.push(m.as_str().to_owned());
                noise.push(l.as_str().to_owned());
                fusion.push(v.as_str().to_owned());
                let mean = |f: fn(&ObjectErrors) -> f64| {
                    inp.per_run(|run| run.errors.get(&(m, l, v)).map(f))
                };
                de[0].push(mean(|e| e.all.mean_single_m()));
                de[1].push(mean(|e| e.all.mean_fused_m()));
                de[2].push(mean(|e| e.covisible.mean_single_m()));
                de[3].push(mean(|e| e.covisible.mean_fused_m()));
            }
        }
    }
    t.text("method", names);
    t.text("pose_noise", noise);
    t.text("fusion", fusion);
    let columns = [
        "de_single_m",
        "de_fused_m",
        "de_single_covis_m",
        "de_fused_covis_m",
    ];
    for (name, samples) in columns.iter().zip(&de) {
        t.stat(name, samples);
    }
    t
}

/// The data of `coid eval`'s plots.
pub fn plot_data(
    settings: &Settings,
    runs: &[RunEval],
    lambdas: &BTreeMap<Method, f64>,
) -> PlotData {
    let inp = inputs(settings, runs, lambdas);
    let mean = |v: Vec<f64>| mean_ci95(&v).0;
    let lambda_sweep = inp
        .levels
        .iter()
        .map(|&l| {
            let point = |k: usize, g: f64| {
                let get = |f: fn(&PairCounts) -> f64| {
                    let key = (Method::Ours, l, inp.decision(Method::Ours), inp.kind, k);
                    mean(inp.per_run(|r| r.thresholded.get(&key).map(f)))
                };
                (
                    g,
                    get(PairCounts::precision),
                    get(PairCounts::recall),
                    get(PairCounts::f1),
                )
            };
            let pts = inp
                .grid
                .iter()
                .enumerate()
                .map(|(k, &g)| point(k, g))
                .collect();
            (l.as_str().to_owned(), pts)
        })
        .collect();
    let f1 = inp
        .levels
        .iter()
        .map(|&l| {
            let v = inp
                .methods
                .iter()
                .map(|&m| mean_ci95(&inp.per_run(|r| r.table1.get(&(m, l)).map(|c| c.f1()))))
                .collect();
            (l.as_str().to_owned(), v)
        })
        .collect();
    let reliability = inp
        .deep_methods()
        .iter()
        .map(|&m| {
            let per_level = inp
                .levels
                .iter()
                .map(|&l| (l.as_str().to_owned(), reliability(&pooled(&inp, m, l))))
                .collect();
            (m.as_str().to_owned(), per_level)
        })
        .collect();
    PlotData {
        lambda_sweep,
        methods: inp.methods.iter().map(|m| m.as_str().to_owned()).collect(),
        f1,
        errors: error_samples(&inp),
        reliability,
    }
}

/// Per level: the pooled single and fused errors of `ours` (aligned fusion
/// when configured, else paper).
fn error_samples(inp: &Inputs) -> Vec<(String, Vec<f64>, Vec<f64>)> {
    let variant = if inp.variants.contains(&FusionVariant::Aligned) {
        FusionVariant::Aligned
    } else {
        FusionVariant::Paper
    };
    inp.levels
        .iter()
        .map(|&l| {
            let (mut s, mut f) = (Vec::new(), Vec::new());
            for r in inp.runs {
                if let Some((a, b)) = r.ours_errors.get(&(l, variant)) {
                    s.extend_from_slice(a);
                    f.extend_from_slice(b);
                }
            }
            (l.as_str().to_owned(), s, f)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Settings;
    use crate::geometry::Pose2;
    use crate::matching::deep::decision::MatchDistribution;
    use crate::matching::{Correspondence, Identification};
    use crate::report::TableColumn;
    use crate::sensor::DetectionTruth;

    #[test]
    fn the_lambda_grid_has_every_twentieth_each_lambda_once_and_no_threshold() {
        let g = lambda_grid(&[0.7]);
        assert_eq!(g.len(), 22);
        assert_eq!((g[0], g[20], g[21]), (0.0, 1.0, f64::INFINITY));
        assert!(g.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(grid_index(&g, f64::INFINITY), 21);
        assert_eq!(grid_index(&g, 0.96), 19);
        let g = lambda_grid(&[0.72, 0.72, 0.33, f64::NAN, f64::INFINITY]);
        assert_eq!(g.len(), 24);
        assert!(g.contains(&0.72) && g.contains(&0.33));
        assert_eq!(
            grid_index(&g, 0.72),
            g.iter().position(|&x| x == 0.72).unwrap()
        );
    }

    /// Two vehicles that both see objects x and y (detections 0 and 1).
    fn truths() -> (ObservationTruth, ObservationTruth) {
        let t = |ids: [&str; 2]| ObservationTruth {
            ego_pose: Pose2::identity(),
            detections: ids
                .iter()
                .map(|id| DetectionTruth {
                    object_id: Some((*id).to_owned()),
                    position_m: None,
                    visible_fraction: 1.0,
                    sender: false,
                })
                .collect(),
        };
        (t(["x", "y"]), t(["x", "y"]))
    }

    /// A 2 x 2 distribution of one sample: the right pairs with
    /// probabilities `p0` and `p1`.
    fn dist(p0: f32, p1: f32) -> MatchDistribution {
        let s = vec![
            p0,
            0.0,
            1.0 - p0, //
            0.0,
            p1,
            1.0 - p1, //
            1.0 - p0,
            1.0 - p1,
            0.0,
        ];
        MatchDistribution::from_samples(2, 2, &[s])
    }

    fn run_with(dists: &[MatchDistribution], grid: &[f64]) -> RunEval {
        let (ta, tb) = truths();
        let mut run = RunEval::default();
        for d in dists {
            let matches: Vec<Correspondence> = d.decide(Some((UncertaintyKind::Total, 0.7)));
            let e = MethodEval {
                method: Method::Ours,
                counts: count_pairs(&ta, &tb, &matches),
                identification: Identification {
                    matches,
                    distribution: Some(d.clone()),
                },
                fused: vec![],
            };
            run.record(&e, PoseNoiseLabel::Gps, (&ta, &tb), grid);
        }
        run
    }

    fn numbers(t: &Table, name: &str) -> Vec<f64> {
        match t.column(name) {
            Some(TableColumn::Number(v)) => v.clone(),
            other => panic!("{name}: {other:?}"),
        }
    }

    /// Table 2 and 3 from hand-made distributions: run 1 has pairs at
    /// p = 0.95 and 0.6 (entropy 0.29 and 0.97 bits), run 2 at 0.95 and
    /// 0.95. Before thresholding both runs find both pairs (F1 1); at
    /// lambda 0.7 run 1 keeps one of two (F1 2/3), run 2 both (F1 1).
    #[test]
    fn tables_two_and_three_from_hand_made_distributions() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = dir.path().join("c.toml");
        std::fs::write(&cfg, "[pose_noise]\nlevels = [\"gps\"]\n").unwrap();
        let settings = Settings::load(&cfg).unwrap();
        let lambdas = BTreeMap::from([(Method::Ours, 0.7)]);
        let grid = lambda_grid(lambdas.values());
        let runs = vec![
            run_with(&[dist(0.95, 0.6)], &grid),
            run_with(&[dist(0.95, 0.95)], &grid),
        ];
        let t = eval_tables(&settings, &runs, &lambdas);
        assert_eq!(t.table2.height(), 1);
        assert_eq!(numbers(&t.table2, "f1_before"), vec![1.0]);
        let after = numbers(&t.table2, "f1_after")[0];
        assert!((after - (2.0 / 3.0 + 1.0) / 2.0).abs() < 1e-12, "{after}");
        let ci = numbers(&t.table2, "f1_after_ci95")[0];
        // Two runs, 2/3 and 1: s = (1/3)/sqrt(2), half-width t(1) s / sqrt(2).
        assert!((ci - 12.706204736 * (1.0 / 3.0) / 2.0).abs() < 1e-6, "{ci}");
        // Table 3: one sample per distribution, so no epistemic part: the
        // epistemic threshold keeps everything, aleatoric = entropy here.
        let f = numbers(&t.table3, "f1");
        assert_eq!(f.len(), 3);
        assert_eq!(f[0], 1.0);
        assert!((f[1] - after).abs() < 1e-12 && (f[2] - after).abs() < 1e-12);
        // Table 1 holds the default decision (thresholded for `ours`).
        assert!((numbers(&t.table1, "f1")[0] - after).abs() < 1e-12);
        assert_eq!(
            t.table1.column("n_runs"),
            Some(&TableColumn::Count(vec![2]))
        );
        // The sweep at lambda 0: nothing kept, recall 0, precision
        // undefined in both runs (not 1).
        let recall = numbers(&t.lambda_sweep, "recall");
        assert_eq!(recall.len(), grid.len());
        assert_eq!(recall[0], 0.0);
        assert!(numbers(&t.lambda_sweep, "precision")[0].is_nan());
        match t.lambda_sweep.column("n_runs_precision") {
            Some(TableColumn::Count(n)) => assert_eq!((n[0], n[grid.len() - 1]), (0, 2)),
            other => panic!("{other:?}"),
        }
    }
}
