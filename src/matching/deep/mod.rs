//! The paper's Bayesian deep graph matcher (Section 3) and its deep
//! baselines and ablations. `features` and `decision` are plain Rust;
//! `model` (and `train`) are the only code in the crate that see tensors
//! (burn). Callers get a [`MatchDistribution`] or plain correspondences.

pub mod decision;
pub mod features;
pub mod model;
pub mod train;

use std::path::{Path, PathBuf};

use burn::prelude::*;
use rand::{Rng, RngCore};
use rand_chacha::ChaCha8Rng;

use self::decision::{MatchDistribution, UncertaintyKind};
use self::features::graph_input;
use self::model::{Architecture, GraphTensors, LossTerms, Masks, Network};
use super::{Correspondence, MatchView, Matcher, Method};
use crate::rng::{self, Purpose};

/// Architecture and loss terms of each deep method (paper Table 1 rows).
pub fn variant(method: Method) -> Option<(Architecture, LossTerms)> {
    let arch = Architecture::default();
    let (consensus, non, unc) = match method {
        Method::Ours => (true, true, true),
        Method::CoidNon => (true, true, false),
        Method::CoidUnc => (true, false, true),
        Method::Dgmc => (true, false, false),
        Method::GcnGm => (false, false, false),
        _ => return None,
    };
    Some((Architecture { consensus, ..arch }, LossTerms { non, unc }))
}

/// Whether a method's decision removes uncertain pairs: the methods trained
/// with the paper's uncertainty-aware losses do; DGMC and GCN-GM, as
/// published, do not (their thresholded F1 is still reported in Table 2).
pub fn thresholds_by_default(method: Method) -> bool {
    matches!(method, Method::Ours | Method::CoidNon | Method::CoidUnc)
}

/// Weights file of a method in a models folder.
pub fn weights_path(models_dir: &Path, method: Method) -> PathBuf {
    models_dir.join(format!("{}.bpk", method.as_str()))
}

#[derive(Debug, thiserror::Error)]
#[error(
    "cannot load the weights of '{method}' from {path} ({reason}); run `coid train` to make them"
)]
pub struct LoadError {
    pub method: &'static str,
    pub path: PathBuf,
    pub reason: String,
}

/// Draws inverted-dropout masks (0 or 1 / (1 - p)) of the given shape.
fn dropout_mask(rng: &mut ChaCha8Rng, len: usize, p: f64) -> Vec<f32> {
    if p <= 0.0 {
        return vec![1.0; len];
    }
    let keep = 1.0 - p;
    let scale = (1.0 / keep) as f32;
    // Compare raw 32-bit draws with the keep threshold: one draw per unit.
    let threshold = (keep * 4_294_967_296.0).min(f64::from(u32::MAX)) as u32;
    let mut out = vec![0f32; len];
    for v in out.iter_mut() {
        if rng.next_u32() < threshold {
            *v = scale;
        }
    }
    out
}

/// All masks of one forward pass with `t` samples, from one stream.
pub fn draw_masks(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    t: usize,
    n1: usize,
    n2: usize,
    device: &Device,
) -> Masks {
    let mut mask = |n: usize, d: usize, p: f64| {
        Tensor::<3>::from_data(
            TensorData::new(dropout_mask(rng, t * n * d, p), [t, n, d]),
            device,
        )
    };
    let conv1 = [
        mask(n1, arch.hidden, arch.dropout_conv),
        mask(n2, arch.hidden, arch.dropout_conv),
    ];
    let conv2 = [
        mask(n1, arch.out, arch.dropout_conv),
        mask(n2, arch.out, arch.dropout_conv),
    ];
    let r = arch.consensus_dim;
    let phi = if arch.consensus {
        Tensor::<4>::from_data(
            TensorData::new(
                dropout_mask(rng, t * n1 * n2 * r, arch.dropout_phi),
                [t, n1, n2, r],
            ),
            device,
        )
    } else {
        Tensor::<4>::ones([1, 1, 1, 1], device)
    };
    let normal = rand_distr::StandardNormal;
    let indicators: Vec<f32> = (0..n1 * r)
        .map(|_| rng.sample::<f64, _>(normal) as f32)
        .collect();
    Masks {
        conv1,
        conv2,
        phi,
        indicators: Tensor::from_data(TensorData::new(indicators, [1, n1, r]), device),
    }
}

