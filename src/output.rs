//! The only module that touches polars and writes results: `summary.csv`,
//! `objects.parquet` and `summary.md` into `results/<run>/`.
//!
//! A run folder appears complete or not at all: everything is written into a
//! hidden temporary folder beside it, flushed, then renamed into place. An
//! existing folder is never overwritten unless asked, and then it is swapped
//! out only after the new one is complete.

use std::fmt::Write as _;
use std::fs::File;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use polars::prelude::*;

use crate::config::Settings;
use crate::eval::SummaryRow;
use crate::pipeline::RunResults;

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error(
        "output folder {0} already exists (choose another --out, or pass --force to replace it)"
    )]
    Exists(PathBuf),
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Polars { path: PathBuf, source: PolarsError },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Builds the summary table.
pub fn summary_frame(rows: &[SummaryRow]) -> PolarsResult<DataFrame> {
    df!(
        "method" => rows.iter().map(|r| r.key.method.as_str()).collect::<Vec<_>>(),
        "pose_noise" => rows.iter().map(|r| r.key.pose_noise.as_str()).collect::<Vec<_>>(),
        "fusion" => rows.iter().map(|r| r.key.fusion.as_str()).collect::<Vec<_>>(),
        "n_instances" => rows.iter().map(|r| r.n_instances as u64).collect::<Vec<_>>(),
        "n_objects" => rows.iter().map(|r| r.n_objects as u64).collect::<Vec<_>>(),
        "precision" => rows.iter().map(|r| r.precision).collect::<Vec<_>>(),
        "recall" => rows.iter().map(|r| r.recall).collect::<Vec<_>>(),
        "f1" => rows.iter().map(|r| r.f1).collect::<Vec<_>>(),
        "de_single_m" => rows.iter().map(|r| r.de_single_m).collect::<Vec<_>>(),
        "de_fused_m" => rows.iter().map(|r| r.de_fused_m).collect::<Vec<_>>(),
    )
}

/// Builds the per-object table.
pub fn objects_frame(results: &RunResults) -> PolarsResult<DataFrame> {
    let o = &results.objects;
    df!(
        "instance" => o.iter().map(|r| r.instance as u64).collect::<Vec<_>>(),
        "step" => o.iter().map(|r| r.step).collect::<Vec<_>>(),
        "time_s" => o.iter().map(|r| r.time_s).collect::<Vec<_>>(),
        "method" => o.iter().map(|r| r.key.method.as_str()).collect::<Vec<_>>(),
        "pose_noise" => o.iter().map(|r| r.key.pose_noise.as_str()).collect::<Vec<_>>(),
        "fusion" => o.iter().map(|r| r.key.fusion.as_str()).collect::<Vec<_>>(),
        "ego_id" => o.iter().map(|r| r.estimate.ego_id.as_str()).collect::<Vec<_>>(),
        "peer_id" => o.iter().map(|r| r.estimate.peer_id.as_str()).collect::<Vec<_>>(),
        "object_id" => o.iter().map(|r| r.estimate.object_id.as_str()).collect::<Vec<_>>(),
        "match_correct" => o.iter().map(|r| r.estimate.match_correct).collect::<Vec<_>>(),
        "pose_refined" => o.iter().map(|r| r.estimate.pose_refined).collect::<Vec<_>>(),
        "truth_x" => o.iter().map(|r| r.estimate.truth_m.x).collect::<Vec<_>>(),
        "truth_y" => o.iter().map(|r| r.estimate.truth_m.y).collect::<Vec<_>>(),
        "single_x" => o.iter().map(|r| r.estimate.single_m.x).collect::<Vec<_>>(),
        "single_y" => o.iter().map(|r| r.estimate.single_m.y).collect::<Vec<_>>(),
        "fused_x" => o.iter().map(|r| r.estimate.fused_m.x).collect::<Vec<_>>(),
        "fused_y" => o.iter().map(|r| r.estimate.fused_m.y).collect::<Vec<_>>(),
    )
}

fn fmt_num(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "n/a".into()
    }
}

