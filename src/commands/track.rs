//! `track`: every connected vehicle's tracker, its CPMs over the channel,
//! and what the receivers make of them, over one run; `track_sweep`: over
//! the test (or validation) runs at each latency, loss and rate.

use std::path::PathBuf;

use anyhow::Context;

use super::{Common, ConfigSource, Event};
use crate::config::Overrides;
use crate::io::markdown::fmt_num;
use crate::label::counted;
use crate::report::{self, Table};
use crate::v2x::channel::LossModel;
use crate::v2x::{OverTimeCounts, V2xSettings, VehicleTracking};
use crate::{io, pipeline, render};

/// What to track (or sweep) and where the tables go.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackRequest {
    pub common: Common,
    /// The sweep over the validation runs ([train] validation_seeds)
    /// instead of the test runs (`track_sweep` only).
    pub validation: bool,
}

impl TrackRequest {
    /// `config` with everything else at its default.
    pub fn of(config: ConfigSource) -> Self {
        Self {
            common: Common::of(config),
            validation: false,
        }
    }
}

/// What tracking (or its sweep) wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackReport {
    pub folder: PathBuf,
    /// What was tracked or swept, in one line (the folder named last).
    pub line: String,
    /// Why nothing was tracked, when no connected vehicle came near.
    pub no_vehicle: Option<String>,
}

/// Tracks over the run of `request`'s configuration and writes
/// `tracking.csv` and `association.csv`.
///
/// # Errors
/// The configuration, the results folder or the run fails; nothing is
/// then written.
pub fn track(request: &TrackRequest, mut on: impl FnMut(Event)) -> anyhow::Result<TrackReport> {
    let common = &request.common;
    let settings = super::prepare(&common.config, &Overrides::default(), None, &mut on)?;
    let claim = common.claim("-track", None, io::ResultKind::Track)?;
    let out = claim.out().to_owned();
    let results = pipeline::track(&settings, &pipeline::Warnings::default(), |p| {
        on(Event::Simulating(p));
    })
    .context("run failed")?;
    let tracking = report::tracking_table(&results.vehicles);
    let association = report::association_table(&results.over_time);
    let tables = [
        ("tracking.csv", &tracking),
        ("association.csv", &association),
    ];
    claim.fill(|dir| io::write_tracking(dir, &tables, |_| Ok(())))?;
    let no_vehicle = results.vehicles.is_empty().then(|| {
        format!(
            "coid: warning: no connected vehicle came near junction '{}' in {} s (see \
             [connected], [scenario] radius_m and end_s)",
            settings.scenario.junction, settings.scenario.end_s
        )
    });
    let mut all = VehicleTracking::default();
    for v in &results.vehicles {
        all.add(v);
    }
    let o = &results.over_time;
    let pairs = if o.receptions == 0 {
        "no pair to score".to_owned()
    } else {
        format!(
            "pair F1 {} per message, {} over time",
            fmt_num(o.per_message.f1(), 3),
            fmt_num(o.over_time.f1(), 3)
        )
    };
    let in_flight = match all.in_flight_at_end {
        0 => String::new(),
        n => format!(", {n} still on their way at the end"),
    };
    let line = format!(
        "coid: {} tracked, MOTA {}; {}, {} of {} lost{in_flight}; {}: {pairs}; wrote {}",
        counted(results.vehicles.len() as u64, "connected vehicle"),
        fmt_num(all.mot.mota(), 3),
        counted(all.messages, "CPM"),
        all.lost,
        counted(all.delivered + all.lost + all.in_flight_at_end, "delivery"),
        counted(o.receptions, "reception"),
        out.display()
    );
    Ok(TrackReport {
        folder: out,
        line,
        no_vehicle,
    })
}

/// One setting of the sweep: the factor, its value, and the change.
struct Variant {
    factor: &'static str,
    value: f64,
    apply: Box<dyn Fn(&mut V2xSettings)>,
}

fn variants() -> Vec<Variant> {
    let mut v = Vec::new();
    for (factor, compensate) in [("latency_ms", true), ("latency_ms_uncompensated", false)] {
        for ms in [0.0, 100.0, 300.0] {
            v.push(Variant {
                factor,
                value: ms,
                apply: Box::new(move |s: &mut V2xSettings| {
                    s.channel.latency_s = ms / 1000.0;
                    s.compensate_latency = compensate;
                }),
            });
        }
    }
    for p in [0.0, 0.1, 0.3] {
        v.push(Variant {
            factor: "loss",
            value: p,
            apply: Box::new(move |s: &mut V2xSettings| {
                s.channel.loss = LossModel::Independent { probability: p };
            }),
        });
    }
    for hz in [10.0, 5.0, 1.0] {
        v.push(Variant {
            factor: "rate_hz",
            value: hz,
            apply: Box::new(move |s: &mut V2xSettings| s.cpm.rate_hz = hz),
        });
    }
    v
}

