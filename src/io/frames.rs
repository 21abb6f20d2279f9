//! The only code that touches polars: result rows and tables as data
//! frames, written as CSV (6 decimals) or Parquet, and a run's
//! `summary.csv` read back for a batch aggregate.

use std::fs::File;
use std::path::{Path, PathBuf};

use polars::io::parquet::write::BatchedWriter;
use polars::prelude::*;

use super::{OutputError, io};
use crate::label;
use crate::report::{
    self, AggregateRow, ExportRunRow, MatchRow, Metric, ObjectRow, RowKey, RunRow, SummaryRow,
    Table, TableColumn,
};

fn polars_err(path: &Path) -> impl FnOnce(PolarsError) -> OutputError + '_ {
    move |source| OutputError::Polars {
        path: path.to_owned(),
        source,
    }
}

/// Per-object rows as a data frame (the columns of `objects.parquet`).
fn objects_frame(o: &[ObjectRow]) -> PolarsResult<DataFrame> {
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
            TableColumn::Flag(v) => Column::new(name.as_str().into(), v),
            TableColumn::Vectors(v) => {
                let lists: ListChunked = v
                    .iter()
                    .map(|x| Series::new(PlSmallStr::EMPTY, x.as_slice()))
                    .collect();
                lists.with_name(name.as_str().into()).into_column()
            }
        })
        .collect();
    DataFrame::new_infer_height(columns)
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
    write_table(path, &report::summary_table(rows))
}

/// A new Parquet file at `path` with the columns of `template`, written
/// row group by row group: the file (kept to flush it at the end) and the
/// writer.
fn batched_parquet(
    path: &Path,
    template: PolarsResult<DataFrame>,
) -> Result<(File, BatchedWriter<File>), OutputError> {
    let file = File::create(path).map_err(io(path))?;
    let handle = file.try_clone().map_err(io(path))?;
    let schema = template
        .map_err(polars_err(path))?
        .schema()
        .as_ref()
        .clone();
    let writer = ParquetWriter::new(handle)
        .batched(&schema)
        .map_err(polars_err(path))?;
    Ok((file, writer))
}

/// Rows per row group of `objects.parquet`: what is held in memory before
/// it is written.
pub const OBJECT_ROWS_PER_GROUP: usize = 65_536;

/// `objects.parquet` written as the rows come, one row group of
/// [`OBJECT_ROWS_PER_GROUP`] rows at a time (the last one shorter).
pub struct ObjectsWriter {
    path: PathBuf,
    file: File,
    writer: BatchedWriter<File>,
    buffer: Vec<ObjectRow>,
    rows_per_group: usize,
}

impl ObjectsWriter {
    pub fn create(path: &Path) -> Result<Self, OutputError> {
        Self::with_rows_per_group(path, OBJECT_ROWS_PER_GROUP)
    }

    /// With row groups of `rows_per_group` rows (at least 1).
    fn with_rows_per_group(path: &Path, rows_per_group: usize) -> Result<Self, OutputError> {
        let rows_per_group = rows_per_group.max(1);
        let (file, writer) = batched_parquet(path, objects_frame(&[]))?;
        Ok(Self {
            path: path.to_owned(),
            file,
            writer,
            buffer: Vec::with_capacity(rows_per_group),
            rows_per_group,
        })
    }