/// The human-readable report.
pub fn summary_markdown(settings: &Settings, results: &RunResults, rows: &[SummaryRow]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# coid-sim run\n");
    let _ = writeln!(s, "- config: `{}`", settings.source.display());
    let _ = writeln!(
        s,
        "- scenario: `{}`, junction `{}`",
        settings.scenario.sumocfg.display(),
        settings.scenario.junction
    );
    let _ = writeln!(
        s,
        "- seeds: traffic {}, sensor {}; simulated {:.1} s in {} steps; {} instances",
        settings.seeds.traffic,
        settings.seeds.sensor,
        results.sim_end_s,
        results.n_steps,
        results.n_instances
    );
    let _ = writeln!(
        s,
        "- precision/recall pool all pairs of all instances; displacement errors are means over matched objects (metres, ground plane, ego frame)\n"
    );
    let _ = writeln!(
        s,
        "| method | pose noise | fusion | instances | objects | precision | recall | F1 | DE single (m) | DE fused (m) |"
    );
    let _ = writeln!(s, "|---|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.key.method.as_str(),
            r.key.pose_noise.as_str(),
            r.key.fusion.as_str(),
            r.n_instances,
            r.n_objects,
            fmt_num(r.precision, 4),
            fmt_num(r.recall, 4),
            fmt_num(r.f1, 4),
            fmt_num(r.de_single_m, 4),
            fmt_num(r.de_fused_m, 4),
        );
    }
    s
}

/// Writes a run's results into `out` (see the module docs for atomicity).
pub fn write_run(
    out: &Path,
    settings: &Settings,
    results: &RunResults,
    force: bool,
) -> Result<(), OutputError> {
    atomic_dir(out, force, |dir| write_files(dir, settings, results))
}

fn write_files(dir: &Path, settings: &Settings, results: &RunResults) -> Result<(), OutputError> {
    let rows = results.summary.rows();
    let polars_err = |path: &Path| {
        let path = path.to_owned();
        move |source| OutputError::Polars { path, source }
    };

    let path = dir.join("summary.csv");
    let mut df = summary_frame(&rows).map_err(polars_err(&path))?;
    let mut f = File::create(&path).map_err(io(&path))?;
    CsvWriter::new(&mut f)
        .include_header(true)
        .with_float_precision(Some(6))
        .finish(&mut df)
        .map_err(polars_err(&path))?;
    f.sync_all().map_err(io(&path))?;

    let path = dir.join("objects.parquet");
    let mut df = objects_frame(results).map_err(polars_err(&path))?;
    let f = File::create(&path).map_err(io(&path))?;
    ParquetWriter::new(&f)
        .finish(&mut df)
        .map_err(polars_err(&path))?;
    f.sync_all().map_err(io(&path))?;

    let path = dir.join("summary.md");
    let mut f = File::create(&path).map_err(io(&path))?;
    f.write_all(summary_markdown(settings, results, &rows).as_bytes())
        .map_err(io(&path))?;
    f.sync_all().map_err(io(&path))?;
    Ok(())
}

/// What `coid train` records beside each model's weights.
pub struct TrainingRecord<'a> {
    pub method: &'a str,
    pub settings: &'a Settings,
    pub n_examples: usize,
    pub report: &'a crate::matching::deep::train::TrainReport,
    pub seconds: f64,
}

