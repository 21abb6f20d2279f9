//! What each deep method is, as plain data (no tensors, no burn): each
//! deep [`Method`]'s network ([`Method::backbone`]: paper Table 1 rows),
//! the [`Architecture`] of the project's network, the loss terms it trains with ([`PairLoss`],
//! [`LossTerms`]), and the shared likelihood it starts from. Configs and
//! model records name these types without touching the network.

use super::features::NODE_FEATURES;
use crate::matching::Method;
use crate::matching::likelihood::LikelihoodTerms;
use crate::sensor::AppearanceWidth;

/// The network a deep method trains and runs (as a record holds it: a
/// published network names its `kind`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(untagged)]
pub enum Backbone {
    /// GCN-GM's or DGMC's network as Fey et al. publish it, on the paper's
    /// inputs (`matching::deep::published`).
    Published(PublishedConfig),
    /// The project's network: a learned correction of the shared pair
    /// likelihood, which sees the reported poses.
    Likelihood(Architecture),
}

impl<'de> serde::Deserialize<'de> for Backbone {
    /// A published network's configuration when it names its `kind`, else
    /// the project network's; a field that does not fit is named.
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let v = serde_json::Value::deserialize(d)?;
        if v.get("kind").is_some() {
            serde_json::from_value(v)
                .map(Backbone::Published)
                .map_err(D::Error::custom)
        } else {
            serde_json::from_value(v)
                .map(Backbone::Likelihood)
                .map_err(D::Error::custom)
        }
    }
}

impl Backbone {
    /// The width of the appearance vectors its nodes read beside class,
    /// colour and size.
    pub fn appearance_width(&self) -> AppearanceWidth {
        match self {
            Backbone::Published(c) => c.appearance_width,
            Backbone::Likelihood(a) => a.appearance_width(),
        }
    }

    /// What `[train]` chose of a published network (the project's
    /// network: the defaults, which it does not read).
    pub fn shape(&self) -> NetworkShape {
        match self {
            Backbone::Published(c) => NetworkShape {
                graph: c.graph,
                consensus_dim: c.consensus_dim,
                edge_scale_m: c.edge_scale_m,
            },
            Backbone::Likelihood(_) => NetworkShape::default(),
        }
    }

    /// The same network of `shape` (a published network; the project's
    /// network keeps its own).
    pub fn with_shape(self, shape: NetworkShape) -> Self {
        match self {
            Backbone::Published(c) => Backbone::Published(PublishedConfig {
                graph: shape.graph,
                consensus_dim: shape.consensus_dim,
                edge_scale_m: shape.edge_scale_m,
                ..c
            }),
            Backbone::Likelihood(a) => Backbone::Likelihood(a),
        }
    }

    /// The same network reading appearance vectors `width` wide: its
    /// first layer as wide as class, colour, size and the vector.
    pub fn with_appearance(self, width: AppearanceWidth) -> Self {
        match self {
            Backbone::Published(c) => Backbone::Published(PublishedConfig {
                appearance_width: width,
                ..c
            }),
            Backbone::Likelihood(a) => Backbone::Likelihood(a.with_appearance(width)),
        }
    }
}

/// What a deep method is: its network and how it trains (the [`Method`]s
/// whose kind is [`crate::matching::MethodKind::Deep`]; a single-pass
/// variant is its weights owner's network). The first five deep methods
/// see the paper's inputs only (Table 1: [`Backbone::Published`]); the
/// others the reported poses too (Table 1b: [`Backbone::Likelihood`]).
impl Method {
    /// Its network (`None`: not a trained network). On the paper's
    /// inputs: GCN-GM's for `gcn-gm`, DGMC's for `dgmc` and for the
    /// paper's method and its ablations (the paper builds on DGMC:
    /// SplineCNN, consensus, Sinkhorn; the "no match" dustbin is coid's
    /// addition, after SuperGlue). With the poses:
    /// the project's network, with the consensus for all but
    /// `gcn-gm+gps`.
    pub fn backbone(self) -> Option<Backbone> {
        let m = self.weights_owner();
        Some(match m {
            Method::GcnGm => Backbone::Published(PublishedConfig::new(PublishedKind::GcnGm)),
            Method::Coid | Method::CoidNon | Method::CoidUnc | Method::Dgmc => {
                Backbone::Published(PublishedConfig::new(PublishedKind::Dgmc))
            }
            Method::Ours
            | Method::CoidNonGps
            | Method::CoidUncGps
            | Method::DgmcGps
            | Method::GcnGmGps => Backbone::Likelihood(Architecture {
                consensus_steps: usize::from(m != Method::GcnGmGps),
                ..Architecture::default()
            }),
            _ => return None,
        })
    }