    /// Adds rows; every full row group goes to the file.
    pub fn write(&mut self, rows: &[ObjectRow]) -> Result<(), OutputError> {
        let mut rest = rows;
        while !rest.is_empty() {
            let room = self.rows_per_group - self.buffer.len();
            let (now, later) = rest.split_at(room.min(rest.len()));
            self.buffer.extend_from_slice(now);
            if self.buffer.len() == self.rows_per_group {
                self.flush()?;
            }
            rest = later;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), OutputError> {
        if self.buffer.is_empty() {
            return Ok(());
        }
        let df = objects_frame(&self.buffer).map_err(polars_err(&self.path))?;
        self.writer
            .write_batch(&df)
            .map_err(polars_err(&self.path))?;
        self.buffer.clear();
        Ok(())
    }

    /// Writes the last row group and the footer, flushed to disk.
    pub fn finish(mut self) -> Result<(), OutputError> {
        self.flush()?;
        self.writer.finish().map_err(polars_err(&self.path))?;
        self.file.sync_all().map_err(io(&self.path))
    }
}

/// A Parquet file of [`Table`]s with the same columns, one row group per
/// table written (a dataset's files). The first table written decides the
/// columns (a dataset's optional columns are there or not); a file nothing
/// was written to has the template's.
pub struct TableWriter {
    path: PathBuf,
    template: Table,
    open: Option<(File, BatchedWriter<File>)>,
}

impl TableWriter {
    /// A file with the columns (names and types) of `template` unless
    /// the first table written has others.
    pub fn create(path: &Path, template: &Table) -> Result<Self, OutputError> {
        File::create(path).map_err(io(path))?;
        Ok(Self {
            path: path.to_owned(),
            template: template.clone(),
            open: None,
        })
    }

    /// Writes `table` as one row group (nothing when it has no rows).
    pub fn write(&mut self, table: &Table) -> Result<(), OutputError> {
        if table.height() == 0 {
            return Ok(());
        }
        let df = table_frame(table).map_err(polars_err(&self.path))?;
        if self.open.is_none() {
            self.open = Some(batched_parquet(&self.path, Ok(df.clear()))?);
        }
        let (_, writer) = self.open.as_mut().expect("opened above");
        writer.write_batch(&df).map_err(polars_err(&self.path))
    }