/// Writes a trained model into `dir`: `<method>.bpk` (weights, written by
/// `save_weights` to a temporary path first), `<method>.toml` (config,
/// seeds, data size, final loss) and `<method>_loss.csv` (mean loss per
/// epoch). Each file is renamed into place only when complete.
pub fn write_model(
    dir: &Path,
    record: &TrainingRecord,
    save_weights: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), OutputError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let tmp = |name: &str| dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let publish = |name: &str, tmp_path: &Path| {
        let dst = dir.join(name);
        std::fs::rename(tmp_path, &dst).map_err(io(&dst))
    };

    let weights = format!("{}.bpk", record.method);
    let tmp_weights = tmp(&weights);
    save_weights(&tmp_weights).map_err(|e| OutputError::Io {
        path: dir.join(&weights),
        source: std::io::Error::other(e),
    })?;
    publish(&weights, &tmp_weights)?;

    let t = &record.settings.train;
    let mut meta = String::new();
    let _ = writeln!(
        meta,
        "# Trained by `coid train`; the config and seeds it was trained with."
    );
    let _ = writeln!(meta, "method = {:?}", record.method);
    let _ = writeln!(
        meta,
        "config = {:?}",
        record.settings.source.display().to_string()
    );
    let _ = writeln!(meta, "train_traffic_seeds = {:?}", t.traffic_seeds);
    let _ = writeln!(
        meta,
        "eval_traffic_seeds = {:?}",
        record.settings.eval.traffic_seeds
    );
    let _ = writeln!(meta, "epochs = {}", t.epochs);
    let _ = writeln!(meta, "learning_rate = {}", t.learning_rate);
    let _ = writeln!(meta, "seed = {}", t.seed);
    let _ = writeln!(meta, "examples = {}", record.n_examples);
    let _ = writeln!(meta, "steps = {}", record.report.steps);
    let _ = writeln!(meta, "seconds = {:.1}", record.seconds);
    let _ = writeln!(
        meta,
        "final_epoch_loss = {}",
        record
            .report
            .epoch_losses
            .last()
            .copied()
            .unwrap_or(f64::NAN)
    );
    let name = format!("{}.toml", record.method);
    let p = tmp(&name);
    std::fs::write(&p, meta).map_err(io(&p))?;
    publish(&name, &p)?;

    let mut curve = String::from("epoch,mean_loss\n");
    for (k, l) in record.report.epoch_losses.iter().enumerate() {
        let _ = writeln!(curve, "{},{l:.6}", k + 1);
    }
    let name = format!("{}_loss.csv", record.method);
    let p = tmp(&name);
    std::fs::write(&p, curve).map_err(io(&p))?;
    publish(&name, &p)
}

fn table_frame(t: &crate::experiments::Table) -> PolarsResult<DataFrame> {
    use crate::experiments::TableColumn;
    let columns: Vec<Column> = t
        .columns
        .iter()
        .map(|(name, col)| match col {
            TableColumn::Text(v) => Column::new(name.as_str().into(), v),
            TableColumn::Number(v) => Column::new(name.as_str().into(), v),
        })
        .collect();
    DataFrame::new_infer_height(columns)
}

fn write_csv(path: &Path, df: &mut DataFrame) -> Result<(), OutputError> {
    let mut f = File::create(path).map_err(io(path))?;
    CsvWriter::new(&mut f)
        .include_header(true)
        .with_float_precision(Some(6))
        .finish(df)
        .map_err(|source| OutputError::Polars {
            path: path.to_owned(),
            source,
        })?;
    f.sync_all().map_err(io(path))
}

/// Writes `coid eval`'s tables (CSV) and a `summary.md` into `out`, atomically
/// as for a run.
pub fn write_eval(
    out: &Path,
    settings: &Settings,
    tables: &crate::experiments::EvalTables,
    force: bool,
    plots: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), OutputError> {
    let mut files: Vec<(&str, &crate::experiments::Table)> = vec![
        ("table1.csv", &tables.table1),
        ("table2.csv", &tables.table2),
        ("table3.csv", &tables.table3),
        ("lambda_sweep.csv", &tables.lambda_sweep),
        ("case_study.csv", &tables.case_study),
    ];
    files.retain(|(_, t)| !t.columns.is_empty());
    atomic_dir(out, force, |dir| {
        let mut md = String::new();
        let _ = writeln!(md, "# coid-sim evaluation\n");
        let _ = writeln!(md, "- config: `{}`", settings.source.display());
        let _ = writeln!(
            md,
            "- test runs (traffic = sensor seed): {:?}; training runs: {:?}",
            settings.eval.traffic_seeds, settings.train.traffic_seeds
        );
        let _ = writeln!(
            md,
            "- every number is the mean over test runs, `±` the half-width of its 95% confidence interval (Student t)\n"
        );
        for (name, t) in &files {
            let path = dir.join(name);
            let mut df = table_frame(t).map_err(|source| OutputError::Polars {
                path: path.clone(),
                source,
            })?;
            write_csv(&path, &mut df)?;
            let _ = writeln!(md, "## {name}\n\n{}\n", markdown_table(t));
        }
        let path = dir.join("summary.md");
        std::fs::write(&path, md).map_err(io(&path))?;
        plots(dir).map_err(|e| OutputError::Io {
            path: dir.to_owned(),
            source: std::io::Error::other(e),
        })
    })
}