    /// The project's network of a method with the poses (`None` on the
    /// paper's inputs, or not a deep method).
    pub fn architecture(self) -> Option<Architecture> {
        match self.backbone()? {
            Backbone::Likelihood(a) => Some(a),
            Backbone::Published(_) => None,
        }
    }

    /// The terms a deep method trains with: the pair term, and the
    /// paper's Eq. 12 and 13 as the rows of Table 1 have them (none for a
    /// method that is not a deep one). The published networks' pair term
    /// is their own (the NLL of the true correspondences under `S_0` and
    /// `S_L`); the project's network's is the likelihood of the true
    /// assignment.
    pub fn loss_terms(self) -> LossTerms {
        let (non, unc) = match self.weights_owner() {
            Method::Coid | Method::Ours => (true, true),
            Method::CoidNon | Method::CoidNonGps => (true, false),
            Method::CoidUnc | Method::CoidUncGps => (false, true),
            _ => (false, false),
        };
        LossTerms {
            pairs: PairLoss::Likelihood,
            non,
            unc,
        }
    }

    /// Its terms with the pair term `[train] loss` names (`pairs`): for
    /// the paper's method and its ablations and for the project's
    /// network; DGMC and GCN-GM as published keep their NLL.
    pub fn loss_terms_with(self, pairs: PairLoss) -> LossTerms {
        let terms = self.loss_terms();
        match self.weights_owner() {
            Method::Dgmc | Method::GcnGm => terms,
            _ => LossTerms { pairs, ..terms },
        }
    }

    /// The dropout masks it trains with: DGMC and GCN-GM as published
    /// draw standard dropout, a mask per node and channel, whatever the
    /// settings; the paper's method and its ablations (on DGMC's network)
    /// as `[train] paper_dropout_masks` says (`paper`); the project's
    /// network as `[train] dropout_masks` says (`project`).
    pub fn training_masks(self, project: MaskScope, paper: MaskScope) -> MaskScope {
        match self.weights_owner() {
            Method::Dgmc | Method::GcnGm => MaskScope::PerNode,
            Method::Coid | Method::CoidNon | Method::CoidUnc => paper,
            _ => project,
        }
    }

    /// Whether its decision removes uncertain pairs: the methods trained
    /// with the paper's uncertainty-aware losses do; DGMC and GCN-GM, as
    /// published, do not (their thresholded F1 is still reported in Table
    /// 2).
    pub fn thresholds_by_default(self) -> bool {
        let terms = self.loss_terms();
        terms.non || terms.unc
    }
}

/// Which published network.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PublishedKind {
    /// psi_1 embeddings, `S_0 = Sinkhorn(H_s H_t^T)`.
    GcnGm,
    /// GCN-GM's `S_0`, then `steps` neighbourhood-consensus steps.
    Dgmc,
}

/// The graph a published network's psi_1 convolves over, on each
/// vehicle's body-frame positions; its edges carry their lengths.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NetworkGraph {
    /// The scene's Delaunay graph (the paper's, l. 69).
    #[default]
    Delaunay,
    /// Every pair of nodes (what spectral matching and RRWM compare):
    /// each node sees every other one's distance.
    Complete,
}

