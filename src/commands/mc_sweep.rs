//! `mc_sweep` (`coid eval --mc-sweep`): the paper's Fig. 8b for the paper's method
//! (`coid`) and `ours`, those of them `[matching] methods` lists. The number of
//! MC-dropout samples T (1, 10, 20, ..., 100, at the trained dropout
//! rates) and the dropout rate at inference (0.1 to 0.8 in every layer,
//! T = 20), one at a time, each on the validation runs (where a setting may
//! be chosen) and on the test runs (the curve beside it), at the validated
//! decision and thresholds. T = 1 is one pass with one dropout draw.

use std::path::PathBuf;

use anyhow::Context;

use super::{Common, Event};
use crate::config::Overrides;
use crate::io::{self, OutputError};
use crate::matching::{self, Method};
use crate::report::{Table, mean_ci95};
use crate::sensor::PoseNoiseLabel;
use crate::tables::{MethodLevel, RunEval};
use crate::{experiments, pipeline, render};

/// The sample counts of the sweep.
const SAMPLES: [usize; 11] = [1, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100];
/// The dropout rates of the sweep.
const RATES: [f64; 8] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8];
/// T while the rate is swept (the paper's).
const SAMPLES_AT_RATES: usize = 20;

/// One setting of the sweep.
#[derive(Clone, Copy)]
struct Setting {
    factor: &'static str,
    value: f64,
    samples: usize,
    rate: Option<f64>,
}

fn settings_of_sweep() -> Vec<Setting> {
    let by_samples = SAMPLES.iter().map(|&t| Setting {
        factor: "samples",
        value: t as f64,
        samples: t,
        rate: None,
    });
    let by_rate = RATES.iter().map(|&p| Setting {
        factor: "dropout",
        value: p,
        samples: SAMPLES_AT_RATES,
        rate: Some(p),
    });
    by_samples.chain(by_rate).collect()
}

/// One row: a method at a setting on one split at one level, with its
/// per-run F1.
struct Row {
    method: Method,
    setting: Setting,
    split: &'static str,
    level: PoseNoiseLabel,
    f1: Vec<f64>,
}

/// What a sweep wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct McSweepReport {
    pub folder: PathBuf,
    /// What was swept, in one line (the folder named last).
    pub line: String,
}

/// Sweeps T and the dropout rate of `coid` and `ours` (those of them
/// `[matching] methods` lists) on the validation and the test runs of
/// `common`'s configuration, and writes `mc_sweep.csv` and its picture
/// (into `results/<config stem>-mc-sweep` by default).
///
/// # Errors
/// The configuration lists neither method, a run fails, or the folder
/// is taken; nothing is then written.
pub fn mc_sweep(common: &Common, mut on: impl FnMut(Event)) -> anyhow::Result<McSweepReport> {
    let threads = super::threads(common.threads)?;
    let settings = super::prepare(&common.config, &Overrides::default(), None, &mut on)?;
    let claim = common.claim("-mc-sweep", None, io::ResultKind::Eval)?;
    let methods: Vec<Method> = settings
        .matching
        .methods
        .iter()
        .copied()
        .filter(|m| matches!(m, Method::Coid | Method::Ours))
        .collect();
    if methods.is_empty() {
        anyhow::bail!("--mc-sweep sweeps coid and ours: [matching] methods lists neither");
    }
    let lambdas = matching::method_lambdas(&pipeline::choices(&settings, &methods)?);
    let splits = [
        ("validation", experiments::validation_runs(&settings)?),
        ("test", experiments::test_runs(&settings)?),
    ];
    let sweep = settings_of_sweep();
    let total: usize = splits.iter().map(|(_, r)| r.len()).sum::<usize>() * sweep.len();
    let levels: Vec<PoseNoiseLabel> = settings.pose_noise.iter().map(|l| l.label).collect();
    let mut rows = Vec::new();
    let warnings = crate::pipeline::Warnings::default();
    let mut done = 0;
    for setting in &sweep {
        for (split, runs) in &splits {
            let current = format!("{} {} ({split})", setting.factor, setting.value);
            let mut evals: Vec<RunEval> = Vec::new();
            for run in runs {
                on(Event::Runs {
                    done,
                    total,
                    current: &current,
                });
                let s = run.with_inference(setting.samples, setting.rate)?;
                let e = experiments::eval_run(&s, &methods, &lambdas, threads, &warnings, |_| {})
                    .with_context(|| {
                    format!("{split} run (seed {}) failed", s.seeds.traffic)
                })?;
                evals.push(e);
                done += 1;
            }
            rows.extend(rows_of(&evals, &methods, &levels, *setting, split));
        }
    }
    let table = sweep_table(&rows);
    let panels: Vec<render::Panel> = methods.iter().flat_map(|&m| panels(&rows, m)).collect();
    let out = claim.out().to_owned();
    claim.fill(|dir| {
        io::write_tracking(dir, &[("mc_sweep.csv", &table)], |dir| {
            render::line_panels(&dir.join("mc_sweep"), &panels)
                .map_err(|e| OutputError::picture(dir, e))
        })
    })?;
    let line = format!(
        "coid: swept {} settings of {} on {} validation and {} test runs; wrote {}",
        sweep.len(),
        methods
            .iter()
            .map(|m| m.as_str())
            .collect::<Vec<_>>()
            .join(" and "),
        splits[0].1.len(),
        splits[1].1.len(),
        out.display()
    );
    Ok(McSweepReport { folder: out, line })
}