/// A table in Markdown, `x ± ci` for each `x` with an `x_ci95` column.
fn markdown_table(t: &crate::experiments::Table) -> String {
    use crate::experiments::TableColumn;
    let names: Vec<&String> = t.columns.iter().map(|(n, _)| n).collect();
    let shown: Vec<usize> = (0..names.len())
        .filter(|&k| !names[k].ends_with("_ci95"))
        .collect();
    let rows = match t.columns.first() {
        Some((_, TableColumn::Text(v))) => v.len(),
        Some((_, TableColumn::Number(v))) => v.len(),
        None => 0,
    };
    let cell = |k: usize, r: usize| -> String {
        match &t.columns[k].1 {
            TableColumn::Text(v) => v[r].clone(),
            TableColumn::Number(v) => {
                let ci = t
                    .columns
                    .iter()
                    .find(|(n, _)| *n == format!("{}_ci95", names[k]))
                    .and_then(|(_, c)| match c {
                        TableColumn::Number(c) => Some(c[r]),
                        TableColumn::Text(_) => None,
                    });
                match ci {
                    Some(c) if c.is_finite() => format!("{} ± {}", fmt_num(v[r], 4), fmt_num(c, 4)),
                    _ => fmt_num(v[r], 4),
                }
            }
        }
    };
    let mut s = format!(
        "| {} |\n|{}\n",
        shown
            .iter()
            .map(|&k| names[k].as_str())
            .collect::<Vec<_>>()
            .join(" | "),
        "---|".repeat(shown.len())
    );
    for r in 0..rows {
        let _ = writeln!(
            s,
            "| {} |",
            shown
                .iter()
                .map(|&k| cell(k, r))
                .collect::<Vec<_>>()
                .join(" | ")
        );
    }
    s
}

/// Creates `out` atomically: `fill` writes into a temporary sibling folder,
/// which then replaces `out` (refused when `out` exists and not `force`).
fn atomic_dir(
    out: &Path,
    force: bool,
    fill: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    if out.exists() && !force {
        return Err(OutputError::Exists(out.to_owned()));
    }
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(io(&parent))?;
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let tmp = parent.join(format!(".{name}.tmp-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    let result = fill(&tmp).and_then(|()| {
        if out.exists() {
            let old = parent.join(format!(".{name}.old-{}", std::process::id()));
            std::fs::rename(out, &old).map_err(io(out))?;
            std::fs::rename(&tmp, out).map_err(io(out))?;
            std::fs::remove_dir_all(&old).map_err(io(&old))
        } else {
            std::fs::rename(&tmp, out).map_err(io(out))
        }
    });
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result
}

/// One row of a run's `summary.csv`, as read back for a batch aggregate.
#[derive(Clone, Debug, PartialEq)]
pub struct RunRow {
    pub method: String,
    pub pose_noise: String,
    pub fusion: String,
    pub n_instances: u64,
    pub precision: f64,
    pub recall: f64,
    pub f1: f64,
    pub de_single_m: f64,
    pub de_fused_m: f64,
}

/// Reads a run's `summary.csv`.
pub fn read_run_summary(path: &Path) -> Result<Vec<RunRow>, OutputError> {
    let perr = |source| OutputError::Polars {
        path: path.to_owned(),
        source,
    };
    let df = CsvReadOptions::default()
        .with_has_header(true)
        .try_into_reader_with_file_path(Some(path.to_owned()))
        .and_then(|r| r.finish())
        .map_err(perr)?;
    let text = |c: &str| -> Result<Vec<String>, OutputError> {
        Ok(df
            .column(c)
            .and_then(|c| c.cast(&DataType::String))
            .map_err(perr)?
            .str()
            .map_err(perr)?
            .iter()
            .map(|v| v.unwrap_or("").to_owned())
            .collect())
    };
    let num = |c: &str| -> Result<Vec<f64>, OutputError> {
        Ok(df
            .column(c)
            .and_then(|c| c.cast(&DataType::Float64))
            .map_err(perr)?
            .f64()
            .map_err(perr)?
            .iter()
            .map(|v| v.unwrap_or(f64::NAN))
            .collect())
    };
    let (m, p, f) = (text("method")?, text("pose_noise")?, text("fusion")?);
    let (ni, pr, re, f1, ds, dfu) = (
        num("n_instances")?,
        num("precision")?,
        num("recall")?,
        num("f1")?,
        num("de_single_m")?,
        num("de_fused_m")?,
    );
    Ok((0..df.height())
        .map(|k| RunRow {
            method: m[k].clone(),
            pose_noise: p[k].clone(),
            fusion: f[k].clone(),
            n_instances: ni[k] as u64,
            precision: pr[k],
            recall: re[k],
            f1: f1[k],
            de_single_m: ds[k],
            de_fused_m: dfu[k],
        })
        .collect())
}