    /// Writes the footer, flushed to disk.
    pub fn finish(self) -> Result<(), OutputError> {
        let (file, writer) = match self.open {
            Some(open) => open,
            None => batched_parquet(&self.path, table_frame(&self.template))?,
        };
        writer.finish().map_err(polars_err(&self.path))?;
        file.sync_all().map_err(io(&self.path))
    }
}

/// Reads an export's `runs.parquet`; the reason it cannot be, in one line.
pub fn read_export_runs(path: &Path) -> Result<Vec<ExportRunRow>, String> {
    let text = first_line;
    let f = File::open(path).map_err(|e| e.to_string())?;
    let df = ParquetReader::new(f).finish().map_err(text)?;
    let count = |name: &str| -> Result<Vec<u64>, String> {
        let c = df
            .column(name)
            .map_err(|_| format!("it has no column '{name}'"))?
            .cast(&DataType::UInt64)
            .map_err(text)?;
        Ok(c.u64()
            .map_err(text)?
            .iter()
            .map(|v| v.unwrap_or(0))
            .collect())
    };
    let strings = |name: &str| -> Result<Option<Vec<String>>, String> {
        let Ok(c) = df.column(name) else {
            return Ok(None);
        };
        let c = c.cast(&DataType::String).map_err(text)?;
        Ok(Some(
            c.str()
                .map_err(text)?
                .iter()
                .map(|v| v.unwrap_or("").to_owned())
                .collect(),
        ))
    };
    let (run, n) = (count("run")?, count("n_instances")?);
    let version = count("schema_version")?;
    let split = strings("split")?.ok_or("it has no column 'split'")?;
    let digest = strings("config_digest")?;
    Ok((0..df.height())
        .map(|k| ExportRunRow {
            run: run[k],
            split: split[k].clone(),
            n_instances: n[k],
            config_digest: digest.as_ref().map(|d| d[k].clone()),
            schema_version: version[k],
        })
        .collect())
}

/// Reads a matches file (`coid score --matches`): Parquet, or CSV when
/// its name ends in `.csv` (in any case). Columns `run`, `instance`, `a`, `b`
/// (non-negative integers, no empty values) and, optionally,
/// `pose_noise` (text), `probability` and `uncertainty` (numbers); other
/// columns are ignored. The reason it cannot be read, in one line.
pub fn read_matches(path: &Path) -> Result<Vec<MatchRow>, String> {
    let text = first_line;
    let df = if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
    {
        check_csv_header(path)?;
        CsvReadOptions::default()
            .with_has_header(true)
            .try_into_reader_with_file_path(Some(path.to_owned()))
            .and_then(|r| r.finish())
            .map_err(text)?
    } else {
        let f = File::open(path).map_err(|e| e.to_string())?;
        ParquetReader::new(f).finish().map_err(text)?
    };
    matches_of(&df)
}

/// Reads matches given as a Parquet file's bytes (a frame handed over in
/// memory, as the Python package does), checked as [`read_matches`]
/// checks a file.
pub fn read_matches_parquet(bytes: &[u8]) -> Result<Vec<MatchRow>, String> {
    let df = ParquetReader::new(std::io::Cursor::new(bytes))
        .finish()
        .map_err(first_line)?;
    matches_of(&df)
}

/// The rows of a matches frame, its columns checked.
fn matches_of(df: &DataFrame) -> Result<Vec<MatchRow>, String> {
    let n = df.height();
    if let Some(missing) = ["run", "instance", "a", "b"]
        .into_iter()
        .find(|c| df.column(c).is_err())
    {
        return Err(format!("it has no column '{missing}'"));
    }
    if n == 0 {
        return Ok(Vec::new());
    }
    // The columns as a dataset's are read: an optional column is all or
    // nothing (an empty cell is refused, not read as "1" or "the default").
    let index = |name: &str| -> Result<Vec<u64>, String> {
        let c = df
            .column(name)
            .map_err(|_| format!("it has no column '{name}'"))?;
        match dataset_column(c, name, "u64", 0)? {
            TableColumn::Count(v) => Ok(v),
            _ => Err(format!("column '{name}' holds {}, not integers", c.dtype())),
        }
    };
    let number = |name: &str| -> Result<Vec<Option<f64>>, String> {
        let Ok(c) = df.column(name) else {
            return Ok(vec![None; n]);
        };
        match dataset_column(c, name, "f64", 0)? {
            TableColumn::Number(v) => Ok(v.into_iter().map(Some).collect()),
            _ => Err(format!("column '{name}' holds {}, not numbers", c.dtype())),
        }
    };
    let level = pose_noise_column(df)?;
    let (run, instance, a, b) = (index("run")?, index("instance")?, index("a")?, index("b")?);
    let (p, u) = (number("probability")?, number("uncertainty")?);
    Ok((0..n)
        .map(|k| MatchRow {
            run: run[k],
            instance: instance[k],
            pose_noise: level[k].clone(),
            a: a[k],
            b: b[k],
            probability: p[k],
            uncertainty: u[k],
        })
        .collect())
}

/// A matches file's `pose_noise` column: `None` in every row without it;
/// with it, text in every row.
fn pose_noise_column(df: &DataFrame) -> Result<Vec<Option<String>>, String> {
    let Ok(c) = df.column("pose_noise") else {
        return Ok(vec![None; df.height()]);
    };
    let Ok(text) = c.str() else {
        return Err(format!("column 'pose_noise' holds {}, not text", c.dtype()));
    };
    let level: Vec<Option<String>> = text.iter().map(|v| v.map(str::to_owned)).collect();
    match level.iter().position(Option::is_none) {
        Some(k) => Err(format!(
            "column 'pose_noise' is empty in row {} (leave the column out for matches that \
             hold at every level)",
            k + 1
        )),
        None => Ok(level),
    }
}

/// Refuses a CSV file whose header names a column twice (a reader would
/// take one of the two silently).
fn check_csv_header(path: &Path) -> Result<(), String> {
    use std::io::BufRead;
    let f = File::open(path).map_err(|e| e.to_string())?;
    let mut header = String::new();
    std::io::BufReader::new(f)
        .read_line(&mut header)
        .map_err(|e| e.to_string())?;
    let names: Vec<&str> = header
        .trim_end_matches(['\r', '\n'])
        .split(',')
        .map(|n| n.trim().trim_matches('"'))
        .collect();
    for (k, name) in names.iter().enumerate() {
        if names[..k].contains(name) {
            return Err(format!("its header names column '{name}' twice"));
        }
    }
    Ok(())
}

/// Whether a Parquet file is whole: `PAR1` at its start and at its end
/// (a file cut short, or never finished, lacks the footer).
pub fn parquet_is_whole(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut f) = File::open(path) else {
        return false;
    };
    let mut head = [0u8; 4];
    let mut tail = [0u8; 4];
    f.read_exact(&mut head).is_ok()
        && f.seek(SeekFrom::End(-4)).is_ok()
        && f.read_exact(&mut tail).is_ok()
        && &head == b"PAR1"
        && &tail == b"PAR1"
}

