//! What each deep method is, as plain data (no tensors, no burn): the
//! [`DeepMethod`]s (paper Table 1 rows), the [`Architecture`] of each
//! one's network, the loss terms it trains with ([`PairLoss`],
//! [`LossTerms`]), and the shared likelihood it starts from. Configs and
//! model records name these types without touching the network.

use super::features::NODE_FEATURES;
use crate::matching::Method;
use crate::matching::likelihood::LikelihoodTerms;

/// A deep method: the [`Method`]s that are a trained network, as a type of
/// their own ([`Method::kind`] gives it), so that what only a deep method
/// has (an architecture, loss terms, weights) is asked of this type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeepMethod {
    Ours,
    OursNoPrior,
    CoidNon,
    CoidUnc,
    Dgmc,
    GcnGm,
}

impl DeepMethod {
    /// The method this is.
    pub fn method(self) -> Method {
        match self {
            DeepMethod::Ours => Method::Ours,
            DeepMethod::OursNoPrior => Method::OursNoPrior,
            DeepMethod::CoidNon => Method::CoidNon,
            DeepMethod::CoidUnc => Method::CoidUnc,
            DeepMethod::Dgmc => Method::Dgmc,
            DeepMethod::GcnGm => Method::GcnGm,
        }
    }

    /// Its network: neighbourhood consensus for all but GCN-GM; the
    /// likelihood's position term for all but `ours-noprior`.
    pub fn architecture(self) -> Architecture {
        Architecture {
            consensus: self != DeepMethod::GcnGm,
            positions: self != DeepMethod::OursNoPrior,
            ..Architecture::default()
        }
    }

    /// The terms it trains with: the pair likelihood, and the paper's
    /// Eq. 12 and 13 as the rows of Table 1 have them.
    pub fn loss_terms(self) -> LossTerms {
        let (non, unc) = match self {
            DeepMethod::Ours | DeepMethod::OursNoPrior => (true, true),
            DeepMethod::CoidNon => (true, false),
            DeepMethod::CoidUnc => (false, true),
            DeepMethod::Dgmc | DeepMethod::GcnGm => (false, false),
        };
        LossTerms {
            pairs: PairLoss::Likelihood,
            non,
            unc,
        }
    }

    /// Whether its decision removes uncertain pairs: the methods trained
    /// with the paper's uncertainty-aware losses do; DGMC and GCN-GM, as
    /// published, do not (their thresholded F1 is still reported in Table
    /// 2).
    pub fn thresholds_by_default(self) -> bool {
        matches!(
            self,
            DeepMethod::Ours | DeepMethod::OursNoPrior | DeepMethod::CoidNon | DeepMethod::CoidUnc
        )
    }
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

crate::label_enum! { "dropout masks";
    /// How MC dropout draws its masks at inference.
    pub enum MaskScope {
        /// The paper's Eq. 8: in each sample, one Bernoulli mask over each
        /// layer's input units, shared by every node of every graph and
        /// every pair: sample t is one draw of the weights, W^(t).
        #[strum(serialize = "shared")]
        Shared,
        /// A mask per node and unit (and per pair entry in the consensus
        /// MLP), drawn from each graph's and each pair's own stream: how
        /// the shipped weights were trained.
        #[strum(serialize = "per-node")]
        PerNode,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::MethodKind;

    /// The deep methods and their rows of Table 1:
    /// (consensus, positions, non, unc).
    #[test]
    fn each_deep_method_has_its_table_row() {
        let rows = [
            (Method::Ours, (true, true, true, true)),
            (Method::OursNoPrior, (true, false, true, true)),
            (Method::CoidNon, (true, true, true, false)),
            (Method::CoidUnc, (true, true, false, true)),
            (Method::Dgmc, (true, true, false, false)),
            (Method::GcnGm, (false, true, false, false)),
        ];
        let deep: Vec<Method> = Method::all()
            .iter()
            .copied()
            .filter(|m| matches!(m.kind(), MethodKind::Deep(_)))
            .collect();
        assert_eq!(deep, rows.map(|(m, _)| m));
        for (m, row) in rows {
            let MethodKind::Deep(d) = m.kind() else {
                unreachable!()
            };
            assert_eq!(d.method(), m);
            let (a, t) = (d.architecture(), d.loss_terms());
            assert_eq!((a.consensus, a.positions, t.non, t.unc), row, "{m:?}");
            assert_eq!(t.pairs, PairLoss::Likelihood);
            let thresholds = !matches!(m, Method::Dgmc | Method::GcnGm);
            assert_eq!(d.thresholds_by_default(), thresholds);
        }
        assert!(!matches!(
            Method::GpsAppHungarian.kind(),
            MethodKind::Deep(_)
        ));
    }
}
