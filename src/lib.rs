//! coid-sim: seeded co-simulation of cooperative perception at road
//! intersections. The modules read as the pipeline, bottom to top (see
//! ARCHITECTURE.md; a module uses only modules below it):
//!
//! - foundations: [`geometry`], [`rng`], [`label`], [`paths`] (where coid
//!   keeps its files), [`interrupt`] (how the process ends on a signal),
//!   [`assignment`], [`traffic`];
//! - stages: [`bridge`] (SUMO), [`sensor`], [`graph`], [`fusion`],
//!   [`matching`];
//! - [`evaluate`]: one instance, one method: match, count, fuse;
//! - [`v2x`]: cooperation over time (trackers, messages, the channel, the
//!   receivers' association and fusion over messages);
//! - [`config`]: the TOML file into each stage's settings;
//! - [`report`]: rows, tables and plot data before they are written;
//! - [`tables`], [`render`], [`io`]: the paper's tables, pictures, files;
//! - [`dataset`]: instances as files in one schema, coid's or converted
//!   from elsewhere, and read back;
//! - [`pipeline`]: one run; [`experiments`], [`batch`]: many runs;
//!   [`export`]: instances out for matchers written elsewhere, their
//!   matches back in; [`training`]: `coid train`'s seeds and child
//!   processes;
//! - [`commands`]: the commands as typed calls, what the command line
//!   and the Python package run;
//! - [`cli`]: the `coid` commands.

mod assignment;
mod batch;
mod bridge;
pub mod cli;
pub mod commands;
pub mod config;
pub mod dataset;
pub mod evaluate;
mod experiments;
mod export;
mod fusion;
pub mod geometry;
pub mod graph;
mod interrupt;
mod io;
mod label;
pub mod matching;
mod paths;
pub mod pipeline;
mod render;
mod report;
mod rng;
mod scenarios;
pub mod sensor;
mod tables;
pub mod traffic;
mod training;
mod v2x;