/// One of `coid eval`'s tables as CSV.
pub fn write_table(path: &Path, table: &Table) -> Result<(), OutputError> {
    write_csv(path, table_frame(table))
}

/// A batch's aggregate `summary.csv`.
pub fn write_aggregate(path: &Path, rows: &[AggregateRow]) -> Result<(), OutputError> {
    write_table(path, &report::aggregate_table(rows))
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
    let [m, p, f] = report::KEY_COLUMNS.map(text);
    let (m, p, f) = (m?, p?, f?);
    let n = num("n_instances")?;
    let values = Metric::ALL.map(|metric| num(metric.column()));
    let mut columns = Vec::new();
    for v in values {
        columns.push(v?);
    }
    let bad = |what: String| OutputError::Batch(format!("{}: {what}", path.display()));
    (0..df.height())
        .map(|k| {
            let key = RowKey {
                method: label::parse(report::KEY_COLUMNS[0], &m[k]).map_err(bad)?,
                pose_noise: label::parse(report::KEY_COLUMNS[1], &p[k]).map_err(bad)?,
                fusion: label::parse(report::KEY_COLUMNS[2], &f[k]).map_err(bad)?,
            };
            Ok(RunRow {
                key,
                n_instances: n[k] as u64,
                values: std::array::from_fn(|i| columns[i][k]),
            })
        })
        .collect()
}

/// The first line of a polars error.
fn first_line(e: PolarsError) -> String {
    e.to_string().lines().next().unwrap_or("").to_owned()
}

/// The rows of a dataset's Parquet file: how many there are, and one
/// integer column of all of them (a dataset is read run by run: the `run`
/// column says where each run's rows are). The reason it cannot be, in one
/// line naming the column.
pub fn read_dataset_counts(path: &Path, name: &str) -> Result<Vec<u64>, String> {
    let t = read_dataset_table(path, &[(name, "u64")], None)?;
    match t.columns.into_iter().next() {
        Some((_, TableColumn::Count(v))) => Ok(v),
        _ => Err(format!("it has no column '{name}'")),
    }
}

/// Reads a dataset's Parquet file (all of it, or the `rows` `(first,
/// count)`) into a table of the declared `columns` (name and type: `u64`,
/// `f64`, `String`, `bool`, `Vec<f32>`, each optionally `Option<..>`), in
/// their order; only those columns are read, and an optional column the
/// file lacks is left out. The reason it cannot be, in one line naming the
/// column and, for an empty or bad value, the row of the file (1-based).
pub fn read_dataset_table(
    path: &Path,
    columns: &[(&str, &str)],
    rows: Option<(usize, usize)>,
) -> Result<Table, String> {
    let text = first_line;
    let f = File::open(path).map_err(|e| e.to_string())?;
    let mut reader = ParquetReader::new(f);
    let present = reader.schema().map_err(text)?;
    let wanted: Vec<String> = columns
        .iter()
        .map(|(name, _)| (*name).to_owned())
        .filter(|name| present.contains(name.as_str()))
        .collect();
    let df = reader
        .with_columns(Some(wanted))
        .with_slice(rows)
        .finish()
        .map_err(text)?;
    dataset_table_of(&df, columns, rows.map_or(0, |r| r.0))
}

/// A dataset file's table given as a Parquet file's bytes (a frame handed
/// over in memory), its `columns` read and checked as
/// [`read_dataset_table`] reads a file's.
pub fn read_dataset_table_parquet(bytes: &[u8], columns: &[(&str, &str)]) -> Result<Table, String> {
    let df = ParquetReader::new(std::io::Cursor::new(bytes))
        .finish()
        .map_err(first_line)?;
    dataset_table_of(&df, columns, 0)
}

