//! coid-sim: seeded co-simulation of cooperative perception at road
//! intersections. SUMO drives the traffic (through [`bridge`]), [`sensor`]
//! derives each connected vehicle's camera detections, [`graph`] builds
//! Delaunay scene graphs, [`matching`] identifies correspondences, [`fusion`]
//! combines matched measurements and [`eval`] scores them; [`pipeline`] runs
//! the stages and [`output`] writes the results. See ARCHITECTURE.md.

pub mod batch;
pub mod bridge;
pub mod config;
pub mod eval;
pub mod experiments;
pub mod fusion;
pub mod geometry;
pub mod graph;
pub mod matching;
pub mod output;
pub mod pipeline;
pub mod render;
pub mod rng;
pub mod sensor;
pub mod traffic;
