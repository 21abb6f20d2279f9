//! `reid_sweep` (`coid eval --reid-sweep R1,R2,...`): where learned and learning-free
//! matching cross as appearance gets better. At each point the
//! re-identification descriptor is calibrated on the validation runs to
//! cross-view rank-1 R (`[appearance] rank1`, `auroc = "free"`), the
//! methods run with the models and baseline choices made at that point
//! (`<models_dir>/rank1-<R>`, by `coid train --reid-rank1 R`), on the
//! validation runs and on the test runs: every method's F1 (mean and 95%
//! interval over runs) and AP, and the paired differences that answer the
//! question (the paper's method against MOGM, `ours` against GPS+appearance
//! Hungarian).

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::{Common, ConfigSource, Event};
use crate::config::{Overrides, Settings};
use crate::io::{self, OutputError};
use crate::matching::deep::arch::Backbone;
use crate::matching::{self, BaselineChoice, Inputs, Method};
use crate::report::{PairedDifference, Table, mean_ci95, paired_bootstrap};
use crate::sensor::PoseNoiseLabel;
use crate::tables::{MethodLevel, RunEval};
use crate::{experiments, pipeline, render};

/// The models folder of the point at rank-1 `r` under `models_dir`.
pub fn point_models_dir(models_dir: &Path, r: f64) -> PathBuf {
    models_dir.join(format!("rank1-{r:.2}"))
}

/// One method at one point, split and level.
struct Row {
    method: Method,
    /// What the method made of the descriptor at this point.
    descriptor: String,
    rank1: f64,
    measured: (f64, f64),
    split: &'static str,
    level: PoseNoiseLabel,
    f1: Vec<f64>,
    ap: f64,
}

/// The comparisons the sweep is for: (method, against it), each at the
/// level where both are read.
const PAIRS: [(Method, Method); 2] = [
    (Method::Coid, Method::Mogm),
    (Method::Ours, Method::GpsAppHungarian),
];

/// A re-identification sweep to run.
#[derive(Clone, Debug, PartialEq)]
pub struct ReidSweepRequest {
    pub common: Common,
    /// The cross-view rank-1 rates of the points, each in (0, 1).
    pub points: Vec<f64>,
}

/// What a sweep wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct ReidSweepReport {
    pub folder: PathBuf,
    /// `reid_sweep_differences.csv` as a Markdown table.
    pub differences: String,
    /// What was swept, in one line (the folder named last).
    pub line: String,
}

/// Runs every configured method at each point of `request` on the
/// validation and the test runs, with the models and baseline choices of
/// `<models_dir>/rank1-<R>`, and writes `reid_sweep.csv`,
/// `reid_sweep_differences.csv` and their picture (into
/// `results/<config stem>-reid-sweep` by default).
///
/// # Errors
/// A point is no rate or named twice, the configuration has no
/// descriptor, a point's models folder is missing, a run fails, or the
/// folder is taken; nothing is then written.
pub fn reid_sweep(
    request: &ReidSweepRequest,
    mut on: impl FnMut(Event),
) -> anyhow::Result<ReidSweepReport> {
    let common = &request.common;
    let threads = super::threads(common.threads)?;
    let points = &request.points;
    // The config is read here only to refuse a bad one before the folder
    // is claimed: each point calibrates its own descriptor.
    common.config.load(&Overrides::default())?;
    let claim = common.claim("-reid-sweep", None, io::ResultKind::Eval)?;
    for (k, &r) in points.iter().enumerate() {
        if !(r > 0.0 && r < 1.0) {
            anyhow::bail!("--reid-sweep: a rank-1 must be a rate in (0, 1), got {r}");
        }
        if points[..k]
            .iter()
            .any(|&p| format!("{p:.2}") == format!("{r:.2}"))
        {
            anyhow::bail!("--reid-sweep names the point {r:.2} twice");
        }
    }
    let mut rows = Vec::new();
    let warnings = pipeline::Warnings::default();
    for &r in points {
        let s = point_settings(&common.config, r, &mut on)?;
        let methods = s.matching.methods.clone();
        let lambdas = matching::method_lambdas(&pipeline::choices(&s, &methods)?);
        let measured = s
            .appearance
            .reid
            .as_ref()
            .and_then(|x| x.calibration.as_ref())
            .map_or((f64::NAN, f64::NAN), |c| (c.figures.rank1, c.figures.auroc));
        let levels: Vec<PoseNoiseLabel> = s.pose_noise.iter().map(|l| l.label).collect();
        let uses = methods
            .iter()
            .map(|&m| descriptor_use(&s, m))
            .collect::<anyhow::Result<Vec<String>>>()?;
        let splits = [
            ("validation", experiments::validation_runs(&s)?),
            ("test", experiments::test_runs(&s)?),
        ];
        for (split, runs) in splits {
            let current = format!("rank-1 {r:.2} ({split})");
            let mut evals = Vec::with_capacity(runs.len());
            for run in &runs {
                on(Event::Runs {
                    done: evals.len(),
                    total: runs.len(),
                    current: &current,
                });
                let e = experiments::eval_run(run, &methods, &lambdas, threads, &warnings, |_| {})
                    .with_context(|| format!("{split} run (seed {}) failed", run.seeds.traffic))?;
                evals.push(e);
            }
            let rows_here = rows_of(&evals, (&methods, &uses), &levels, (r, measured), split);
            rows.extend(rows_here);
        }
    }
    let (table, differences) = (sweep_table(&rows), differences_table(&rows));
    let out = claim.out().to_owned();
    claim.fill(|dir| {
        let tables = [
            ("reid_sweep.csv", &table),
            ("reid_sweep_differences.csv", &differences),
        ];
        io::write_tracking(dir, &tables, |dir| {
            render::line_panels(&dir.join("reid_sweep"), &panels(&rows))
                .map_err(|e| OutputError::picture(dir, e))
        })
    })?;
    let line = format!(
        "coid: swept {} re-identification qualities; wrote {}",
        points.len(),
        out.display()
    );
    Ok(ReidSweepReport {
        folder: out,
        differences: io::markdown::table(&differences),
        line,
    })
}