impl NetworkGraph {
    /// The paper's graph.
    pub fn is_delaunay(&self) -> bool {
        *self == NetworkGraph::Delaunay
    }
}

/// DGMC's random node indicators per consensus step (`rnd_dim`), as coid
/// trains the paper's network by default.
pub const CONSENSUS_DIM: usize = 32;

/// The last B-spline knot of the published networks' edge lengths by
/// default, metres (5 knots: one every 15 m).
pub const EDGE_SCALE_M: f64 = 60.0;

/// What `[train]` chooses of the published networks beyond the paper's
/// sizes (`graph`, `consensus_dim`, `edge_scale_m`); recorded with the
/// weights, which run as they were trained.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NetworkShape {
    pub graph: NetworkGraph,
    /// Random node indicators per consensus step, and psi_2's width.
    pub consensus_dim: usize,
    /// The last knot of the edge-length splines (longer edges clipped to
    /// it), metres.
    pub edge_scale_m: f64,
}

impl Default for NetworkShape {
    fn default() -> Self {
        Self {
            graph: NetworkGraph::Delaunay,
            consensus_dim: CONSENSUS_DIM,
            edge_scale_m: EDGE_SCALE_M,
        }
    }
}

/// The architecture of a published network and its fixed settings, in
/// the vocabulary [`Architecture`] speaks.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PublishedConfig {
    pub kind: PublishedKind,
    /// psi_1's first layer (paper: 256).
    pub hidden: usize,
    /// psi_1's embedding (paper: 32).
    pub out: usize,
    /// Dropout on psi_1's 256 hidden channels (paper: 0.4; once, as
    /// DGMC's `SplineCNN` applies it); MC dropout at inference uses the
    /// same rate. (Older records: `dropout`.)
    #[serde(alias = "dropout")]
    pub dropout_conv: f64,
    /// Random node indicators per consensus step, and psi_2's width (DGMC's
    /// `rnd_dim`, as older records name it).
    #[serde(alias = "rnd_dim")]
    pub consensus_dim: usize,
    /// Consensus steps L (DGMC's `num_steps`; 0 for GCN-GM). (Older
    /// records: `steps`.)
    #[serde(alias = "steps")]
    pub consensus_steps: usize,
    /// Sinkhorn iterations of every normalisation.
    pub sinkhorn_iters: usize,
    /// The last B-spline knot (edge lengths beyond are clipped), metres.
    pub edge_scale_m: f64,
    /// The width of the appearance vectors psi_1 reads beside class,
    /// colour and size (a dataset's learned features).
    #[serde(default, skip_serializing_if = "AppearanceWidth::is_none")]
    pub appearance_width: AppearanceWidth,
    /// The graph psi_1 convolves over (`[train] graph`).
    #[serde(default, skip_serializing_if = "NetworkGraph::is_delaunay")]
    pub graph: NetworkGraph,
}

impl PublishedConfig {
    /// psi_1's input width: class, colour, size and the appearance vector.
    pub fn node_features(&self) -> usize {
        NODE_FEATURES + self.appearance_width.get()
    }
}

impl PublishedConfig {
    /// The paper's sizes; DGMC with 10 consensus steps (DGMC's PascalVOC
    /// and WILLOW setting).
    pub fn new(kind: PublishedKind) -> Self {
        Self {
            kind,
            hidden: 256,
            out: 32,
            dropout_conv: 0.4,
            consensus_dim: CONSENSUS_DIM,
            consensus_steps: match kind {
                PublishedKind::GcnGm => 0,
                PublishedKind::Dgmc => 10,
            },
            sinkhorn_iters: 20,
            edge_scale_m: EDGE_SCALE_M,
            appearance_width: AppearanceWidth::NONE,
            graph: NetworkGraph::Delaunay,
        }
    }

    /// Consensus steps this configuration runs.
    pub fn consensus_steps(&self) -> usize {
        match self.kind {
            PublishedKind::GcnGm => 0,
            PublishedKind::Dgmc => self.consensus_steps,
        }
    }
}