/// A stable key of a matching problem's inputs: the masks of a pair depend
/// only on the pair, not on what was matched before.
fn problem_key(first: &MatchView, second: &MatchView) -> u64 {
    let mut parts = vec![
        first.detections.len() as u64,
        second.detections.len() as u64,
    ];
    for d in first.detections.iter().chain(second.detections) {
        parts.push(d.position_m.x.to_bits());
        parts.push(d.position_m.y.to_bits());
    }
    rng::key(&parts)
}

/// A trained deep matcher with MC-dropout inference.
pub struct DeepMatcher {
    pub method: Method,
    pub arch: Architecture,
    net: Network,
    device: Device,
    /// Monte Carlo samples (paper: T = 20).
    pub samples: usize,
    /// Removal of uncertain pairs in [`Matcher::match_pair`].
    pub threshold: Option<(UncertaintyKind, f64)>,
    /// Seed of the dropout-mask streams.
    pub seed: u64,
}

impl DeepMatcher {
    pub fn new(
        method: Method,
        net: Network,
        arch: Architecture,
        samples: usize,
        threshold: Option<(UncertaintyKind, f64)>,
        seed: u64,
    ) -> Self {
        Self {
            method,
            arch,
            net: net.valid(),
            device: Device::flex(),
            samples,
            threshold,
            seed,
        }
    }

    pub fn load(
        method: Method,
        models_dir: &Path,
        samples: usize,
        threshold: Option<(UncertaintyKind, f64)>,
        seed: u64,
    ) -> Result<Self, LoadError> {
        let path = weights_path(models_dir, method);
        let fail = |reason: String| LoadError {
            method: method.as_str(),
            path: path.clone(),
            reason,
        };
        let (arch, _) = variant(method).ok_or_else(|| fail("not a deep method".into()))?;
        if !path.is_file() {
            return Err(fail("no such file".into()));
        }
        let net = model::load(&arch, &path, &Device::flex()).map_err(fail)?;
        Ok(Self::new(method, net, arch, samples, threshold, seed))
    }

    /// The `samples` MC-dropout assignments, each `(n1 + 1) x (n2 + 1)`
    /// row-major; both sides must be non-empty.
    pub fn samples(&self, first: &MatchView, second: &MatchView) -> Vec<Vec<f32>> {
        let (n1, n2) = (first.detections.len(), second.detections.len());
        let g1 = GraphTensors::new(
            &graph_input(first.detections, first.graph, &first.pose_reported),
            &self.device,
        );
        let g2 = GraphTensors::new(
            &graph_input(second.detections, second.graph, &second.pose_reported),
            &self.device,
        );
        let mut stream = rng::stream(self.seed, Purpose::Dropout, &[problem_key(first, second)]);
        let masks = draw_masks(&mut stream, &self.arch, self.samples, n1, n2, &self.device);
        let cost = Tensor::<3>::from_data(
            TensorData::new(features::position_cost(first, second), [1, n1, n2]),
            &self.device,
        );
        let log_p = self
            .net
            .forward(&g1, &g2, masks, cost, self.arch.sinkhorn_iters);
        let p: Vec<f32> = log_p.exp().try_into_vec_as::<f32>().unwrap_or_default();
        p.chunks((n1 + 1) * (n2 + 1)).map(<[f32]>::to_vec).collect()
    }