/// Tracks over the test (or validation) runs at each latency (0, 100,
/// 300 ms; compensated and not), loss (0, 10, 30 %) and rate (10, 5,
/// 1 Hz), one at a time around the configuration's `[v2x]`, and writes
/// `sweep.csv` and `sweep_latency.png/.svg`.
///
/// # Errors
/// The configuration, the results folder or a run fails; nothing is then
/// written.
pub fn track_sweep(
    request: &TrackRequest,
    mut on: impl FnMut(Event),
) -> anyhow::Result<TrackReport> {
    let common = &request.common;
    let suffix = if request.validation {
        "-sweep-validation"
    } else {
        "-sweep"
    };
    let settings = super::prepare(&common.config, &Overrides::default(), None, &mut on)?;
    let claim = common.claim(suffix, None, io::ResultKind::Track)?;
    let out = claim.out().to_owned();
    let seeds = if request.validation {
        settings.train.validation_seeds.clone()
    } else {
        settings.eval.traffic_seeds.clone()
    };
    let variants = variants();
    let total = variants.len() * seeds.len();
    let mut runs: Vec<Vec<OverTimeCounts>> = Vec::new();
    let warnings = pipeline::Warnings::default();
    for v in &variants {
        let mut v2x = settings.v2x.clone();
        (v.apply)(&mut v2x);
        let s = settings.with_v2x(v2x);
        let mut per_seed = Vec::new();
        for &seed in &seeds {
            on(Event::Runs {
                done: runs.len() * seeds.len() + per_seed.len(),
                total,
                current: &format!("{} = {} seed {seed}", v.factor, v.value),
            });
            let r = pipeline::track(&s.for_seed(seed), &warnings, |_| {})
                .with_context(|| format!("{} = {}, seed {seed} failed", v.factor, v.value))?;
            per_seed.push(r.over_time);
        }
        runs.push(per_seed);
    }
    let table = sweep_table(&variants, &runs);
    let panels = latency_panels(&table);
    claim.fill(|dir| {
        io::write_tracking(dir, &[("sweep.csv", &table)], |dir| {
            render::line_panels(&dir.join("sweep_latency"), &panels).map_err(|e| {
                io::OutputError::Picture {
                    path: dir.to_owned(),
                    message: e.message,
                }
            })
        })
    })?;
    let line = format!(
        "coid: swept {} over {}; wrote {}",
        counted(variants.len() as u64, "setting"),
        counted(
            seeds.len() as u64,
            if request.validation {
                "validation run"
            } else {
                "test run"
            }
        ),
        out.display()
    );
    Ok(TrackReport {
        folder: out,
        line,
        no_vehicle: None,
    })
}

/// `sweep.csv`: per setting, each run metric's mean and 95% interval.
fn sweep_table(variants: &[Variant], runs: &[Vec<OverTimeCounts>]) -> Table {
    let mut t = Table::default();
    t.text(
        "factor",
        variants.iter().map(|v| v.factor.to_owned()).collect(),
    );
    t.number("value", variants.iter().map(|v| v.value).collect());
    t.count("n_runs", runs.iter().map(|r| r.len() as u64).collect());
    let names = OverTimeCounts::default().metrics().map(|m| m.0);
    for (k, name) in names.iter().enumerate() {
        let samples: Vec<Vec<f64>> = runs
            .iter()
            .map(|per_seed| per_seed.iter().map(|r| r.metrics()[k].1).collect())
            .collect();
        t.stat(name, &samples);
    }
    t
}

/// F1 and the oracle-associated fused error against latency, compensated
/// and not.
fn latency_panels(t: &Table) -> Vec<render::Panel> {
    let column = |name: &str| match t.column(name) {
        Some(report::TableColumn::Number(v)) => v.clone(),
        _ => Vec::new(),
    };
    let factors = match t.column("factor") {
        Some(report::TableColumn::Text(v)) => v.clone(),
        _ => Vec::new(),
    };
    let values = column("value");
    // (points, their 95% half-widths) of one metric against latency.
    let series = |factor: &str, metric: &str| -> (Vec<(f64, f64)>, Vec<f64>) {
        let (m, ci) = (column(metric), column(&format!("{metric}_ci95")));
        (0..factors.len())
            .filter(|&k| factors[k] == factor && m[k].is_finite())
            .map(|k| ((values[k], m[k]), ci.get(k).copied().unwrap_or(f64::NAN)))
            .unzip()
    };
    let panel = |title: &str, y_label: &str, min_span: f64, lines: &[(&str, &str, &str)]| {
        let (series, bands): (Vec<_>, Vec<_>) = lines
            .iter()
            .map(|(name, factor, metric)| {
                let (points, ci) = series(factor, metric);
                (((*name).to_owned(), points), ci)
            })
            .unzip();
        let mut all: Vec<(f64, f64)> = Vec::new();
        for ((_, points), ci) in series.iter().zip(&bands) {
            all.extend(points.iter().zip(ci).map(|(&(_, y), &c)| (y, c)));
        }
        render::Panel {
            title: title.into(),
            x_label: "latency (ms)".into(),
            y_label: y_label.into(),
            x_range: (0.0, 300.0),
            // The axis spans what the lines and bands cover, so that the
            // differences they are drawn for show.
            y_range: render::fitted_range(&all, min_span),
            series,
            bands,
        }
    };
    vec![
        panel(
            "pair F1 against latency",
            "F1, mean over runs (band: 95% CI)",
            0.05,
            &[
                ("per message", "latency_ms", "f1_per_message"),
                ("over time", "latency_ms", "f1_over_time"),
                (
                    "over time, not compensated",
                    "latency_ms_uncompensated",
                    "f1_over_time",
                ),
            ],
        ),
        panel(
            "displacement error against latency (true pairs)",
            "DE (m), mean over runs (band: 95% CI)",
            0.2,
            &[
                ("single", "latency_ms", "oracle_de_single_m"),
                ("fused", "latency_ms", "oracle_de_fused_m"),
                (
                    "fused, not compensated",
                    "latency_ms_uncompensated",
                    "oracle_de_fused_m",
                ),
                ("fused by CI", "latency_ms", "oracle_de_fused_ci_m"),
            ],
        ),
    ]
}