/// Architecture and regularisation of the project's network, in the
/// vocabulary [`PublishedConfig`] speaks.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, try_from = "RawArchitecture")]
pub struct Architecture {
    /// The width of the appearance vectors its first layer reads beside
    /// class, colour and size (a dataset's learned features).
    #[serde(default, skip_serializing_if = "AppearanceWidth::is_none")]
    pub appearance_width: AppearanceWidth,
    pub hidden: usize,
    pub out: usize,
    pub dropout_conv: f64,
    /// DGMC neighbourhood consensus: one step (`dgmc+gps`, `ours`,
    /// ablations) or none (`gcn-gm+gps`).
    pub consensus_steps: usize,
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

/// The project network's record as read: the names it is written with,
/// or the older ones a record may hold (`node_features` for class,
/// colour, size and the vector together; `consensus` on or off).
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RawArchitecture {
    #[serde(default)]
    appearance_width: Option<usize>,
    #[serde(default)]
    node_features: Option<usize>,
    hidden: usize,
    out: usize,
    dropout_conv: f64,
    #[serde(default)]
    consensus_steps: Option<usize>,
    #[serde(default)]
    consensus: Option<bool>,
    consensus_dim: usize,
    dropout_phi: f64,
    sinkhorn_iters: usize,
    positions: bool,
    pair_hidden: usize,
}

impl TryFrom<RawArchitecture> for Architecture {
    type Error = String;

    fn try_from(r: RawArchitecture) -> Result<Self, String> {
        let appearance_width = match (r.appearance_width, r.node_features) {
            (Some(w), None) => AppearanceWidth::new(w),
            (None, None) => AppearanceWidth::NONE,
            (None, Some(n)) => n
                .checked_sub(NODE_FEATURES)
                .map(AppearanceWidth::new)
                .ok_or_else(|| {
                    format!(
                        "node_features = {n} is narrower than class, colour and size \
                     ({NODE_FEATURES}): not an architecture of this coid"
                    )
                })?,
            (Some(_), Some(_)) => {
                return Err("appearance_width and node_features name one width twice".into());
            }
        };
        let consensus_steps = match (r.consensus_steps, r.consensus) {
            (Some(s), None) => s,
            (None, Some(on)) => usize::from(on),
            _ => return Err("name consensus_steps (or, in old records, consensus) once".into()),
        };
        Ok(Self {
            appearance_width,
            hidden: r.hidden,
            out: r.out,
            dropout_conv: r.dropout_conv,
            consensus_steps,
            consensus_dim: r.consensus_dim,
            dropout_phi: r.dropout_phi,
            sinkhorn_iters: r.sinkhorn_iters,
            positions: r.positions,
            pair_hidden: r.pair_hidden,
        })
    }
}

impl Default for Architecture {
    fn default() -> Self {
        Self {
            appearance_width: AppearanceWidth::NONE,
            hidden: 256,
            out: 32,
            dropout_conv: 0.4,
            consensus_steps: 1,
            consensus_dim: 32,
            dropout_phi: 0.2,
            sinkhorn_iters: 20,
            positions: true,
            pair_hidden: 32,
        }
    }
}

impl Architecture {
    /// The same network reading appearance vectors `width` wide.
    pub fn with_appearance(self, width: AppearanceWidth) -> Self {
        Self {
            appearance_width: width,
            ..self
        }
    }

    /// The width of the appearance vectors it reads.
    pub fn appearance_width(&self) -> AppearanceWidth {
        self.appearance_width
    }

    /// Its first layer's input width: class, colour, size and the
    /// appearance vector.
    pub fn node_features(&self) -> usize {
        NODE_FEATURES + self.appearance_width.get()
    }