    /// E[Y] and the per-pair uncertainties from `samples` MC-dropout passes.
    pub fn distribution(&self, first: &MatchView, second: &MatchView) -> MatchDistribution {
        let (n1, n2) = (first.detections.len(), second.detections.len());
        if n1 == 0 || n2 == 0 {
            // Everything goes to the dustbin.
            let mut mean = vec![0f32; (n1 + 1) * (n2 + 1)];
            for i in 0..n1 {
                mean[i * (n2 + 1) + n2] = 1.0;
            }
            for j in 0..n2 {
                mean[n1 * (n2 + 1) + j] = 1.0;
            }
            return MatchDistribution {
                n1,
                n2,
                mean,
                aleatoric: vec![0.0; n1 * n2],
            };
        }
        let samples = self.samples(first, second);
        MatchDistribution::from_samples(n1, n2, &samples)
    }
}

impl Matcher for DeepMatcher {
    fn method(&self) -> Method {
        self.method
    }

    fn match_pair(&self, first: &MatchView, second: &MatchView) -> Vec<Correspondence> {
        self.distribution(first, second).decide(self.threshold)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Pose2, Vec2};
    use crate::graph::SceneGraph;
    use crate::matching::tests::{EXACT, detections_from, world_objects};
    use rand::SeedableRng;

    #[test]
    fn sinkhorn_rows_and_columns_sum_to_one_with_dustbins() {
        let device = Device::flex();
        let scores = Tensor::<3>::random(
            [2, 4, 6],
            burn::tensor::Distribution::Normal(0.0, 3.0),
            &device,
        );
        let p = model::log_sinkhorn(scores, Tensor::ones([1], &device), 50).exp();
        let v: Vec<f32> = p.try_into_vec_as::<f32>().unwrap();
        for t in 0..2 {
            let at = |i: usize, j: usize| v[t * 35 + i * 7 + j];
            for i in 0..4 {
                let row: f32 = (0..7).map(|j| at(i, j)).sum();
                assert!((row - 1.0).abs() < 1e-3, "row {i}: {row}");
            }
            for j in 0..6 {
                let col: f32 = (0..5).map(|i| at(i, j)).sum();
                assert!((col - 1.0).abs() < 1e-3, "col {j}: {col}");
            }
        }
    }