/// The rows of one setting on one split: each method at each level (a
/// method on the paper's inputs, the same at every level, at the first).
fn rows_of(
    evals: &[RunEval],
    methods: &[Method],
    levels: &[PoseNoiseLabel],
    setting: Setting,
    split: &'static str,
) -> Vec<Row> {
    MethodLevel::read_at(methods, levels)
        .into_iter()
        .map(|key| Row {
            method: key.method,
            setting,
            split,
            level: key.pose_noise,
            f1: key.f1_per_run(evals),
        })
        .collect()
}

/// `mc_sweep.csv`: per setting, split and level, F1's mean and 95%
/// interval over runs.
fn sweep_table(rows: &[Row]) -> Table {
    let mut t = Table::default();
    let texts = |f: fn(&Row) -> String| rows.iter().map(f).collect::<Vec<_>>();
    t.text("method", texts(|r| r.method.as_str().to_owned()));
    t.text("factor", texts(|r| r.setting.factor.to_owned()));
    t.number("value", rows.iter().map(|r| r.setting.value).collect());
    t.text("split", texts(|r| r.split.to_owned()));
    t.text("pose_noise", texts(|r| r.level.as_str().to_owned()));
    t.count("n_runs", rows.iter().map(|r| r.f1.len() as u64).collect());
    let samples: Vec<Vec<f64>> = rows.iter().map(|r| r.f1.clone()).collect();
    t.stat("f1", &samples);
    t
}

/// `method`'s F1 against T and against the dropout rate: a line per
/// split and level, its 95% interval as a band.
fn panels(rows: &[Row], method: Method) -> Vec<render::Panel> {
    let rows: Vec<&Row> = rows.iter().filter(|r| r.method == method).collect();
    let name = method.as_str();
    let panel = |factor: &str, title: &str, x_label: &str, x_range: (f64, f64)| {
        let mut keys: Vec<(&str, PoseNoiseLabel)> = Vec::new();
        for r in rows.iter().filter(|r| r.setting.factor == factor) {
            if !keys.contains(&(r.split, r.level)) {
                keys.push((r.split, r.level));
            }
        }
        let mut series = Vec::new();
        let mut bands = Vec::new();
        let mut all = Vec::new();
        for (split, level) in keys {
            let (points, ci): (Vec<(f64, f64)>, Vec<f64>) = rows
                .iter()
                .filter(|r| r.setting.factor == factor && r.split == split && r.level == level)
                .map(|r| {
                    let (m, c) = mean_ci95(&r.f1);
                    ((r.setting.value, m), c)
                })
                .filter(|((_, m), _)| m.is_finite())
                .unzip();
            all.extend(points.iter().zip(&ci).map(|(&(_, m), &c)| (m, c)));
            series.push((format!("{split}, {}", level.as_str()), points));
            bands.push(ci);
        }
        render::Panel {
            title: format!("{name}: {title}"),
            x_label: x_label.into(),
            y_label: format!("F1 of {name}, mean over runs (band: 95% CI)"),
            x_range,
            y_range: render::fitted_range(&all, 0.05),
            series,
            bands,
        }
    };
    vec![
        panel(
            "samples",
            "F1 against MC-dropout samples T",
            "T",
            (0.0, 100.0),
        ),
        panel(
            "dropout",
            "F1 against the dropout rate at inference (T = 20)",
            "dropout rate",
            (0.0, 0.9),
        ),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sweep is Fig. 8b's: T from 1 to 100, rates 0.1 to 0.8 at T = 20.
    #[test]
    fn the_sweep_covers_fig_8b() {
        let s = settings_of_sweep();
        assert_eq!(s.len(), 19);
        assert_eq!((s[0].samples, s[0].rate), (1, None));
        assert_eq!((s[10].samples, s[10].rate), (100, None));
        assert!(s[11..].iter().all(|x| x.samples == 20 && x.rate.is_some()));
        assert_eq!(s[18].rate, Some(0.8));
    }
}