    /// Whether it has the consensus step.
    pub fn has_consensus(&self) -> bool {
        self.consensus_steps > 0
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
    /// How (MC) dropout draws its masks, in training and at inference.
    pub enum MaskScope {
        /// The paper's Eq. 8: in each sample, one Bernoulli mask over each
        /// layer's input units, shared by every node of the graphs (and, at
        /// inference, by every graph and pair): sample t is one draw of
        /// the weights, W^(t). In training each pair's sample is a draw of
        /// its own, shared by both of its graphs.
        #[strum(serialize = "shared")]
        Shared,
        /// A mask per node and unit (and per pair entry in the consensus
        /// MLP), drawn from each graph's and each pair's own stream.
        #[strum(serialize = "per-node")]
        PerNode,
    }
}

crate::label_enum! { "indicator draws";
    /// `[matching] indicators`: how DGMC's random node indicators are
    /// drawn across a pair's MC-dropout samples at inference.
    pub enum IndicatorScope {
        /// A fresh draw per sample (and per consensus step), as DGMC draws
        /// them in every forward pass: the samples differ in their masks
        /// and their indicators.
        #[strum(serialize = "per-sample")]
        PerSample,
        /// One draw per pair and consensus step, shared by its samples:
        /// the samples differ in their dropout masks alone, the paper's
        /// Eq. 9 (a sample is a draw of the weights).
        #[strum(serialize = "per-pair")]
        PerPair,
    }
}

crate::label_enum! { "dropout masks";
    /// `[matching] dropout_masks`: the masks MC dropout draws at
    /// inference.
    pub enum MaskChoice {
        /// As the weights were trained (their record's
        /// `dropout_masks`; "per-node" for weights whose record predates
        /// it).
        #[strum(serialize = "as-trained")]
        AsTrained,
        /// Eq. 8's shared masks, whatever the training drew.
        #[strum(serialize = "shared")]
        Shared,
        /// Masks per node and unit, whatever the training drew.
        #[strum(serialize = "per-node")]
        PerNode,
    }
}

impl MaskChoice {
    /// The scope inference uses for weights trained with `trained`.
    pub fn resolve(self, trained: MaskScope) -> MaskScope {
        match self {
            MaskChoice::AsTrained => trained,
            MaskChoice::Shared => MaskScope::Shared,
            MaskChoice::PerNode => MaskScope::PerNode,
        }
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

crate::label_enum! { "no-match weights";
    /// How the published networks' negative log-likelihood weighs the
    /// "no match" labels (the dustbin entry of every node without a
    /// partner) against the true pairs.
    #[strum(serialize_all = "lowercase")]
    pub enum NoMatchWeights {
        /// Every labelled entry alike (DGMC's NLL with dustbins): where two
        /// views share few objects, "no match" dominates.
        Entries,
        /// True pairs and "no match" labels each a half, each a mean of its
        /// own (as `loss = "likelihood"` weighs them for the project's
        /// network).
        Halves,
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
    use crate::matching::{Inputs, MethodKind};

    /// The deep methods and their rows of Tables 1 and 1b: (inputs,
    /// consensus, non, unc).
    #[test]
    fn each_deep_method_has_its_table_row() {
        use Inputs::{Paper, V2xPoses};
        let rows = [
            (Method::Coid, (Paper, true, true, true)),
            (Method::CoidNon, (Paper, true, true, false)),
            (Method::CoidUnc, (Paper, true, false, true)),
            (Method::Dgmc, (Paper, true, false, false)),
            (Method::GcnGm, (Paper, false, false, false)),
            (Method::Ours, (V2xPoses, true, true, true)),
            (Method::CoidNonGps, (V2xPoses, true, true, false)),
            (Method::CoidUncGps, (V2xPoses, true, false, true)),
            (Method::DgmcGps, (V2xPoses, true, false, false)),
            (Method::GcnGmGps, (V2xPoses, false, false, false)),
        ];
        // Variants run their owner's network.
        let deep: Vec<Method> = Method::all()
            .iter()
            .copied()
            .filter(|m| matches!(m.kind(), MethodKind::Deep) && !m.is_variant())
            .collect();
        assert_eq!(deep, rows.map(|(m, _)| m));
        for (t1, owner) in [
            (Method::CoidT1, Method::Coid),
            (Method::OursT1, Method::Ours),
        ] {
            assert_eq!(t1.kind(), owner.kind());
            assert_eq!(t1.inputs(), owner.inputs());
            assert_eq!(owner.single_pass_variant(), Some(t1));
        }
        let rule = Method::CoidPaperRule;
        assert_eq!((rule.weights_owner(), rule.inputs()), (Method::Coid, Paper));
        assert!(rule.is_variant() && !rule.single_pass() && rule.thresholds_by_default());
        for (m, row) in rows {
            assert_eq!(m.kind(), MethodKind::Deep);
            let d = m;
            let consensus = match d.backbone().unwrap() {
                Backbone::Published(c) => c.consensus_steps() > 0,
                Backbone::Likelihood(a) => a.has_consensus() && a.positions,
            };
            let t = d.loss_terms();
            assert_eq!((m.inputs(), consensus, t.non, t.unc), row, "{m:?}");
            assert_eq!(d.architecture().is_some(), m.inputs() == V2xPoses);
            let thresholds = t.non || t.unc;
            assert_eq!(d.thresholds_by_default(), thresholds);
        }
        assert!(!matches!(Method::GpsAppHungarian.kind(), MethodKind::Deep));
    }

    /// DGMC and GCN-GM train with standard dropout as published; the
    /// paper's method and its ablations as `paper_dropout_masks` says, the
    /// project's network as `dropout_masks` says.
    #[test]
    fn published_baselines_train_with_standard_dropout() {
        use MaskScope::{PerNode, Shared};
        for m in Method::all() {
            if m.kind() != MethodKind::Deep {
                continue;
            }
            let d = *m;
            let published = matches!(m, Method::Dgmc | Method::GcnGm);
            let paper = m.inputs() == Inputs::Paper && !published;
            let expect = |project, paper_masks| match (published, paper) {
                (true, _) => PerNode,
                (false, true) => paper_masks,
                (false, false) => project,
            };
            for (project, paper_masks) in [(Shared, PerNode), (PerNode, Shared)] {
                assert_eq!(
                    d.training_masks(project, paper_masks),
                    expect(project, paper_masks),
                    "{m:?}"
                );
            }
        }
    }

    /// A record's network reads back as the kind it was written as: the
    /// published configuration is not taken for the project's network,
    /// nor the other way round.
    /// `[train] loss` reaches the paper's method, its ablations and the
    /// project's network; DGMC and GCN-GM as published keep their NLL.
    #[test]
    fn the_pair_loss_reaches_the_papers_method_not_the_published_baselines() {
        for m in [
            Method::Coid,
            Method::CoidNon,
            Method::CoidUnc,
            Method::Ours,
            Method::DgmcGps,
        ] {
            assert_eq!(
                m.loss_terms_with(PairLoss::Paper).pairs,
                PairLoss::Paper,
                "{m:?}"
            );
        }
        for m in [Method::Dgmc, Method::GcnGm] {
            assert_eq!(
                m.loss_terms_with(PairLoss::Paper).pairs,
                PairLoss::Likelihood,
                "{m:?}"
            );
        }
        assert!(Method::Coid.loss_terms_with(PairLoss::Paper).non);
    }

    #[test]
    fn backbones_round_trip_through_toml() {
        #[derive(serde::Serialize, serde::Deserialize)]
        struct Holder {
            architecture: Backbone,
        }
        for m in Method::all() {
            let Some(backbone) = m.backbone() else {
                continue;
            };
            let text = toml::to_string(&Holder {
                architecture: backbone,
            })
            .unwrap();
            let back: Holder = toml::from_str(&text).unwrap();
            assert_eq!(back.architecture, backbone, "{m:?}: {text}");
        }
    }
}