/// Writes a batch's aggregate `summary.csv` (and `summary.md`) into `dir`,
/// each through a temporary file and a rename.
pub fn write_batch_summary(
    dir: &Path,
    rows: &[crate::batch::AggregateRow],
    header: &str,
) -> Result<(), OutputError> {
    let col =
        |f: &dyn Fn(&crate::batch::AggregateRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    let mut df = df!(
        "method" => rows.iter().map(|r| r.method.as_str()).collect::<Vec<_>>(),
        "pose_noise" => rows.iter().map(|r| r.pose_noise.as_str()).collect::<Vec<_>>(),
        "fusion" => rows.iter().map(|r| r.fusion.as_str()).collect::<Vec<_>>(),
        "n_runs" => rows.iter().map(|r| r.n_runs as u64).collect::<Vec<_>>(),
        "n_instances" => rows.iter().map(|r| r.n_instances).collect::<Vec<_>>(),
        "precision" => col(&|r| r.precision.0),
        "precision_ci95" => col(&|r| r.precision.1),
        "recall" => col(&|r| r.recall.0),
        "recall_ci95" => col(&|r| r.recall.1),
        "f1" => col(&|r| r.f1.0),
        "f1_ci95" => col(&|r| r.f1.1),
        "de_single_m" => col(&|r| r.de_single_m.0),
        "de_single_m_ci95" => col(&|r| r.de_single_m.1),
        "de_fused_m" => col(&|r| r.de_fused_m.0),
        "de_fused_m_ci95" => col(&|r| r.de_fused_m.1),
    )
    .map_err(|source| OutputError::Polars {
        path: dir.join("summary.csv"),
        source,
    })?;
    let tmp = dir.join(format!(".summary.csv.tmp-{}", std::process::id()));
    write_csv(&tmp, &mut df)?;
    let dst = dir.join("summary.csv");
    std::fs::rename(&tmp, &dst).map_err(io(&dst))?;

    let mut md = format!("# coid-sim batch\n\n{header}\n\n");
    let _ = writeln!(
        md,
        "| method | pose noise | fusion | runs | instances | precision | recall | F1 | DE single (m) | DE fused (m) |"
    );
    let _ = writeln!(md, "|---|---|---|---:|---:|---:|---:|---:|---:|---:|");
    let pm = |(m, c): (f64, f64)| {
        if c.is_finite() {
            format!("{} ± {}", fmt_num(m, 4), fmt_num(c, 4))
        } else {
            fmt_num(m, 4)
        }
    };
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.method,
            r.pose_noise,
            r.fusion,
            r.n_runs,
            r.n_instances,
            pm(r.precision),
            pm(r.recall),
            pm(r.f1),
            pm(r.de_single_m),
            pm(r.de_fused_m)
        );
    }
    let tmp = dir.join(format!(".summary.md.tmp-{}", std::process::id()));
    std::fs::write(&tmp, md).map_err(io(&tmp))?;
    let dst = dir.join("summary.md");
    std::fs::rename(&tmp, &dst).map_err(io(&dst))
}

/// Copies a completed run folder (flat: files only) into `dst` atomically.
pub fn copy_run(src: &Path, dst: &Path) -> Result<(), OutputError> {
    atomic_dir(dst, true, |tmp| {
        for e in std::fs::read_dir(src).map_err(io(src))? {
            let p = e.map_err(io(src))?.path();
            if p.is_file() {
                let to = tmp.join(p.file_name().unwrap_or_default());
                std::fs::copy(&p, &to).map_err(io(&to))?;
            }
        }
        Ok(())
    })
}
