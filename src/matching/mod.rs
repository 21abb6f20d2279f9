//! Correspondence identification: which detections of two vehicles are the
//! same object. Every method implements [`Matcher`]; the rest of the program
//! sees only plain [`Correspondence`] lists with a probability and an
//! uncertainty per pair. Pairs not listed are "no match" (non-covisible).

pub mod affinity;
pub mod deep;
mod gps_hungarian;
mod mogm;
mod oracle;
mod rgm;

pub use gps_hungarian::GpsHungarian;
pub use mogm::Mogm;
pub use oracle::Oracle;
pub use rgm::Rgm;

use serde::Deserialize;

use crate::config::{MatchingSettings, PoseNoiseLevel};
use crate::geometry::Pose2;
use crate::graph::SceneGraph;
use crate::sensor::Detection;

/// The matching methods, with the labels used in configs and results.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Deserialize)]
pub enum Method {
    /// The paper's Bayesian deep graph matcher: L_coid + L_non + L_unc,
    /// MC-dropout uncertainty, thresholding.
    #[serde(rename = "ours")]
    Ours,
    /// Ablation: L_coid + L_non.
    #[serde(rename = "coid+non")]
    CoidNon,
    /// Ablation: L_coid + L_unc.
    #[serde(rename = "coid+unc")]
    CoidUnc,
    /// DGMC: GNN + neighbourhood consensus, L_coid only.
    #[serde(rename = "dgmc")]
    Dgmc,
    /// GCN-GM: GNN similarity + Sinkhorn, L_coid only.
    #[serde(rename = "gcn-gm")]
    GcnGm,
    /// Learning-free multi-order graph matching (appearance, edge lengths,
    /// edge directions; spectral solution).
    #[serde(rename = "mogm")]
    Mogm,
    /// Learning-free regularised graph matching that allows "no match"
    /// (IPFP with a price per match).
    #[serde(rename = "rgm")]
    Rgm,
    /// Detections moved into the ego frame with the GPS poses, gated
    /// Hungarian assignment on Mahalanobis distance.
    #[serde(rename = "gps-hungarian")]
    GpsHungarian,
    /// The true correspondences: an upper bound for fusion.
    #[serde(rename = "oracle")]
    Oracle,
}

impl Method {
    pub fn as_str(self) -> &'static str {
        match self {
            Method::Ours => "ours",
            Method::CoidNon => "coid+non",
            Method::CoidUnc => "coid+unc",
            Method::Dgmc => "dgmc",
            Method::GcnGm => "gcn-gm",
            Method::Mogm => "mogm",
            Method::Rgm => "rgm",
            Method::GpsHungarian => "gps-hungarian",
            Method::Oracle => "oracle",
        }
    }
}

/// One vehicle's side of a matching problem: what that vehicle knows.
#[derive(Clone, Copy, Debug)]
pub struct MatchView<'a> {
    /// Detections in the vehicle's body frame.
    pub detections: &'a [Detection],
    pub graph: &'a SceneGraph,
    /// The vehicle's pose as its GPS reports it, world frame.
    pub pose_reported: Pose2,
    /// The accuracy the GPS claims for that pose (the noise level's sigmas).
    pub pose_noise: PoseNoiseLevel,
}

/// Detection `a` of the first vehicle is detection `b` of the second.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    pub a: usize,
    pub b: usize,
    /// The method's probability that the pair is the same object.
    pub probability: f64,
    /// Binary entropy of `probability`, in bits (0 = certain, 1 = coin flip).
    pub uncertainty: f64,
}

/// A one-to-one correspondence method between two vehicles' detections.
pub trait Matcher: Send + Sync {
    fn method(&self) -> Method;
    /// One-to-one pairs (each `a` and each `b` at most once), sorted by `a`.
    fn match_pair(&self, first: &MatchView, second: &MatchView) -> Vec<Correspondence>;
}

/// Binary entropy in bits, 0 at p in {0, 1} and 1 at p = 0.5.
pub fn binary_entropy_bits(p: f64) -> f64 {
    let p = p.clamp(0.0, 1.0);
    let h = |q: f64| if q <= 0.0 { 0.0 } else { -q * q.log2() };
    h(p) + h(1.0 - p)
}