/// The settings of the point at rank-1 `r`: the config with `rank1 = r`,
/// `auroc = "free"`, its models folder, the descriptor calibrated.
fn point_settings(
    config: &ConfigSource,
    r: f64,
    on: &mut impl FnMut(Event),
) -> anyhow::Result<Settings> {
    let overrides = Overrides {
        reid_rank1: Some(r),
        ..Overrides::default()
    };
    let s = config.load(&overrides)?;
    let shown = config.shown();
    if s.appearance.reid.is_none() {
        anyhow::bail!(
            "--reid-sweep sweeps the re-identification descriptor: {shown} sets [appearance] \
             descriptor = \"none\""
        );
    }
    let dir = point_models_dir(&s.matching.models_dir, r);
    if !dir.is_dir() {
        anyhow::bail!(
            "{} is missing: the point at rank-1 {r:.2} runs the models and baseline choices \
             made there (coid train {}--reid-rank1 {r:.2} --out {})",
            dir.display(),
            if matches!(config, ConfigSource::Defaults) {
                String::new()
            } else {
                format!("--config {shown} ")
            },
            dir.display()
        );
    }
    super::calibrated(&s.with_models(&dir), on)
}

/// What `method` makes of the descriptor with the choices of `s`'s
/// models folder: a deep network's node attributes "read" or "left
/// out" (as `coid train` chose on the validation runs; the project's
/// network also starts from the shared likelihood, which weighs the
/// cosine's likelihood ratio at 1), a baseline's weight on that ratio, or
/// "not used".
fn descriptor_use(s: &Settings, method: Method) -> anyhow::Result<String> {
    let dir = &s.matching.models_dir;
    if let Some(backbone) = method.backbone() {
        let w = io::read_weights(dir, method)?;
        let attributes = if !w.appearance_width.is_none() {
            "read"
        } else {
            "left out"
        };
        return Ok(match backbone {
            Backbone::Likelihood(_) => format!("likelihood weight 1, attributes {attributes}"),
            Backbone::Published(_) => format!("attributes {attributes}"),
        });
    }
    if !method.weighs_descriptors() {
        return Ok("not used".to_owned());
    }
    // The weight the runner reads: the validated one, or the configured.
    let tuned = if s.matching.baselines == BaselineChoice::Validated {
        io::read_baselines(dir, &[method])?.get(&method).copied()
    } else {
        None
    };
    let weight = s.matching.baseline(tuned, method).descriptor_weight;
    Ok(format!("weight {weight:.2}"))
}

/// The rows of one point on one split: each method at each level (a
/// method on the paper's inputs, the same at every level, at the first).
fn rows_of(
    evals: &[RunEval],
    (methods, uses): (&[Method], &[String]),
    levels: &[PoseNoiseLabel],
    (rank1, measured): (f64, (f64, f64)),
    split: &'static str,
) -> Vec<Row> {
    let mut rows = Vec::new();
    for key in MethodLevel::read_at(methods, levels) {
        let pairs: Vec<_> = evals
            .iter()
            .filter_map(|e| e.scored.get(&key))
            .flatten()
            .cloned()
            .collect();
        let truth: usize = evals
            .iter()
            .filter_map(|e| e.table1.get(&key).map(|c| c.ground_truth))
            .sum();
        let k = methods.iter().position(|m| *m == key.method).unwrap_or(0);
        rows.push(Row {
            method: key.method,
            descriptor: uses.get(k).cloned().unwrap_or_default(),
            rank1,
            measured,
            split,
            level: key.pose_noise,
            f1: key.f1_per_run(evals),
            ap: crate::tables::average_precision(&pairs, truth),
        });
    }
    rows
}

