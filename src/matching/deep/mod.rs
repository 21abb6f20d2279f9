//! The deep matchers: the paper's Bayesian deep graph matcher (Section 3)
//! on DGMC's network (`coid` and its ablations), GCN-GM and DGMC as
//! published, and `ours`, the project's network that also sees the
//! reported poses. Callers get a [`Matcher`] from [`matcher`], describe
//! methods with [`arch`], read [`decision::MatchDistribution`]s, count
//! arithmetic with [`cost`] and fit weights with [`train`]; tensors never
//! leave this module, and reading and writing weight files is the
//! caller's business (`io`).
//!
//! Inside, three layers, each knowing only those below it:
//! - building blocks: `arch` (the methods' networks and their knobs),
//!   `graph` (one graph input, its spline bases), `features` (node
//!   attributes and `ours`'s pair inputs), `params` (parameters by name:
//!   weights files and seeded starts), `kernels` (products, lanes,
//!   Sinkhorn), `decision`, `cost`, and the MC-dropout shell `mc` with its
//!   [`mc::Network`] trait and seeded draws;
//! - inference: `ours` and `published`, each network in plain Rust as an
//!   `impl Network` (no tensors);
//! - training: `train`, burn's modules of both networks, their losses and
//!   the trainer, and the tensor reference the tests hold inference to (a
//!   second `impl Network` of each).

pub mod arch;
pub mod cost;
pub mod decision;
pub(crate) mod features;
pub(crate) mod graph;
mod kernels;
mod mc;
mod ours;
mod params;
mod published;
#[cfg(test)]
mod tests;
pub mod train;

pub use self::features::{check_appearance, node_attributes};
pub use self::kernels::matmul;
pub use self::mc::Inference;
pub use self::published::{GraphParts, PublishedForward};

use self::arch::Backbone;
use self::mc::McMatcher;
use self::ours::Ours;
use self::params::Params;
use self::published::Published;
use crate::matching::{Matcher, Method};

/// The matcher of deep `method` with trained weights (the bytes of its
/// `.bpk` file) whose network reads appearance vectors `appearance_width`
/// wide (0: none) and, if it is a published network, is of `shape`
/// (graph, indicator width); an error says why the bytes do not fit the method's network,
/// or that it has none.
pub fn matcher(
    method: Method,
    appearance_width: crate::sensor::AppearanceWidth,
    shape: arch::NetworkShape,
    weights: &[u8],
    run: Inference,
) -> Result<Box<dyn Matcher>, String> {
    let backbone = method
        .backbone()
        .ok_or_else(|| format!("{} is not a deep method", method.as_str()))?;
    Ok(
        match backbone.with_appearance(appearance_width).with_shape(shape) {
            Backbone::Likelihood(arch) => Box::new(McMatcher::new(
                method,
                Ours::from_weights(arch, weights, run)?,
                run,
            )),
            Backbone::Published(cfg) => Box::new(McMatcher::new(
                method,
                Published::from_weights(cfg, weights, run)?,
                run,
            )),
        },
    )
}

/// The matcher of deep `method` with freshly initialised weights
/// (`init_seed`), as training starts from: for benchmarks and tests.
///
/// # Panics
/// When `method` is not a deep method.
pub fn untrained(method: Method, init_seed: u64, run: Inference) -> Box<dyn Matcher> {
    let backbone = method.backbone().expect("a deep method");
    match backbone {
        Backbone::Likelihood(arch) => Box::new(McMatcher::new(
            method,
            Ours::untrained(arch, init_seed, run),
            run,
        )),
        Backbone::Published(cfg) => {
            let p = Params::seeded(&published::spec(&cfg), init_seed);
            Box::new(McMatcher::new(method, Published::new(cfg, &p, run), run))
        }
    }
}

/// The weights of an untrained network of `method` whose gates are open
/// (as after the first training steps): for tests of everything the
/// learned parts touch, without training.
#[cfg(test)]
pub(crate) fn opened_weights(method: Method, seed: u64) -> Vec<u8> {
    train::opened_weights(method, seed)
}
