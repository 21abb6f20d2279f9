//! What each deep method is, as plain data (no tensors, no burn): the
//! [`Architecture`] of each one's network ([`variant`]: paper Table 1
//! rows), the loss terms it trains with ([`PairLoss`], [`LossTerms`]),
//! and the shared likelihood it starts from. Configs and model records
//! name these types without touching the network.

use super::features::NODE_FEATURES;
use crate::matching::Method;
use crate::matching::likelihood::LikelihoodTerms;

/// Architecture and loss terms of each deep method (paper Table 1 rows).
pub fn variant(method: Method) -> Option<(Architecture, LossTerms)> {
    let arch = Architecture::default();
    let (consensus, non, unc) = match method {
        Method::Ours | Method::OursNoPrior => (true, true, true),
        Method::CoidNon => (true, true, false),
        Method::CoidUnc => (true, false, true),
        Method::Dgmc => (true, false, false),
        Method::GcnGm => (false, false, false),
        _ => return None,
    };
    let positions = method != Method::OursNoPrior;
    Some((
        Architecture {
            consensus,
            positions,
            ..arch
        },
        LossTerms {
            pairs: PairLoss::Likelihood,
            non,
            unc,
        },
    ))
}

/// Whether a method's decision removes uncertain pairs: the methods trained
/// with the paper's uncertainty-aware losses do; DGMC and GCN-GM, as
/// published, do not (their thresholded F1 is still reported in Table 2).
pub fn thresholds_by_default(method: Method) -> bool {
    matches!(
        method,
        Method::Ours | Method::OursNoPrior | Method::CoidNon | Method::CoidUnc
    )
}

/// Architecture and regularisation of one matcher variant.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Architecture {
    pub node_features: usize,
    pub hidden: usize,
    pub out: usize,
    pub dropout_conv: f64,
    /// DGMC neighbourhood consensus on (`dgmc`, `ours`, ablations) or off
    /// (`gcn-gm`).
    pub consensus: bool,
    pub consensus_dim: usize,
    pub dropout_phi: f64,
    pub sinkhorn_iters: usize,
    /// Whether the shared likelihood has its position term (and the
    /// network sees where each node lies from the other vehicle): every
    /// deep method but `ours-noprior`, the paper's network as published,
    /// which must match on appearance and structure.
    pub positions: bool,
    /// Hidden units of the pair MLP and of the "no match" MLP.
    pub pair_hidden: usize,
}

impl Default for Architecture {
    fn default() -> Self {
        Self {
            node_features: NODE_FEATURES,
            hidden: 256,
            out: 32,
            dropout_conv: 0.4,
            consensus: true,
            consensus_dim: 32,
            dropout_phi: 0.2,
            sinkhorn_iters: 20,
            positions: true,
            pair_hidden: 32,
        }
    }
}

/// The terms and gates of the shared likelihood that a variant starts
/// from: position and appearance, or appearance alone (`ours-noprior`).
pub fn likelihood_terms(arch: &Architecture, gate_chi2: f64) -> LikelihoodTerms {
    LikelihoodTerms {
        position: arch.positions,
        ..LikelihoodTerms::full(gate_chi2)
    }
}

crate::label_enum! { "pair loss";
    /// The term of the loss that teaches which pairs are the same object.
    #[strum(serialize_all = "lowercase")]
    pub enum PairLoss {
        /// The log-likelihood of the true assignment with dustbins
        /// (SuperGlue): `-log P_ij` of every true pair and `-log P` of the
        /// dustbin of every node without a partner, the two halves weighed
        /// equally (each a mean of its own).
        Likelihood,
        /// The paper's Eq. 11: `-log(sum(P o Y*) / n_true)`.
        Paper,
    }
}

/// Which terms a variant trains with: a pair term, and the paper's
/// Eq. 12 (`non`) and Eq. 13 (`unc`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LossTerms {
    pub pairs: PairLoss,
    pub non: bool,
    pub unc: bool,
}
