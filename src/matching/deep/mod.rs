//! The paper's Bayesian deep graph matcher (Section 3) and its deep
//! baselines and ablations. Every variant scores pairs with the shared
//! pair log-likelihood ([`crate::matching::likelihood`]) plus a gated
//! residual it learns, so that an untrained network decides exactly as
//! GPS+appearance Hungarian does (`ours-noprior`: as an appearance-only
//! Hungarian).
//!
//! One job per file. Plain Rust: `arch` (what each deep method is, as
//! [`arch::DeepMethod`]: architecture, loss terms), `features` (what
//! the network sees), `decision` (E[Y], uncertainty, decision rules),
//! `examples` (labelled training pairs), `cost` (the multiply-adds of one
//! inference, counted from the network's shapes). Tensors (burn), and only here:
//! `init` (seeded weights), `spline` (graphs as tensors, the SplineCNN
//! layer), `network` (embeddings, pair scores), `masks` (dropout),
//! `sinkhorn`, `loss`, `weights` (to and from bytes), `train` (fitting)
//! and `matcher` ([`DeepMatcher`], inference). `shared_conv`: the second
//! spline layer at inference under shared masks in plain Rust (the gemm
//! crate), without the arithmetic the masks drop. `published`: GCN-GM and
//! DGMC as published, on the paper's inputs only (no GPS pose,
//! no heading, no likelihood prior); they share only the node attributes,
//! the seeded initialisation, the mask draw and Sinkhorn with the rest. Callers get
//! [`decision::MatchDistribution`]s, correspondences, and weights as
//! bytes: reading and writing weight files is the caller's business
//! (`io`).

pub mod arch;
pub mod cost;
pub mod decision;
pub mod dense;
mod examples;
pub mod features;
mod init;
mod loss;
mod masks;
mod matcher;
mod network;
mod plain_pair;
pub mod published;
mod shared_conv;
mod sinkhorn;
mod spline;
pub mod train;
mod weights;

#[cfg(test)]
pub(crate) use self::matcher::opened_weights;
pub use self::matcher::{DeepMatcher, Inference, PairSamples};
