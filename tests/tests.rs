//! Integration tests: the real `coid` binary runs the real SUMO (libsumo in
//! process, through the bridge) on the shipped scenario, for short runs.
//! Every test works in its own temporary folder; each binary invocation is
//! its own process, so the libsumo singleton never sees two simulations.
//! One test (`likelihood::`) drives the library itself, SUMO included, in
//! this test process: the only one that may.

#[path = "integration/util.rs"]
mod util;

#[path = "integration/appearance.rs"]
mod appearance;
#[path = "integration/bad_input.rs"]
mod bad_input;
#[path = "integration/batch.rs"]
mod batch;
#[path = "integration/dataset.rs"]
mod dataset;
#[path = "integration/detectors.rs"]
mod detectors;
#[path = "integration/export_score.rs"]
mod export_score;
#[path = "integration/family_roles.rs"]
mod family_roles;
#[path = "integration/hostile.rs"]
mod hostile;
#[path = "integration/hostile_datasets.rs"]
mod hostile_datasets;
#[path = "integration/learned.rs"]
mod learned;
#[path = "integration/likelihood.rs"]
mod likelihood;
#[path = "integration/pictures.rs"]
mod pictures;
#[path = "integration/protocol.rs"]
mod protocol;
#[path = "integration/pt_writer.rs"]
mod pt_writer;
#[path = "integration/regression.rs"]
mod regression;
#[path = "integration/regression49.rs"]
mod regression49;
#[path = "integration/run.rs"]
mod run;
#[path = "integration/scenarios.rs"]
mod scenarios;
#[path = "integration/suite.rs"]
mod suite;
#[path = "integration/tables.rs"]
mod tables;
#[path = "integration/v2x.rs"]
mod v2x;