/// The `columns` of a dataset file's frame `df` (its first row being row
/// `first_row` of the file) as a table.
fn dataset_table_of(
    df: &DataFrame,
    columns: &[(&str, &str)],
    first_row: usize,
) -> Result<Table, String> {
    let mut out = Table::default();
    for &(name, ty) in columns {
        let ty = ty.replace(' ', "");
        let (optional, ty) = match ty.strip_prefix("Option<") {
            Some(inner) => (true, inner.strip_suffix('>').unwrap_or(inner).to_owned()),
            None => (false, ty),
        };
        let Ok(c) = df.column(name) else {
            if optional {
                continue;
            }
            return Err(format!("it has no column '{name}'"));
        };
        let col = dataset_column(c, name, &ty, first_row)?;
        out.columns.push((name.to_owned(), col));
    }
    Ok(out)
}

/// A dataset file's column `c` (`name`, declared type `ty`, its first row
/// being row `first_row` of the file) as a table's column.
fn dataset_column(
    c: &Column,
    name: &str,
    ty: &str,
    first_row: usize,
) -> Result<TableColumn, String> {
    let text = first_line;
    let empty = |k: usize| format!("column '{name}' is empty in row {}", first_row + k + 1);
    let col = match ty {
        "u64" => {
            if !c.dtype().is_integer() {
                return Err(format!("column '{name}' holds {}, not integers", c.dtype()));
            }
            let c = c
                .strict_cast(&DataType::UInt64)
                .map_err(|_| format!("column '{name}' holds a negative value"))?;
            let v: Vec<Option<u64>> = c.u64().map_err(text)?.iter().collect();
            TableColumn::Count(all(v, empty)?)
        }
        "f64" => {
            if !c.dtype().is_primitive_numeric() {
                return Err(format!("column '{name}' holds {}, not numbers", c.dtype()));
            }
            let c = c.cast(&DataType::Float64).map_err(text)?;
            let v: Vec<Option<f64>> = c.f64().map_err(text)?.iter().collect();
            TableColumn::Number(all(v, empty)?)
        }
        "bool" => {
            let v: Vec<Option<bool>> = c
                .bool()
                .map_err(|_| format!("column '{name}' holds {}, not true/false", c.dtype()))?
                .iter()
                .collect();
            TableColumn::Flag(all(v, empty)?)
        }
        "String" => {
            let v: Vec<Option<String>> = c
                .str()
                .map_err(|_| format!("column '{name}' holds {}, not text", c.dtype()))?
                .iter()
                .map(|s| s.map(str::to_owned))
                .collect();
            TableColumn::Text(all(v, empty)?)
        }
        "Vec<f32>" => {
            let lists = c
                .list()
                .map_err(|_| format!("column '{name}' holds {}, not lists", c.dtype()))?;
            let mut v = Vec::with_capacity(lists.len());
            for (k, s) in lists.amortized_iter().enumerate() {
                let s = s.map(|s| s.as_ref().clone());
                let s = s.ok_or_else(|| empty(k))?;
                let s = s.cast(&DataType::Float32).map_err(text)?;
                let x: Option<Vec<f32>> = s.f32().map_err(text)?.iter().collect();
                v.push(x.ok_or_else(|| {
                    format!(
                        "column '{name}' has an empty value in row {}",
                        first_row + k + 1
                    )
                })?);
            }
            TableColumn::Vectors(v)
        }
        other => {
            return Err(format!(
                "column '{name}' has a type coid cannot read ({other})"
            ));
        }
    };
    Ok(col)
}