    fn scene_views() -> (
        Vec<crate::sensor::Detection>,
        Vec<crate::sensor::Detection>,
        SceneGraph,
        SceneGraph,
        Pose2,
        Pose2,
    ) {
        let objects = world_objects();
        let pa = Pose2::identity();
        let pb = Pose2::new(Vec2::new(45.0, 30.0), -2.4);
        let da = detections_from(&pa, &objects, &(0..objects.len()).collect::<Vec<_>>());
        let db = detections_from(&pb, &objects, &[5, 2, 7, 0, 3, 6, 1, 4]);
        let ga =
            SceneGraph::delaunay(&da.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap();
        let gb =
            SceneGraph::delaunay(&db.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap();
        (da, db, ga, gb, pa, pb)
    }

    fn matcher_with(arch: Architecture, seed: u64) -> DeepMatcher {
        Device::flex().seed(seed);
        let net = Network::new(&arch, &Device::flex());
        DeepMatcher::new(Method::Ours, net, arch, 20, None, seed)
    }

    /// The MC samples of the test scene.
    fn mc_samples(m: &DeepMatcher) -> Vec<Vec<f32>> {
        let (da, db, ga, gb, pa, pb) = scene_views();
        let va = MatchView {
            detections: &da,
            graph: &ga,
            pose_reported: pa,
            pose_noise: EXACT,
        };
        let vb = MatchView {
            detections: &db,
            graph: &gb,
            pose_reported: pb,
            pose_noise: EXACT,
        };
        let samples = m.samples(&va, &vb);
        assert_eq!(samples.len(), 20);
        samples
    }

    /// Largest per-entry variance across samples.
    fn max_variance(samples: &[Vec<f32>]) -> f64 {
        let t = samples.len() as f64;
        (0..samples[0].len())
            .map(|k| {
                let mean = samples.iter().map(|s| f64::from(s[k])).sum::<f64>() / t;
                samples
                    .iter()
                    .map(|s| (f64::from(s[k]) - mean).powi(2))
                    .sum::<f64>()
                    / t
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn mc_dropout_samples_really_differ_at_inference() {
        let with = matcher_with(Architecture::default(), 3);
        let v = max_variance(&mc_samples(&with));
        assert!(
            v > 1e-4,
            "p > 0 must give varying samples (max variance {v})"
        );
        let without = matcher_with(
            Architecture {
                dropout_conv: 0.0,
                dropout_phi: 0.0,
                ..Architecture::default()
            },
            3,
        );
        let samples = mc_samples(&without);
        assert!(
            samples.iter().all(|s| *s == samples[0]),
            "p = 0 must give identical samples"
        );
    }

    #[test]
    fn dropout_masks_have_the_right_rate_and_scale() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let m = dropout_mask(&mut rng, 100_000, 0.4);
        let kept = m.iter().filter(|&&v| v > 0.0).count() as f64 / m.len() as f64;
        assert!((kept - 0.6).abs() < 0.01, "{kept}");
        assert!(m.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.6).abs() < 1e-6));
        assert!(dropout_mask(&mut rng, 10, 0.0).iter().all(|&v| v == 1.0));
    }

    #[test]
    fn save_then_load_gives_identical_outputs() {
        let arch = Architecture::default();
        let m = matcher_with(arch, 11);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ours.bpk");
        model::save(&m.net, &path).unwrap();
        let loaded = DeepMatcher::new(
            Method::Ours,
            model::load(&arch, &path, &Device::flex()).unwrap(),
            arch,
            20,
            None,
            11,
        );
        let (da, db, ga, gb, pa, pb) = scene_views();
        let va = MatchView {
            detections: &da,
            graph: &ga,
            pose_reported: pa,
            pose_noise: EXACT,
        };
        let vb = MatchView {
            detections: &db,
            graph: &gb,
            pose_reported: pb,
            pose_noise: EXACT,
        };
        assert_eq!(m.distribution(&va, &vb), loaded.distribution(&va, &vb));
    }

    #[test]
    fn empty_sides_send_everything_to_the_dustbin() {
        let m = matcher_with(Architecture::default(), 1);
        let (da, _, ga, gb, pa, pb) = scene_views();
        let va = MatchView {
            detections: &da,
            graph: &ga,
            pose_reported: pa,
            pose_noise: EXACT,
        };
        let vb = MatchView {
            detections: &[],
            graph: &gb,
            pose_reported: pb,
            pose_noise: EXACT,
        };
        assert!(m.match_pair(&va, &vb).is_empty());
    }

    fn shipped(method: Method) -> DeepMatcher {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
        DeepMatcher::load(method, &dir, 20, Some((UncertaintyKind::Total, 0.7)), 1).unwrap()
    }

    #[test]
    fn shipped_model_matches_a_moved_copy_of_a_scene_to_itself() {
        let (found, wrong) = crate::matching::tests::self_match(&shipped(Method::Ours));
        assert_eq!((found, wrong), (1.0, 0));
    }

    #[test]
    fn shipped_model_finds_nothing_between_unrelated_scenes() {
        // Different objects (other classes, other places) seen by two
        // vehicles far apart.
        let objects = world_objects();
        let others: Vec<_> = objects
            .iter()
            .map(|&(p, _, col)| {
                (
                    Vec2::new(p.x + 150.0, p.y - 90.0),
                    crate::traffic::ObjectClass::Pedestrian,
                    col,
                )
            })
            .collect();
        let idx: Vec<usize> = (0..objects.len()).collect();
        let pa = Pose2::identity();
        let pb = Pose2::new(Vec2::new(140.0, -100.0), 1.0);
        let da = detections_from(&pa, &objects, &idx);
        let db = detections_from(&pb, &others, &idx);
        let ga =
            SceneGraph::delaunay(&da.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap();
        let gb =
            SceneGraph::delaunay(&db.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap();
        let va = MatchView {
            detections: &da,
            graph: &ga,
            pose_reported: pa,
            pose_noise: EXACT,
        };
        let vb = MatchView {
            detections: &db,
            graph: &gb,
            pose_reported: pb,
            pose_noise: EXACT,
        };
        assert!(shipped(Method::Ours).match_pair(&va, &vb).is_empty());
    }
}
