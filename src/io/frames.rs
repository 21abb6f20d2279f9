//! The only code that touches polars: result rows and tables as data
//! frames, written as CSV (6 decimals) or Parquet, and a run's
//! `summary.csv` read back for a batch aggregate.

use std::fs::File;
use std::path::Path;

use polars::prelude::*;

use super::{OutputError, io};
use crate::report::{AggregateRow, RunResults, RunRow, SummaryRow, Table, TableColumn};

fn polars_err(path: &Path) -> impl FnOnce(PolarsError) -> OutputError + '_ {
    move |source| OutputError::Polars {
        path: path.to_owned(),
        source,
    }
}

/// The summary table of a run.
fn summary_frame(rows: &[SummaryRow]) -> PolarsResult<DataFrame> {
    df!(
        "method" => rows.iter().map(|r| r.key.method.as_str()).collect::<Vec<_>>(),
        "pose_noise" => rows.iter().map(|r| r.key.pose_noise.as_str()).collect::<Vec<_>>(),
        "fusion" => rows.iter().map(|r| r.key.fusion.as_str()).collect::<Vec<_>>(),
        "n_instances" => rows.iter().map(|r| r.n_instances as u64).collect::<Vec<_>>(),
        "n_objects" => rows.iter().map(|r| r.n_objects as u64).collect::<Vec<_>>(),
        "n_matched" => rows.iter().map(|r| r.n_matched as u64).collect::<Vec<_>>(),
        "precision" => rows.iter().map(|r| r.precision).collect::<Vec<_>>(),
        "recall" => rows.iter().map(|r| r.recall).collect::<Vec<_>>(),
        "f1" => rows.iter().map(|r| r.f1).collect::<Vec<_>>(),
        "de_single_m" => rows.iter().map(|r| r.de_single_m).collect::<Vec<_>>(),
        "de_fused_m" => rows.iter().map(|r| r.de_fused_m).collect::<Vec<_>>(),
        "de_single_covis_m" => rows.iter().map(|r| r.de_single_covis_m).collect::<Vec<_>>(),
        "de_fused_covis_m" => rows.iter().map(|r| r.de_fused_covis_m).collect::<Vec<_>>(),
        "de_single_matched_m" => rows.iter().map(|r| r.de_single_matched_m).collect::<Vec<_>>(),
        "de_fused_matched_m" => rows.iter().map(|r| r.de_fused_matched_m).collect::<Vec<_>>(),
        "triple_chains" => rows.iter().map(|r| r.triple_chains as u64).collect::<Vec<_>>(),
        "inconsistent_triple_share" => rows.iter().map(|r| r.inconsistent_triple_share).collect::<Vec<_>>(),
        "object_precision" => rows.iter().map(|r| r.object_precision).collect::<Vec<_>>(),
        "object_recall" => rows.iter().map(|r| r.object_recall).collect::<Vec<_>>(),
        "object_f1" => rows.iter().map(|r| r.object_f1).collect::<Vec<_>>(),
        "n_ego_objects" => rows.iter().map(|r| r.n_ego_objects as u64).collect::<Vec<_>>(),
        "de_single_per_ego_m" => rows.iter().map(|r| r.de_single_per_ego_m).collect::<Vec<_>>(),
        "de_fused_pairwise_per_ego_m" => rows.iter().map(|r| r.de_fused_pairwise_per_ego_m).collect::<Vec<_>>(),
        "de_fused_all_views_m" => rows.iter().map(|r| r.de_fused_all_views_m).collect::<Vec<_>>(),
    )
}

