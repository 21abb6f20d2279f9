//! Results folders written as the work goes on or at its end: a run's
//! (`objects.parquet` streamed, then the summaries), an export's Parquet
//! tables, an evaluation's and `coid track`'s tables; each fills a claimed
//! folder ([`Claim`]) and publishes it.

use std::path::Path;

use super::{Claim, OutputError, frames, io, markdown, write_text, write_texts};
use crate::config::Settings;
use crate::matching::{DeepChoice, Method};
use crate::report::{ObjectRow, RunResults, Table};

/// A run's results folder while the run goes on: `objects.parquet` grows
/// in the claimed folder's staging folder, row group by row group;
/// [`RunFolder::finish`] adds `summary.csv` and `summary.md` and publishes
/// it. Dropped unfinished (an error, a panic), it leaves nothing behind
/// and `out` untouched.
pub struct RunFolder {
    claim: Claim,
    objects: frames::ObjectsWriter,
}

impl RunFolder {
    /// Starts `objects.parquet` in the claimed folder.
    pub fn create(claim: Claim) -> Result<Self, OutputError> {
        let objects = frames::ObjectsWriter::create(&claim.dir().join("objects.parquet"))?;
        Ok(Self { claim, objects })
    }

    /// Adds per-object rows to `objects.parquet`.
    pub fn objects(&mut self, rows: &[ObjectRow]) -> Result<(), OutputError> {
        self.objects.write(rows)
    }

    /// Completes the folder: `objects.parquet`, `summary.csv`, `summary.md`.
    pub fn finish(self, settings: &Settings, results: &RunResults) -> Result<(), OutputError> {
        self.objects.finish()?;
        let dir = self.claim.dir();
        let rows = results.summary.rows();
        frames::write_summary(&dir.join("summary.csv"), &rows)?;
        write_text(
            &dir.join("summary.md"),
            &markdown::run(settings, results, &rows),
        )?;
        self.claim.publish()
    }
}

/// A folder of Parquet tables written as the work goes on (`coid
/// export`): each file grows row group by row group in the claimed
/// folder's staging folder; [`TablesFolder::finish`] adds text files and
/// publishes it. Dropped unfinished, it leaves nothing behind.
pub struct TablesFolder {
    claim: Claim,
    files: Vec<(String, frames::TableWriter)>,
}

impl TablesFolder {
    /// One Parquet file per `(name, template)`, with the template's
    /// columns, in the claimed folder.
    pub fn create(claim: Claim, files: &[(&str, Table)]) -> Result<Self, OutputError> {
        let files = files
            .iter()
            .map(|(name, template)| {
                let path = claim.dir().join(name);
                Ok((
                    (*name).to_owned(),
                    frames::TableWriter::create(&path, template)?,
                ))
            })
            .collect::<Result<_, OutputError>>()?;
        Ok(Self { claim, files })
    }

    /// Appends `table` to the file `name` (one of those it was made with).
    pub fn write(&mut self, name: &str, table: &Table) -> Result<(), OutputError> {
        match self.files.iter_mut().find(|(n, _)| n == name) {
            Some((_, w)) => w.write(table),
            None => Err(OutputError::Batch(format!("no table file {name}"))),
        }
    }

    /// Completes every file, adds `texts` and publishes the folder.
    pub fn finish(self, texts: &[(&str, String)]) -> Result<(), OutputError> {
        self.finish_checked(texts, |_| Ok::<(), std::convert::Infallible>(()))?
            .unwrap_or_else(|never| match never {});
        Ok(())
    }

    /// Completes every file and adds `texts`, then publishes the folder
    /// only if `check` accepts it as it stands complete (read from its
    /// staging folder); refused, nothing is left behind and the refusal is
    /// returned.
    pub fn finish_checked<E>(
        self,
        texts: &[(&str, String)],
        check: impl FnOnce(&Path) -> Result<(), E>,
    ) -> Result<Result<(), E>, OutputError> {
        for (_, w) in self.files {
            w.finish()?;
        }
        write_texts(self.claim.dir(), texts)?;
        if let Err(refused) = check(self.claim.dir()) {
            return Ok(Err(refused));
        }
        self.claim.publish().map(Ok)
    }
}

/// Writes `coid track`'s tables (CSV) and whatever `plots` draws into
/// `dir`.
pub fn write_tracking(
    dir: &Path,
    tables: &[(&str, &Table)],
    plots: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    for (name, t) in tables {
        frames::write_table(&dir.join(name), t)?;
    }
    plots(dir)
}

/// Writes `coid eval`'s tables (CSV), its `summary.md` and whatever `plots`
/// draws into `dir` (made if missing).
pub fn write_eval(
    dir: &Path,
    settings: &Settings,
    tables: &[(&str, &Table)],
    choices: &std::collections::BTreeMap<Method, DeepChoice>,
    pooled: Option<&str>,
    plots: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    for (name, t) in tables {
        frames::write_table(&dir.join(name), t)?;
    }
    write_text(
        &dir.join("summary.md"),
        &markdown::eval(settings, tables, choices, pooled),
    )?;
    plots(dir)
}
