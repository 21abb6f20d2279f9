//! Rows read from files other tools wrote: a matches file's rows and an
//! export's runs.

/// One correspondence of a matches file (`coid score --matches`): node
/// `a` of the instance's first vehicle is node `b` of its second, at one
/// pose-noise level (every level when `pose_noise` is `None`), with the
/// matcher's probability and uncertainty (bits) when it gave them.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchRow {
    pub run: u64,
    pub instance: u64,
    pub pose_noise: Option<String>,
    pub a: u64,
    pub b: u64,
    pub probability: Option<f64>,
    pub uncertainty: Option<f64>,
}

/// One row of an export's `runs.parquet`, as `coid score` checks it.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportRunRow {
    pub run: u64,
    pub split: String,
    pub n_instances: u64,
    /// `None` in exports of schema version 1.
    pub config_digest: Option<String>,
    /// The export's schema version.
    pub schema_version: u64,
}
