//! Multi-run experiments built on the pipeline: collecting training pairs
//! from the training runs, and training the deep matchers. No file IO here
//! (the caller saves through `output` and `matching::deep::model`).

use std::collections::{BTreeMap, HashMap};

use crate::config::{FusionVariant, PoseNoiseLabel, Settings};
use crate::eval::{self, EgoSide, PairCounts};
use crate::matching::Method;
use crate::matching::deep::model::Network;
use crate::matching::deep::train::{self, Example, TrainOptions, TrainReport};
use crate::matching::deep::{self, decision::UncertaintyKind};
use crate::pipeline::{self, Progress, RunError};

/// The settings of run `seed`: traffic and sensor seeds both set to it.
pub fn settings_for_seed(settings: &Settings, seed: u64) -> Settings {
    let mut s = settings.clone();
    s.seeds.traffic = seed;
    s.seeds.sensor = seed;
    s
}

/// Labelled pairs from every training run, at every configured pose-noise
/// level (the same pair under each level's GPS error, so the network learns
/// how far to trust the GPS position prior). `progress(run, runs, examples
/// so far)`.
pub fn collect_examples(
    settings: &Settings,
    mut progress: impl FnMut(usize, usize, usize),
) -> Result<Vec<Example>, RunError> {
    let seeds = &settings.train.traffic_seeds;
    let mut examples = Vec::new();
    for (k, &seed) in seeds.iter().enumerate() {
        let run = settings_for_seed(settings, seed);
        pipeline::simulate(
            &run,
            |_: Progress| {},
            |inst| {
                for level in &settings.pose_noise {
                    let (first, second) = inst.views(seed, level);
                    examples.extend(train::example(&first, &second));
                }
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

/// The threshold grid of the lambda sweep (binary entropy in bits): 0 to 1
/// by 0.05, plus the configured lambda.
pub fn lambda_grid(configured: f64) -> Vec<f64> {
    let mut g: Vec<f64> = (0..=20).map(|k| k as f64 * 0.05).collect();
    g.push(configured);
    g.sort_by(f64::total_cmp);
    g.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    g
}

/// What one test run contributes to the tables.
#[derive(Clone, Debug, Default)]
pub struct RunEval {
    /// Table 1: each method with its default decision.
    pub table1: BTreeMap<(Method, PoseNoiseLabel), PairCounts>,
    /// Deep methods without thresholding.
    pub unthresholded: BTreeMap<(Method, PoseNoiseLabel), PairCounts>,
    /// Deep methods thresholded: (method, level, kind, index into
    /// [`lambda_grid`]).
    pub thresholded: BTreeMap<(Method, PoseNoiseLabel, UncertaintyKind, usize), PairCounts>,
    /// Displacement errors per (method, level, fusion): sums and count.
    pub errors: BTreeMap<(Method, PoseNoiseLabel, FusionVariant), (f64, f64, usize)>,
    /// Every object's single and fused error of the full method (`ours`),
    /// for the error CDFs.
    pub ours_errors: BTreeMap<(PoseNoiseLabel, FusionVariant), (Vec<f64>, Vec<f64>)>,
    pub instances: usize,
}

/// Evaluates every method on one test run (`settings` already carries the
/// run's seeds).
pub fn eval_run(
    settings: &Settings,
    methods: &[Method],
    mut progress: impl FnMut(Progress),
) -> Result<RunEval, RunError> {
    let m = &settings.matching;
    let mut deep = Vec::new();
    let mut plain = Vec::new();
    for &method in methods {
        if deep::variant(method).is_some() {
            let threshold =
                deep::thresholds_by_default(method).then_some((m.uncertainty, m.lambda));
            deep.push(deep::DeepMatcher::load(
                method,
                &m.models_dir,
                m.mc_samples,
                threshold,
                settings.seeds.sensor,
            )?);
        } else {
            plain.push(crate::matching::matcher_for(
                method,
                m,
                settings.seeds.sensor,
            )?);
        }
    }
    let grid = lambda_grid(m.lambda);
    let kinds = [
        UncertaintyKind::Total,
        UncertaintyKind::Epistemic,
        UncertaintyKind::Aleatoric,
    ];
    let mut out = RunEval::default();
    let stats = pipeline::simulate(settings, &mut progress, |inst| {
        let (a, b, frame) = (inst.a, inst.b, inst.frame);
        let truth: HashMap<&str, crate::geometry::Vec2> = frame
            .objects
            .iter()
            .map(|o| (o.id.as_str(), o.pose.position_m()))
            .collect();
        for level in &settings.pose_noise {
            let (va, vb) = inst.views(settings.seeds.sensor, level);
            let (pa, pb) = (va.pose_reported, vb.pose_reported);
            let mut decided: Vec<(Method, Vec<crate::matching::Correspondence>)> = Vec::new();
            for d in &deep {
                let dist = d.distribution(&va, &vb);
                let key = (d.method, level.label);
                out.unthresholded
                    .entry(key)
                    .or_default()
                    .add(eval::count_pairs(&a.obs, &b.obs, &dist.decide(None)));
                for kind in kinds {
                    for (k, &lambda) in grid.iter().enumerate() {
                        let c =
                            eval::count_pairs(&a.obs, &b.obs, &dist.decide(Some((kind, lambda))));
                        out.thresholded
                            .entry((d.method, level.label, kind, k))
                            .or_default()
                            .add(c);
                    }
                }
                decided.push((d.method, dist.decide(d.threshold)));
            }
            for p in &plain {
                decided.push((p.method(), p.match_pair(&va, &vb)));
            }
            for (method, matches) in decided {
                out.table1
                    .entry((method, level.label))
                    .or_default()
                    .add(eval::count_pairs(&a.obs, &b.obs, &matches));
                let side_a = EgoSide {
                    obs: &a.obs,
                    pose_reported: pa,
                };
                let side_b = EgoSide {
                    obs: &b.obs,
                    pose_reported: pb,
                };
                for &variant in &settings.fusion.variants {
                    let min = settings.fusion.align_min_matches;
                    let est =
                        eval::fuse_pair(&side_a, &side_b, &matches, level, variant, min, &truth);
                    if method == Method::Ours {
                        let o = out.ours_errors.entry((level.label, variant)).or_default();
                        o.0.extend(est.iter().map(|x| x.single_error_m()));
                        o.1.extend(est.iter().map(|x| x.fused_error_m()));
                    }
                    let e = out
                        .errors
                        .entry((method, level.label, variant))
                        .or_default();
                    e.0 += est.iter().map(|x| x.single_error_m()).sum::<f64>();
                    e.1 += est.iter().map(|x| x.fused_error_m()).sum::<f64>();
                    e.2 += est.len();
                }
            }
        }
        Ok(())
    })?;
    out.instances = stats.n_instances;
    Ok(out)
}

/// Mean and half-width of the 95% confidence interval (Student t) of a
/// sample; the half-width is NaN for fewer than two values.
pub fn mean_ci95(values: &[f64]) -> (f64, f64) {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    let n = v.len();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let mean = v.iter().sum::<f64>() / n as f64;
    if n < 2 {
        return (mean, f64::NAN);
    }
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (mean, t_975(n - 1) * (var / n as f64).sqrt())
}

/// The 97.5% quantile of Student's t with `dof` degrees of freedom.
fn t_975(dof: usize) -> f64 {
    const TABLE: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    match dof {
        0 => f64::NAN,
        1..=30 => TABLE[dof - 1],
        31..=60 => 2.000 + (2.042 - 2.000) * (60 - dof) as f64 / 30.0,
        _ => 1.96,
    }
}

/// A table for the results folder: named columns of text or numbers.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    pub columns: Vec<(String, TableColumn)>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum TableColumn {
    Text(Vec<String>),
    Number(Vec<f64>),
}

impl Table {
    fn text(&mut self, name: &str, v: Vec<String>) {
        self.columns.push((name.into(), TableColumn::Text(v)));
    }
    fn number(&mut self, name: &str, v: Vec<f64>) {
        self.columns.push((name.into(), TableColumn::Number(v)));
    }
    /// Adds `name` and `name_ci95` from per-run samples.
    fn stat(&mut self, name: &str, samples: &[Vec<f64>]) {
        let (m, c): (Vec<f64>, Vec<f64>) = samples.iter().map(|s| mean_ci95(s)).unzip();
        self.number(name, m);
        self.number(&format!("{name}_ci95"), c);
    }
}

/// The paper's tables over the test runs: each metric's mean over runs and
/// the half-width of its 95% confidence interval.
pub struct EvalTables {
    pub table1: Table,
    pub table2: Table,
    pub table3: Table,
    pub lambda_sweep: Table,
    pub case_study: Table,
}

pub fn eval_tables(settings: &Settings, runs: &[RunEval]) -> EvalTables {
    let levels: Vec<PoseNoiseLabel> = settings.pose_noise.iter().map(|l| l.label).collect();
    let per_run =
        |f: &dyn Fn(&RunEval) -> Option<f64>| -> Vec<f64> { runs.iter().filter_map(f).collect() };
    let methods: Vec<Method> = runs
        .first()
        .map(|r| {
            let mut m: Vec<Method> = r.table1.keys().map(|k| k.0).collect();
            m.dedup();
            m
        })
        .unwrap_or_default();

    let mut t1 = Table::default();
    let (mut names, mut noise, mut p, mut r, mut f) = (vec![], vec![], vec![], vec![], vec![]);
    for &m in &methods {
        for &l in &levels {
            names.push(m.as_str().to_owned());
            noise.push(l.as_str().to_owned());
            p.push(per_run(&|run| {
                run.table1.get(&(m, l)).map(|c| c.precision())
            }));
            r.push(per_run(&|run| run.table1.get(&(m, l)).map(|c| c.recall())));
            f.push(per_run(&|run| run.table1.get(&(m, l)).map(|c| c.f1())));
        }
    }
    t1.text("method", names);
    t1.text("pose_noise", noise);
    t1.stat("precision", &p);
    t1.stat("recall", &r);
    t1.stat("f1", &f);
    t1.number("n_runs", vec![runs.len() as f64; p.len()]);

    let grid = lambda_grid(settings.matching.lambda);
    let at = grid
        .iter()
        .position(|g| (g - settings.matching.lambda).abs() < 1e-9)
        .unwrap_or(0);
    let kind = settings.matching.uncertainty;
    let deep_methods: Vec<Method> = methods
        .iter()
        .copied()
        .filter(|m| deep::variant(*m).is_some())
        .collect();
    let mut t2 = Table::default();
    let (mut names, mut noise, mut before, mut after) = (vec![], vec![], vec![], vec![]);
    for &m in &deep_methods {
        for &l in &levels {
            names.push(m.as_str().to_owned());
            noise.push(l.as_str().to_owned());
            before.push(per_run(&|run| {
                run.unthresholded.get(&(m, l)).map(|c| c.f1())
            }));
            after.push(per_run(&|run| {
                run.thresholded.get(&(m, l, kind, at)).map(|c| c.f1())
            }));
        }
    }
    t2.text("method", names);
    t2.text("pose_noise", noise);
    t2.stat("f1_before", &before);
    t2.stat("f1_after", &after);

    let mut t3 = Table::default();
    let mut sweep = Table::default();
    let mut case = Table::default();
    if deep_methods.contains(&Method::Ours) {
        let m = Method::Ours;
        let (mut kinds, mut noise, mut f) = (vec![], vec![], vec![]);
        for &l in &levels {
            for k in [
                UncertaintyKind::Epistemic,
                UncertaintyKind::Aleatoric,
                UncertaintyKind::Total,
            ] {
                kinds.push(k.as_str().to_owned());
                noise.push(l.as_str().to_owned());
                f.push(per_run(&|run| {
                    run.thresholded.get(&(m, l, k, at)).map(|c| c.f1())
                }));
            }
        }
        t3.text("uncertainty", kinds);
        t3.text("pose_noise", noise);
        t3.stat("f1", &f);

        let (mut lam, mut noise, mut p, mut r, mut f) = (vec![], vec![], vec![], vec![], vec![]);
        for &l in &levels {
            for (k, &g) in grid.iter().enumerate() {
                lam.push(g);
                noise.push(l.as_str().to_owned());
                let get = |run: &RunEval| run.thresholded.get(&(m, l, kind, k)).copied();
                p.push(per_run(&|run| get(run).map(|c| c.precision())));
                r.push(per_run(&|run| get(run).map(|c| c.recall())));
                f.push(per_run(&|run| get(run).map(|c| c.f1())));
            }
        }
        sweep.number("lambda", lam);
        sweep.text("pose_noise", noise);
        sweep.stat("precision", &p);
        sweep.stat("recall", &r);
        sweep.stat("f1", &f);

        let (mut noise, mut fusion, mut p, mut r, mut ds, mut df) =
            (vec![], vec![], vec![], vec![], vec![], vec![]);
        for &l in &levels {
            for &v in &settings.fusion.variants {
                noise.push(l.as_str().to_owned());
                fusion.push(v.as_str().to_owned());
                p.push(per_run(&|run| {
                    run.table1.get(&(m, l)).map(|c| c.precision())
                }));
                r.push(per_run(&|run| run.table1.get(&(m, l)).map(|c| c.recall())));
                let err = |run: &RunEval, fused: bool| {
                    run.errors
                        .get(&(m, l, v))
                        .filter(|e| e.2 > 0)
                        .map(|e| if fused { e.1 } else { e.0 } / e.2 as f64)
                };
                ds.push(per_run(&|run| err(run, false)));
                df.push(per_run(&|run| err(run, true)));
            }
        }
        case.text("pose_noise", noise);
        case.text("fusion", fusion);
        case.stat("precision", &p);
        case.stat("recall", &r);
        case.stat("de_single_m", &ds);
        case.stat("de_fused_m", &df);
    }
    EvalTables {
        table1: t1,
        table2: t2,
        table3: t3,
        lambda_sweep: sweep,
        case_study: case,
    }
}

/// One point of the lambda sweep: (lambda, precision, recall, F1).
pub type SweepPoint = (f64, f64, f64, f64);

/// The data behind `coid eval`'s plots.
pub struct PlotData {
    /// Per level: (level, points) of `ours`.
    pub lambda_sweep: Vec<(String, Vec<SweepPoint>)>,
    /// Methods, and per level the (mean, ci) F1 of each method.
    pub methods: Vec<String>,
    pub f1: Vec<(String, Vec<(f64, f64)>)>,
    /// Per level: pooled single and fused errors of `ours` (aligned fusion
    /// when configured, else paper).
    pub errors: Vec<(String, Vec<f64>, Vec<f64>)>,
}

pub fn plot_data(settings: &Settings, runs: &[RunEval]) -> PlotData {
    let levels: Vec<PoseNoiseLabel> = settings.pose_noise.iter().map(|l| l.label).collect();
    let grid = lambda_grid(settings.matching.lambda);
    let kind = settings.matching.uncertainty;
    let mean = |v: Vec<f64>| mean_ci95(&v).0;
    let lambda_sweep = levels
        .iter()
        .map(|&l| {
            let pts = grid
                .iter()
                .enumerate()
                .map(|(k, &g)| {
                    let get = |f: fn(&PairCounts) -> f64| {
                        mean(
                            runs.iter()
                                .filter_map(|r| {
                                    r.thresholded.get(&(Method::Ours, l, kind, k)).map(f)
                                })
                                .collect(),
                        )
                    };
                    (
                        g,
                        get(PairCounts::precision),
                        get(PairCounts::recall),
                        get(PairCounts::f1),
                    )
                })
                .collect();
            (l.as_str().to_owned(), pts)
        })
        .collect();
    let mut methods: Vec<Method> = runs
        .first()
        .map(|r| r.table1.keys().map(|k| k.0).collect())
        .unwrap_or_default();
    methods.dedup();
    let f1 = levels
        .iter()
        .map(|&l| {
            let v = methods
                .iter()
                .map(|&m| {
                    mean_ci95(
                        &runs
                            .iter()
                            .filter_map(|r| r.table1.get(&(m, l)).map(|c| c.f1()))
                            .collect::<Vec<_>>(),
                    )
                })
                .collect();
            (l.as_str().to_owned(), v)
        })
        .collect();
    let variant = if settings.fusion.variants.contains(&FusionVariant::Aligned) {
        FusionVariant::Aligned
    } else {
        FusionVariant::Paper
    };
    let errors = levels
        .iter()
        .map(|&l| {
            let (mut s, mut f) = (Vec::new(), Vec::new());
            for r in runs {
                if let Some((a, b)) = r.ours_errors.get(&(l, variant)) {
                    s.extend_from_slice(a);
                    f.extend_from_slice(b);
                }
            }
            (l.as_str().to_owned(), s, f)
        })
        .collect();
    PlotData {
        lambda_sweep,
        methods: methods.iter().map(|m| m.as_str().to_owned()).collect(),
        f1,
        errors,
    }
}