/// `reid_sweep.csv`: per point, split, method and level, F1's mean and
/// 95% interval over runs and the pooled AP.
fn sweep_table(rows: &[Row]) -> Table {
    let mut t = Table::default();
    let texts = |f: fn(&Row) -> String| rows.iter().map(f).collect::<Vec<_>>();
    t.number("rank1_target", rows.iter().map(|r| r.rank1).collect());
    t.number(
        "rank1_validation",
        rows.iter().map(|r| r.measured.0).collect(),
    );
    t.number(
        "auroc_validation",
        rows.iter().map(|r| r.measured.1).collect(),
    );
    t.text("split", texts(|r| r.split.to_owned()));
    t.text("method", texts(|r| r.method.as_str().to_owned()));
    t.text("pose_noise", texts(|r| r.level.as_str().to_owned()));
    t.text("descriptor", texts(|r| r.descriptor.clone()));
    t.count("n_runs", rows.iter().map(|r| r.f1.len() as u64).collect());
    let samples: Vec<Vec<f64>> = rows.iter().map(|r| r.f1.clone()).collect();
    t.stat("f1", &samples);
    t.number("ap", rows.iter().map(|r| r.ap).collect());
    t
}

/// The row of `method` at the level it is compared at (its first level on
/// the paper's inputs, else GPS).
fn compared<'a>(rows: &'a [Row], method: Method, rank1: f64, split: &str) -> Option<&'a Row> {
    rows.iter()
        .filter(|r| r.method == method && r.rank1 == rank1 && r.split == split)
        .find(|r| method.inputs() == Inputs::Paper || r.level == PoseNoiseLabel::GPS)
}

/// `reid_sweep_differences.csv`: per point and split, each comparison's
/// paired difference of F1 over runs with its bootstrap interval.
fn differences_table(rows: &[Row]) -> Table {
    let mut points: Vec<(f64, &'static str)> = Vec::new();
    for r in rows {
        if !points.contains(&(r.rank1, r.split)) {
            points.push((r.rank1, r.split));
        }
    }
    let mut out: Vec<(f64, &str, String, PairedDifference)> = Vec::new();
    for (rank1, split) in points {
        for (a, b) in PAIRS {
            if let (Some(x), Some(y)) = (
                compared(rows, a, rank1, split),
                compared(rows, b, rank1, split),
            ) {
                let d = paired_bootstrap(&x.f1, &y.f1, 52);
                out.push((rank1, split, format!("{} - {}", a.as_str(), b.as_str()), d));
            }
        }
    }
    let mut t = Table::default();
    t.number("rank1_target", out.iter().map(|o| o.0).collect());
    t.text("split", out.iter().map(|o| o.1.to_owned()).collect());
    t.text("difference", out.iter().map(|o| o.2.clone()).collect());
    t.count("n_runs", out.iter().map(|o| o.3.n as u64).collect());
    t.number("f1_difference", out.iter().map(|o| o.3.mean).collect());
    t.number("ci95_low", out.iter().map(|o| o.3.lo).collect());
    t.number("ci95_high", out.iter().map(|o| o.3.hi).collect());
    t
}

/// F1 against the rank-1 rate, one panel per split: a line per method at
/// the level it is compared at, its 95% interval as a band.
fn panels(rows: &[Row]) -> Vec<render::Panel> {
    // The oracle (1 everywhere) would only squeeze the others' scale.
    let mut methods: Vec<Method> = Vec::new();
    for r in rows.iter().filter(|r| r.method != Method::Oracle) {
        if !methods.contains(&r.method) {
            methods.push(r.method);
        }
    }
    ["validation", "test"]
        .into_iter()
        .map(|split| {
            let mut series = Vec::new();
            let mut bands = Vec::new();
            let mut all = Vec::new();
            for &m in &methods {
                let (points, ci): (Vec<(f64, f64)>, Vec<f64>) = rows
                    .iter()
                    .filter(|r| r.method == m && r.split == split)
                    .filter(|r| m.inputs() == Inputs::Paper || r.level == PoseNoiseLabel::GPS)
                    .map(|r| {
                        let (mean, c) = mean_ci95(&r.f1);
                        ((r.rank1, mean), c)
                    })
                    .filter(|((_, mean), _)| mean.is_finite())
                    .unzip();
                all.extend(points.iter().zip(&ci).map(|(&(_, m), &c)| (m, c)));
                series.push((m.as_str().to_owned(), points));
                bands.push(ci);
            }
            render::Panel {
                title: format!("F1 against re-identification quality ({split} runs)"),
                x_label: "cross-view rank-1 of the descriptor".into(),
                y_label: "F1, mean over runs (band: 95% CI; GPS methods at 1.2 m)".into(),
                x_range: (0.0, 1.0),
                // From 0: the legend (lower right) sits under the lines.
                y_range: (0.0, render::fitted_range(&all, 0.05).1),
                series,
                bands,
            }
        })
        .collect()
}