fn all<T>(v: Vec<Option<T>>, empty: impl Fn(usize) -> String) -> Result<Vec<T>, String> {
    if let Some(k) = v.iter().position(Option::is_none) {
        return Err(empty(k));
    }
    Ok(v.into_iter().flatten().collect())
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use proptest::prelude::*;

    use super::*;
    use crate::evaluate::{ObjectEstimate, PairCounts};
    use crate::fusion::FusionVariant;
    use crate::geometry::Vec2;
    use crate::matching::Method;
    use crate::report::{RowKey, Summary};
    use crate::sensor::PoseNoiseLabel;

    /// A matches table written in two row groups reads back row for row;
    /// optional columns may be missing; an index that is not an integer is
    /// refused.
    #[test]
    fn matches_written_as_tables_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.parquet");
        let table = |run: u64, p: f64| {
            let mut t = Table::default();
            t.count("run", vec![run, run]);
            t.count("instance", vec![0, 1]);
            t.text("pose_noise", vec!["gps".into(), "none".into()]);
            t.count("a", vec![2, 3]);
            t.count("b", vec![4, 5]);
            t.number("probability", vec![p, 1.0]);
            t
        };
        let mut w = TableWriter::create(&path, &table(0, 0.0)).unwrap();
        w.write(&table(7, 0.25)).unwrap();
        w.write(&Table::default()).unwrap();
        w.write(&table(8, 0.5)).unwrap();
        w.finish().unwrap();
        let rows = read_matches(&path).unwrap();
        assert_eq!(rows.len(), 4);
        assert_eq!(
            rows[2],
            MatchRow {
                run: 8,
                instance: 0,
                pose_noise: Some("gps".into()),
                a: 2,
                b: 4,
                probability: Some(0.5),
                uncertainty: None,
            }
        );
        let csv = dir.path().join("m.csv");
        std::fs::write(&csv, "run,instance,a,b\n1,2,3,4\n").unwrap();
        let rows = read_matches(&csv).unwrap();
        assert_eq!(
            (rows[0].run, rows[0].b, rows[0].pose_noise.clone()),
            (1, 4, None)
        );
        std::fs::write(&csv, "run,instance,a,b\n1,2,3.5,4\n").unwrap();
        assert!(read_matches(&csv).unwrap_err().contains("not integers"));
    }

    /// One random estimate: (key index, covisible, matched, single and
    /// fused offsets from the truth).
    type Raw = (usize, bool, bool, (f64, f64), (f64, f64));

    fn key(k: usize) -> RowKey {
        let methods = [Method::Ours, Method::Mogm, Method::Oracle];
        let levels = [PoseNoiseLabel::NONE, PoseNoiseLabel::GPS];
        let variants = [FusionVariant::Paper, FusionVariant::Aligned];
        RowKey {
            method: methods[k % 3],
            pose_noise: levels[(k / 3) % 2],
            fusion: variants[(k / 6) % 2],
        }
    }

    fn row(instance: usize, n: usize, raw: &Raw) -> ObjectRow {
        let &(k, covisible, matched, (sx, sy), (fx, fy)) = raw;
        let truth_m = Vec2::new(n as f64, -(n as f64) / 3.0);
        ObjectRow {
            instance,
            step: instance as u64,
            time_s: instance as f64 * 0.5,
            key: key(k),
            estimate: ObjectEstimate {
                ego_id: format!("v{}", n % 4),
                peer_id: format!("v{}", (n + 1) % 4),
                object_id: format!("o{n}"),
                covisible,
                matched,
                match_correct: matched && n.is_multiple_of(2),
                pose_refined: false,
                truth_m,
                single_m: truth_m + Vec2::new(sx, sy),
                fused_m: truth_m + Vec2::new(fx, fy),
                fused_nees: 2.0,
                fused_nees_hedged: 2.0,
            },
        }
    }

    /// (n, mean single error, mean fused error) of one object set.
    type SetMeans = (usize, f64, f64);

    /// Per key: (n, mean single, mean fused) over all, covisible and
    /// matched rows, recomputed from the data frame.
    fn recompute(df: &DataFrame) -> BTreeMap<(String, String, String), [SetMeans; 3]> {
        let text = |c: &str| -> Vec<String> {
            let col = df.column(c).unwrap().str().unwrap();
            col.iter().map(|v| v.unwrap().to_owned()).collect()
        };
        let num = |c: &str| -> Vec<f64> {
            let col = df.column(c).unwrap().f64().unwrap();
            col.iter().map(Option::unwrap).collect()
        };
        let flag = |c: &str| -> Vec<bool> {
            let col = df.column(c).unwrap().bool().unwrap();
            col.iter().map(Option::unwrap).collect()
        };
        let (m, l, f) = (text("method"), text("pose_noise"), text("fusion"));
        let (cov, mat) = (flag("covisible"), flag("matched"));
        let (tx, ty, sx, sy, fx, fy) = (
            num("truth_x"),
            num("truth_y"),
            num("single_x"),
            num("single_y"),
            num("fused_x"),
            num("fused_y"),
        );
        let mut sums: BTreeMap<_, [SetMeans; 3]> = BTreeMap::new();
        for i in 0..df.height() {
            let single = (sx[i] - tx[i]).hypot(sy[i] - ty[i]);
            let fused = (fx[i] - tx[i]).hypot(fy[i] - ty[i]);
            let s = sums
                .entry((m[i].clone(), l[i].clone(), f[i].clone()))
                .or_default();
            for (set, member) in [(0, true), (1, cov[i]), (2, mat[i])] {
                if member {
                    s[set].0 += 1;
                    s[set].1 += single;
                    s[set].2 += fused;
                }
            }
        }
        for s in sums.values_mut() {
            for set in s.iter_mut() {
                set.1 /= set.0 as f64;
                set.2 /= set.0 as f64;
            }
        }
        sums
    }

    fn close(a: f64, b: f64) -> bool {
        (a.is_nan() && b.is_nan()) || (a - b).abs() <= 1e-9 * (1.0 + a.abs())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(40))]
        /// The summary accumulated instance by instance equals what
        /// `objects.parquet`, streamed in row groups of any size and
        /// chunks of any size, gives when recomputed.
        #[test]
        fn streamed_rows_recompute_to_the_incremental_summary(
            instances in proptest::collection::vec(
                proptest::collection::vec(
                    (0usize..12, any::<bool>(), any::<bool>(),
                     (-5.0..5.0f64, -5.0..5.0f64), (-5.0..5.0f64, -5.0..5.0f64)),
                    0..12),
                1..20),
            group in 1usize..40,
            chunk in 1usize..30,
        ) {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("objects.parquet");
            let mut writer = ObjectsWriter::with_rows_per_group(&path, group).unwrap();
            let mut summary = Summary::default();
            let mut n = 0;
            for (i, raws) in instances.iter().enumerate() {
                let mut by_key: BTreeMap<RowKey, Vec<ObjectEstimate>> = BTreeMap::new();
                let mut rows = Vec::new();
                for raw in raws {
                    let r = row(i, n, raw);
                    n += 1;
                    by_key.entry(r.key).or_default().push(r.estimate.clone());
                    rows.push(r);
                }
                for (k, est) in &by_key {
                    summary.record(*k, PairCounts::default(), est);
                }
                for c in rows.chunks(chunk) {
                    writer.write(c).unwrap();
                }
            }
            writer.finish().unwrap();
            let df = ParquetReader::new(File::open(&path).unwrap()).finish().unwrap();
            prop_assert_eq!(df.height(), n);
            let recomputed = recompute(&df);
            let rows = summary.rows();
            prop_assert_eq!(rows.len(), recomputed.len());
            for r in &rows {
                let k = (
                    r.key.method.as_str().to_owned(),
                    r.key.pose_noise.as_str().to_owned(),
                    r.key.fusion.as_str().to_owned(),
                );
                let [all, covis, matched] = recomputed[&k];
                prop_assert_eq!(r.n_objects, all.0);
                prop_assert_eq!(r.n_matched, matched.0);
                for (mine, theirs) in [
                    (r.de_single_m, all.1), (r.de_fused_m, all.2),
                    (r.de_single_covis_m, covis.1), (r.de_fused_covis_m, covis.2),
                    (r.de_single_matched_m, matched.1), (r.de_fused_matched_m, matched.2),
                ] {
                    prop_assert!(close(mine, theirs), "{:?}: {} != {}", k, mine, theirs);
                }
            }
        }
    }
}
