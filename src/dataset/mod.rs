//! Datasets: correspondence instances as a folder of Parquet files in one
//! versioned schema (`docs/export-schema.md`, [`SCHEMA_VERSION`]), whoever
//! made them: `coid export` from coid's own runs, `coid convert pyg` from
//! PyTorch Geometric pairs recorded elsewhere ([`convert`]). [`read`]
//! checks a folder and reads it back as plain values, refusing one that
//! does not fit with one line naming the file, row and column.

mod assemble;
mod check;
pub(crate) mod convert;
pub mod read;
pub(crate) mod schema;
pub mod write;

pub use read::Dataset;

/// The version of the dataset schema (`runs.parquet` carries it): 2 added
/// `config_digest`; 3 the nodes' `heading_rad` and `speed_mps`; 4 each
/// vehicle's claimed heading accuracy; 5 optional columns, the vehicles'
/// true poses, nodes' world positions and appearance vectors.
pub const SCHEMA_VERSION: u64 = 5;

/// The schema, written beside the files as `schema.md`.
pub const SCHEMA: &str = include_str!("../../docs/export-schema.md");
