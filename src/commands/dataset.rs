//! `write_dataset`: a dataset folder from its files' tables given in
//! memory (the Python package's frames, whatever the data's source),
//! checked by coid's own reader before the folder appears.

use std::path::PathBuf;

use crate::dataset::write::{self, DatasetTables};
use crate::export;
use crate::io;

/// A dataset's files, each as a Parquet file's bytes: `runs`,
/// `instances`, `nodes`, `truth` and `true_pairs` in the dataset schema
/// (docs/export-schema.md); `edges.parquet` coid computes.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetFrames {
    pub runs: Vec<u8>,
    pub instances: Vec<u8>,
    pub nodes: Vec<u8>,
    pub truth: Vec<u8>,
    pub true_pairs: Vec<u8>,
}

/// Where the dataset goes.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteDatasetRequest {
    pub out: PathBuf,
    /// Replace a dataset folder coid wrote that did not change since.
    pub force: bool,
    pub frames: DatasetFrames,
}

/// What was written.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteDatasetReport {
    pub folder: PathBuf,
    pub runs: usize,
    pub instances: u64,
}

impl WriteDatasetReport {
    /// The dataset in one line, as the Python package prints it.
    pub fn line(&self) -> String {
        format!(
            "coid: wrote a dataset of {} ({}) to {}",
            crate::label::counted(self.runs as u64, "run"),
            crate::label::counted(self.instances, "instance"),
            self.folder.display()
        )
    }
}

/// Writes the dataset of `request`: its runs one after another, as
/// `coid export` writes them (the same files, row groups and schema.md),
/// the edges computed; published only once coid's reader has read and
/// checked every run of it.
///
/// # Errors
/// A table is refused (a missing column, a value of another type, a row
/// of no run), the reader refuses the dataset, or the folder is taken;
/// nothing is then written.
pub fn write_dataset(request: &WriteDatasetRequest) -> anyhow::Result<WriteDatasetReport> {
    let f = &request.frames;
    let [runs, instances, nodes, truth, true_pairs] = write::columns();
    let table = |(file, columns): (&str, &[(&str, &str)]), bytes: &[u8]| {
        io::frames::read_dataset_table_parquet(bytes, columns)
            .map_err(|why| anyhow::anyhow!("the {} frame is refused: {why}", frame_name(file)))
    };
    let tables = DatasetTables {
        runs: table(runs, &f.runs)?,
        instances: table(instances, &f.instances)?,
        nodes: table(nodes, &f.nodes)?,
        truth: table(truth, &f.truth)?,
        true_pairs: table(true_pairs, &f.true_pairs)?,
    };
    let assembled = write::assemble(tables).map_err(|e| anyhow::anyhow!("{e}"))?;
    let existing = io::Existing::when(request.force);
    let claim = io::Claim::new(&request.out, io::ResultKind::Export, existing)?;
    let mut folder = io::TablesFolder::create(claim, &export::files())?;
    for run in &assembled.by_run {
        for (file, rows) in run {
            folder.write(file, rows)?;
        }
    }
    folder.write(export::RUNS_FILE, &assembled.runs)?;
    let n_runs = assembled.n_runs;
    let checked = folder.finish_checked(&[("schema.md", export::SCHEMA.to_owned())], |dir| {
        let dataset = crate::dataset::Dataset::open(dir)?;
        for k in 0..dataset.runs.len() {
            dataset.run(k)?;
        }
        Ok::<(), crate::dataset::read::DatasetError>(())
    })?;
    checked.map_err(|e| anyhow::anyhow!("coid's reader refuses the dataset: {e}"))?;
    Ok(WriteDatasetReport {
        folder: request.out.clone(),
        runs: n_runs,
        instances: assembled.n_instances,
    })
}

/// A file's frame as the caller names it: `nodes.parquet` is "nodes".
fn frame_name(file: &str) -> &str {
    file.strip_suffix(".parquet").unwrap_or(file)
}