/// The per-object table of a run.
fn objects_frame(results: &RunResults) -> PolarsResult<DataFrame> {
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
        "covisible" => o.iter().map(|r| r.estimate.covisible).collect::<Vec<_>>(),
        "matched" => o.iter().map(|r| r.estimate.matched).collect::<Vec<_>>(),
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

fn table_frame(t: &Table) -> PolarsResult<DataFrame> {
    let columns: Vec<Column> = t
        .columns
        .iter()
        .map(|(name, col)| match col {
            TableColumn::Text(v) => Column::new(name.as_str().into(), v),
            TableColumn::Number(v) => Column::new(name.as_str().into(), v),
            TableColumn::Count(v) => Column::new(name.as_str().into(), v),
        })
        .collect();
    DataFrame::new_infer_height(columns)
}

fn aggregate_frame(rows: &[AggregateRow]) -> PolarsResult<DataFrame> {
    let col = |f: &dyn Fn(&AggregateRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    df!(
        "method" => rows.iter().map(|r| r.method.as_str()).collect::<Vec<_>>(),
        "pose_noise" => rows.iter().map(|r| r.pose_noise.as_str()).collect::<Vec<_>>(),
        "fusion" => rows.iter().map(|r| r.fusion.as_str()).collect::<Vec<_>>(),
        "n_runs" => rows.iter().map(|r| r.n_runs as u64).collect::<Vec<_>>(),
        "n_instances" => rows.iter().map(|r| r.n_instances).collect::<Vec<_>>(),
        "precision" => col(&|r| r.precision.0),
        "precision_ci95" => col(&|r| r.precision.1),
        "n_runs_precision" => rows.iter().map(|r| r.n_runs_precision as u64).collect::<Vec<_>>(),
        "recall" => col(&|r| r.recall.0),
        "recall_ci95" => col(&|r| r.recall.1),
        "f1" => col(&|r| r.f1.0),
        "f1_ci95" => col(&|r| r.f1.1),
        "de_single_m" => col(&|r| r.de_single_m.0),
        "de_single_m_ci95" => col(&|r| r.de_single_m.1),
        "de_fused_m" => col(&|r| r.de_fused_m.0),
        "de_fused_m_ci95" => col(&|r| r.de_fused_m.1),
        "de_single_covis_m" => col(&|r| r.de_single_covis_m.0),
        "de_single_covis_m_ci95" => col(&|r| r.de_single_covis_m.1),
        "de_fused_covis_m" => col(&|r| r.de_fused_covis_m.0),
        "de_fused_covis_m_ci95" => col(&|r| r.de_fused_covis_m.1),
        "de_fused_matched_m" => col(&|r| r.de_fused_matched_m.0),
        "de_fused_matched_m_ci95" => col(&|r| r.de_fused_matched_m.1),
    )
}

/// Writes a frame as CSV with a header and 6 decimals, flushed to disk.
fn write_csv(path: &Path, df: PolarsResult<DataFrame>) -> Result<(), OutputError> {
    let mut df = df.map_err(polars_err(path))?;
    let mut f = File::create(path).map_err(io(path))?;
    CsvWriter::new(&mut f)
        .include_header(true)
        .with_float_precision(Some(6))
        .finish(&mut df)
        .map_err(polars_err(path))?;
    f.sync_all().map_err(io(path))
}

/// `summary.csv` of a run.
pub fn write_summary(path: &Path, rows: &[SummaryRow]) -> Result<(), OutputError> {
    write_csv(path, summary_frame(rows))
}

/// `objects.parquet` of a run.
pub fn write_objects(path: &Path, results: &RunResults) -> Result<(), OutputError> {
    let mut df = objects_frame(results).map_err(polars_err(path))?;
    let f = File::create(path).map_err(io(path))?;
    ParquetWriter::new(&f)
        .finish(&mut df)
        .map_err(polars_err(path))?;
    f.sync_all().map_err(io(path))
}

/// One of `coid eval`'s tables as CSV.
pub fn write_table(path: &Path, table: &Table) -> Result<(), OutputError> {
    write_csv(path, table_frame(table))
}

/// A batch's aggregate `summary.csv`.
pub fn write_aggregate(path: &Path, rows: &[AggregateRow]) -> Result<(), OutputError> {
    write_csv(path, aggregate_frame(rows))
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
    let (ni, pr, re, f1) = (
        num("n_instances")?,
        num("precision")?,
        num("recall")?,
        num("f1")?,
    );
    let (ds, dfu) = (num("de_single_m")?, num("de_fused_m")?);
    let (dsc, dfc) = (num("de_single_covis_m")?, num("de_fused_covis_m")?);
    let dfm = num("de_fused_matched_m")?;
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
            de_single_covis_m: dsc[k],
            de_fused_covis_m: dfc[k],
            de_fused_matched_m: dfm[k],
        })
        .collect())
}