/// Builds the matcher for a method; deep methods load their trained
/// weights from `settings.models_dir`.
pub fn matcher_for(
    method: Method,
    settings: &MatchingSettings,
    dropout_seed: u64,
) -> Result<Box<dyn Matcher>, deep::LoadError> {
    Ok(match method {
        Method::Mogm => Box::new(Mogm::default()),
        Method::Rgm => Box::new(Rgm::default()),
        Method::GpsHungarian => Box::new(GpsHungarian {
            gate_chi2: settings.gate_chi2,
        }),
        Method::Oracle => Box::new(Oracle),
        deep_method => {
            let threshold = deep::thresholds_by_default(deep_method)
                .then_some((settings.uncertainty, settings.lambda));
            Box::new(deep::DeepMatcher::load(
                deep_method,
                &settings.models_dir,
                settings.mc_samples,
                threshold,
                dropout_seed,
            )?)
        }
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::config::{PoseNoiseLabel, PoseNoiseLevel};
    use crate::geometry::{Cov2, Vec2};
    use crate::sensor::Appearance;
    use crate::traffic::ObjectClass;

    pub(crate) fn test_settings() -> MatchingSettings {
        MatchingSettings {
            methods: vec![],
            gate_chi2: 9.21,
            models_dir: std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models"),
            mc_samples: 20,
            lambda: 0.7,
            uncertainty: deep::decision::UncertaintyKind::Total,
        }
    }

    pub(crate) const EXACT: PoseNoiseLevel = PoseNoiseLevel {
        label: PoseNoiseLabel::None,
        position_sigma_m: 0.0,
        heading_sigma_rad: 0.0,
    };

    /// Objects in the world: position, class, colour. Colours repeat.
    pub(crate) fn world_objects() -> Vec<(Vec2, ObjectClass, [f64; 3])> {
        let white = [0.95; 3];
        let black = [0.1; 3];
        let red = [0.7, 0.1, 0.1];
        vec![
            (Vec2::new(12.0, 3.0), ObjectClass::Car, white),
            (Vec2::new(18.0, -6.0), ObjectClass::Car, black),
            (Vec2::new(25.0, 9.0), ObjectClass::Car, white),
            (Vec2::new(31.0, -2.0), ObjectClass::Truck, red),
            (Vec2::new(9.0, 14.0), ObjectClass::Pedestrian, black),
            (Vec2::new(22.0, 17.0), ObjectClass::Car, white),
            (Vec2::new(36.0, 12.0), ObjectClass::Car, black),
            (Vec2::new(15.0, -15.0), ObjectClass::Bicycle, red),
        ]
    }

    pub(crate) fn detections_from(
        pose: &Pose2,
        objects: &[(Vec2, ObjectClass, [f64; 3])],
        order: &[usize],
    ) -> Vec<Detection> {
        order
            .iter()
            .map(|&k| {
                let (w, class, colour) = objects[k];
                Detection {
                    position_m: pose.to_body(&w),
                    cov_m2: Cov2::identity() * 0.25,
                    appearance: Appearance {
                        class,
                        colour_rgb: colour,
                        length_m: 4.6,
                        width_m: 1.8,
                        height_m: 1.5,
                    },
                    truth_id: Some(k.to_string()),
                    visible_fraction: 1.0,
                }
            })
            .collect()
    }

    /// Matches a scene against a rigidly moved, reordered copy of itself and
    /// returns the fraction of detections paired with their true twin and
    /// the number of wrong pairs.
    pub(crate) fn self_match(matcher: &dyn Matcher) -> (f64, usize) {
        let objects = world_objects();
        let pa = Pose2::new(Vec2::new(0.0, 0.0), 0.0);
        let pb = Pose2::new(Vec2::new(45.0, 30.0), -2.4);
        let da = detections_from(&pa, &objects, &(0..objects.len()).collect::<Vec<_>>());
        let db = detections_from(&pb, &objects, &[5, 2, 7, 0, 3, 6, 1, 4]);
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
        let m = matcher.match_pair(&va, &vb);
        let right = m
            .iter()
            .filter(|c| da[c.a].truth_id == db[c.b].truth_id)
            .count();
        (right as f64 / objects.len() as f64, m.len() - right)
    }

    #[test]
    fn every_matcher_matches_a_moved_copy_of_a_scene_to_itself() {
        for method in [
            Method::Mogm,
            Method::Rgm,
            Method::GpsHungarian,
            Method::Oracle,
        ] {
            let (found, wrong) =
                self_match(matcher_for(method, &test_settings(), 1).unwrap().as_ref());
            assert_eq!((found, wrong), (1.0, 0), "{method:?}");
        }
    }

    #[test]
    fn graph_matchers_find_nothing_in_unrelated_scenes() {
        // The second vehicle sees other objects of other classes elsewhere.
        let objects = world_objects();
        let others: Vec<(Vec2, ObjectClass, [f64; 3])> = objects
            .iter()
            .map(|&(p, c, col)| {
                (
                    Vec2::new(p.y * 1.7, -p.x * 0.6),
                    if c == ObjectClass::Pedestrian {
                        ObjectClass::Bus
                    } else {
                        ObjectClass::Pedestrian
                    },
                    col,
                )
            })
            .collect();
        let pa = Pose2::identity();
        let pb = Pose2::new(Vec2::new(45.0, 30.0), -2.4);
        let idx: Vec<usize> = (0..objects.len()).collect();
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
        // RGM prices every match, so unsupported pairs stay unmatched.
        assert!(
            matcher_for(Method::Rgm, &test_settings(), 1)
                .unwrap()
                .match_pair(&va, &vb)
                .is_empty()
        );
        // Spectral matching (MOGM) has no absolute "no match": it keeps the
        // strongest compatible candidates (here: the first vehicle's
        // pedestrian and bicycle, both compatible with the second's
        // pedestrians), a known weakness of the method.
        assert!(
            matcher_for(Method::Mogm, &test_settings(), 1)
                .unwrap()
                .match_pair(&va, &vb)
                .len()
                <= 2
        );
    }

    #[test]
    fn entropy_bounds() {
        assert_eq!(binary_entropy_bits(0.0), 0.0);
        assert_eq!(binary_entropy_bits(1.0), 0.0);
        assert!((binary_entropy_bits(0.5) - 1.0).abs() < 1e-12);
        assert!(binary_entropy_bits(0.9) < binary_entropy_bits(0.7));
    }
}
