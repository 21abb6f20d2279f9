//! What the deep networks see besides their graphs ([`super::graph`]):
//! node attributes (the paper's A: class, colour, size and, where a
//! network reads one, the appearance vector), the check that data carries
//! the vectors a network reads, and the pair inputs of the project's
//! network (the pair likelihood through the GPS relative pose, offset
//! votes, range and bearing from either vehicle).
use crate::fusion::PoseEstimate;
use crate::geometry::{Pose2, Vec2};
use crate::matching::MatchView;
use crate::matching::learning_free::appearance_similarity;
use crate::matching::likelihood::{LikelihoodTerms, pair_terms};
use crate::sensor::{AppearanceWidth, Detection};
use crate::traffic::ObjectClass;

/// Node attribute length without appearance vectors: class one-hot (7),
/// colour (3), size (3). A network that reads a dataset's appearance
/// vectors (`appearance_width` wide) has these first, then the vector.
pub(crate) const NODE_FEATURES: usize = 13;

/// Appends `d`'s node attributes: class one-hot, colour and size, then,
/// for a network that reads appearance vectors `appearance_width` wide
/// (0: none), the detection's vector (zeros for a node without one).
/// Callers check that the data carries vectors of that width before a
/// network reads it ([`check_appearance`]).
pub(crate) fn push_node_features(
    d: &Detection,
    appearance_width: AppearanceWidth,
    out: &mut Vec<f32>,
) {
    let mut f = [0f32; NODE_FEATURES];
    let class = ObjectClass::ALL
        .iter()
        .position(|&c| c == d.appearance.class)
        .unwrap_or(0);
    f[class] = 1.0;
    for k in 0..3 {
        f[7 + k] = d.appearance.colour_rgb[k] as f32;
    }
    f[10] = (d.appearance.length_m / 10.0) as f32;
    f[11] = (d.appearance.width_m / 3.0) as f32;
    f[12] = (d.appearance.height_m / 4.0) as f32;
    out.extend_from_slice(&f);
    if let Some(appearance_width) = appearance_width.width() {
        match d.appearance.descriptor.as_ref().map(|v| &v.values[..]) {
            Some(values) => {
                assert_eq!(
                    values.len(),
                    appearance_width,
                    "appearance vectors of the network's width (checked before it runs)"
                );
                out.extend_from_slice(values);
            }
            // A node without one among described nodes (a sender's
            // self-report): zeros, as coid's exports write it.
            None => out.extend(std::iter::repeat_n(0.0, appearance_width)),
        }
    }
}

/// Node attributes of `detections`, `n x (NODE_FEATURES +
/// appearance_width)` row-major ([`push_node_features`]).
pub fn node_attributes(detections: &[Detection], appearance_width: AppearanceWidth) -> Vec<f32> {
    let mut out = Vec::with_capacity(detections.len() * (NODE_FEATURES + appearance_width.get()));
    for d in detections {
        push_node_features(d, appearance_width, &mut out);
    }
    out
}

/// Why a network that reads appearance vectors `network_width` wide (0:
/// none) cannot read data whose vectors are `data_width` wide (`None`:
/// the data has none a method may use); `None` when it can. A network
/// without vectors reads any data (and leaves its vectors alone).
pub fn check_appearance(network: AppearanceWidth, data: AppearanceWidth) -> Option<String> {
    match (network.get(), data.width()) {
        (0, _) => None,
        (w, Some(d)) if w == d => None,
        (w, Some(d)) => Some(format!(
            "the network reads appearance vectors {w} wide; this data's are {d} wide"
        )),
        (w, None) => Some(format!(
            "the network reads appearance vectors {w} wide; this data has none (a dataset's \
             vectors are used when they tell same and different objects apart on its \
             validation runs)"
        )),
    }
}

/// Pair features per (i, j): see [`pair_input`].
pub(crate) const PAIR_FEATURES: usize = 12;
/// Per-node features of the learned "no match" score: see [`pair_input`].
pub(crate) const DUST_FEATURES: usize = 13;
/// Ranges are given in units of this (the default camera range).
const RANGE_SCALE_M: f64 = 70.0;

/// What the pair part of the network sees of one pair of vehicles, beside
/// the two graphs.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PairInput {
    pub(crate) n1: usize,
    pub(crate) n2: usize,
    /// `n1 x n2` row-major: the shared pair log-likelihood
    /// ([`crate::matching::likelihood`]) where the pair passes its gates.
    pub(crate) log_likelihood: Vec<Option<f64>>,
    /// `n1 x n2 x PAIR_FEATURES`: squared Mahalanobis distance over the
    /// gate (0 without positions), log appearance similarity, same class,
    /// confusable class, absolute colour difference per channel, chroma
    /// difference (colour over its brightness, which lighting scales),
    /// relative length, width and height differences, and the pair's
    /// offset vote ([`offset_votes`]).
    pub(crate) pair_features: Vec<f32>,
    /// `n x DUST_FEATURES` per vehicle: the node's range and bearing (cos,
    /// sin) from its own vehicle; its range and bearing from the other
    /// vehicle, through the relative pose (zeros without positions); its
    /// class, one-hot. What tells whether the other vehicle can see it.
    pub(crate) dust_features: [Vec<f32>; 2],
}

/// The pair input of two views, with `relative` the second vehicle's pose
/// in the first one's frame and `terms` the likelihood's terms and gates.
pub(crate) fn pair_input(
    first: &MatchView,
    second: &MatchView,
    relative: &PoseEstimate,
    terms: &LikelihoodTerms,
) -> PairInput {
    let (n1, n2) = (first.detections.len(), second.detections.len());
    let pairs = pair_terms(first, second, relative, terms);
    let similarity: Vec<f64> = first
        .detections
        .iter()
        .flat_map(|a| {
            second
                .detections
                .iter()
                .map(|b| appearance_similarity(&a.appearance, &b.appearance))
        })
        .collect();
    let votes = offset_votes(first, second, relative, terms, &similarity);
    let mut pair_features = Vec::with_capacity(n1 * n2 * PAIR_FEATURES);
    for (i, a) in first.detections.iter().enumerate() {
        for (j, b) in second.detections.iter().enumerate() {
            let k = i * n2 + j;
            let d2 = pairs[k].map_or(terms.gate_chi2, |t| t.d2);
            let d2 = if terms.position { d2 } else { 0.0 };
            let s = similarity[k].max(1e-6);
            pair_features.extend(appearance_pair(a, b, d2 / terms.gate_chi2, s.ln() / 5.0));
            pair_features.push(votes[k].ln_1p() as f32);
        }
    }
    let inverse = relative.pose.inverse();
    let dust = |view: &MatchView, other: &Pose2| -> Vec<f32> {
        let mut v = Vec::with_capacity(view.detections.len() * DUST_FEATURES);
        for d in view.detections {
            let across = if terms.position {
                other.to_parent(&d.position_m)
            } else {
                Vec2::zeros()
            };
            v.extend(range_bearing(&d.position_m));
            v.extend(range_bearing(&across));
            v.extend(class_one_hot(d));
        }
        v
    };
    PairInput {
        n1,
        n2,
        log_likelihood: pairs
            .iter()
            .map(|p| p.map(|p| p.log_likelihood()))
            .collect(),
        pair_features,
        // A node of the first vehicle in the second one's frame, and back.
        dust_features: [dust(first, &inverse), dust(second, &relative.pose)],
    }
}

/// How much the other candidate pairs agree with each pair's offset (a
/// Hough vote), `n1 x n2`. A pair's offset is the first vehicle's
/// detection minus the second's, moved into the first vehicle's frame by
/// the relative pose: its heading always (GPS gives it to 0.2 deg), its
/// position only when the likelihood has the position term. The true
/// pairs share one offset (the vehicles' relative position, unknown
/// without positions; with them, the error common to the relative pose),
/// so each pair's vote is `sum w_kb exp(-|o_ij - o_kb|^2 / 2 (v_ij +
/// v_kb))` over the other candidates (k != i, b != j) that pass the
/// appearance gate, `w` their appearance similarity and `v` the mean
/// per-axis variance of their two detections. A shared error cancels in
/// the differences, which is what no pair's likelihood alone can use.
pub(crate) fn offset_votes(
    first: &MatchView,
    second: &MatchView,
    relative: &PoseEstimate,
    terms: &LikelihoodTerms,
    similarity: &[f64],
) -> Vec<f64> {
    let (n1, n2) = (first.detections.len(), second.detections.len());
    let pose = if terms.position {
        relative.pose
    } else {
        Pose2::new(Vec2::zeros(), relative.pose.heading_rad())
    };
    let moved: Vec<(Vec2, f64)> = second
        .detections
        .iter()
        .map(|d| {
            let cov = pose.cov_to_parent(&d.cov_m2);
            (pose.to_parent(&d.position_m), cov.trace() / 2.0)
        })
        .collect();
    // Candidates as (i, j, offset, variance, weight), by offset x.
    let mut c: Vec<(usize, usize, Vec2, f64, f64)> = Vec::new();
    for (i, a) in first.detections.iter().enumerate() {
        for (j, (p, v)) in moved.iter().enumerate() {
            let w = similarity[i * n2 + j];
            if w >= terms.min_appearance {
                c.push((i, j, a.position_m - p, a.cov_m2.trace() / 2.0 + v, w));
            }
        }
    }
    c.sort_by(|x, y| x.2.x.total_cmp(&y.2.x));
    let widest = c.iter().map(|x| x.3).fold(0.0, f64::max);
    let mut votes = vec![0.0; n1 * n2];
    for (u, &(i, j, o, v, _)) in c.iter().enumerate() {
        // Candidates further apart in x than 5 sigma add nothing.
        let reach = 5.0 * (v + widest).sqrt();
        let mut sum = 0.0;
        let mut add = |&(k, b, q, w_var, w): &(usize, usize, Vec2, f64, f64)| {
            if k != i && b != j {
                sum += w * (-(o - q).norm_squared() / (2.0 * (v + w_var))).exp();
            }
        };
        c[u + 1..]
            .iter()
            .take_while(|x| x.2.x - o.x <= reach)
            .for_each(&mut add);
        c[..u]
            .iter()
            .rev()
            .take_while(|x| o.x - x.2.x <= reach)
            .for_each(&mut add);
        votes[i * n2 + j] = sum;
    }
    votes
}

/// The appearance part of one pair's features, after the two given ones.
fn appearance_pair(a: &Detection, b: &Detection, d2_over_gate: f64, log_s: f64) -> [f32; 11] {
    let (x, y) = (&a.appearance, &b.appearance);
    let colour = |k: usize| (x.colour_rgb[k] - y.colour_rgb[k]).abs();
    let chroma = |c: &[f64; 3]| {
        let mean = (c[0] + c[1] + c[2]) / 3.0;
        c.map(|v| v / mean.max(0.05))
    };
    let (cx, cy) = (chroma(&x.colour_rgb), chroma(&y.colour_rgb));
    let chroma_diff = (0..3).map(|k| (cx[k] - cy[k]).powi(2)).sum::<f64>().sqrt();
    let rel = |p: f64, q: f64| (p - q).abs() / (0.5 * (p + q)).max(0.1);
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    [
        d2_over_gate,
        log_s,
        flag(x.class == y.class),
        flag(x.class.confusable() == y.class || y.class.confusable() == x.class),
        colour(0),
        colour(1),
        colour(2),
        chroma_diff.min(3.0),
        rel(x.length_m, y.length_m),
        rel(x.width_m, y.width_m),
        rel(x.height_m, y.height_m),
    ]
    .map(|v| v as f32)
}

/// Range (in units of the default camera range) and bearing (cos, sin)
/// of a point in a body frame; the bearing of the origin is (1, 0).
fn range_bearing(p: &Vec2) -> [f32; 3] {
    let r = p.norm();
    let (c, s) = if r > 1e-9 {
        (p.x / r, p.y / r)
    } else {
        (1.0, 0.0)
    };
    [(r / RANGE_SCALE_M) as f32, c as f32, s as f32]
}

fn class_one_hot(d: &Detection) -> [f32; 7] {
    let mut f = [0f32; 7];
    if let Some(k) = ObjectClass::ALL
        .iter()
        .position(|&c| c == d.appearance.class)
    {
        f[k] = 1.0;
    }
    f
}

#[cfg(test)]
mod tests {
    use super::*;

    /// True pairs share one offset, so they vote for each other: with the
    /// GPS 2 m off (positions) and without positions at all (only the
    /// heading), every true pair gets more votes than any wrong pair of its
    /// row, among look-alikes.
    #[test]
    fn true_pairs_get_the_offset_votes() {
        use crate::matching::gps_relative_pose;
        use crate::matching::likelihood::LikelihoodTerms;
        use crate::matching::testkit::{self, GPS, Side};
        let world = testkit::world_objects();
        let all: Vec<usize> = (0..world.len()).collect();
        let a = Side::of(testkit::POSE_A, &world, &all, GPS);
        let mut b = Side::of(testkit::POSE_B, &world, &[5, 2, 7, 0, 3, 6, 1, 4], GPS);
        b.pose = Pose2::new(
            b.pose.position_m() + Vec2::new(2.0, -0.5),
            b.pose.heading_rad(),
        );
        let (va, vb) = (a.view(), b.view());
        let similarity: Vec<f64> = a
            .detections
            .iter()
            .flat_map(|x| {
                b.detections.iter().map(|y| {
                    crate::matching::learning_free::appearance_similarity(
                        &x.appearance,
                        &y.appearance,
                    )
                })
            })
            .collect();
        let n2 = b.detections.len();
        for position in [true, false] {
            let terms = LikelihoodTerms {
                position,
                ..LikelihoodTerms::full(9.21)
            };
            let votes = offset_votes(&va, &vb, &gps_relative_pose(&va, &vb), &terms, &similarity);
            for (i, object) in a.objects.iter().enumerate() {
                let j = b.objects.iter().position(|o| o == object).unwrap();
                let truth = votes[i * n2 + j];
                let best_wrong = (0..n2)
                    .filter(|&k| k != j)
                    .map(|k| votes[i * n2 + k])
                    .fold(0.0, f64::max);
                assert!(
                    truth > best_wrong,
                    "position {position}, row {i}: {truth} vs {best_wrong}"
                );
            }
        }
    }

    /// A network that reads appearance vectors gets each node's vector
    /// after class, colour and size; one that does not reads none of it.
    #[test]
    fn node_attributes_carry_the_appearance_vector_after_class_colour_and_size() {
        use crate::matching::testkit;
        let objects = testkit::world_objects();
        let mut dets =
            testkit::Side::of(testkit::POSE_A, &objects[..2], &[0, 1], testkit::EXACT).detections;
        let law = crate::sensor::DescriptorLaw {
            slope: 1.0,
            neutral: 0.5,
        };
        for (k, d) in dets.iter_mut().enumerate() {
            d.appearance.descriptor = Some(crate::sensor::Descriptor {
                values: vec![k as f32, 2.0, 3.0].into(),
                law,
            });
        }
        let without = node_attributes(&dets, crate::sensor::AppearanceWidth::NONE);
        assert_eq!(without.len(), 2 * NODE_FEATURES);
        let with = node_attributes(&dets, crate::sensor::AppearanceWidth::new(3));
        assert_eq!(with.len(), 2 * (NODE_FEATURES + 3));
        for k in 0..2 {
            let row = &with[k * (NODE_FEATURES + 3)..(k + 1) * (NODE_FEATURES + 3)];
            assert_eq!(
                row[..NODE_FEATURES],
                without[k * NODE_FEATURES..(k + 1) * NODE_FEATURES]
            );
            assert_eq!(row[NODE_FEATURES..], [k as f32, 2.0, 3.0]);
        }
        assert_eq!(
            check_appearance(
                crate::sensor::AppearanceWidth::NONE,
                crate::sensor::AppearanceWidth::NONE
            ),
            None
        );
        assert_eq!(
            check_appearance(
                crate::sensor::AppearanceWidth::new(3),
                crate::sensor::AppearanceWidth::new(3)
            ),
            None
        );
        assert!(
            check_appearance(
                crate::sensor::AppearanceWidth::new(3),
                crate::sensor::AppearanceWidth::new(4)
            )
            .unwrap()
            .contains("4 wide")
        );
        assert!(
            check_appearance(
                crate::sensor::AppearanceWidth::new(3),
                crate::sensor::AppearanceWidth::NONE
            )
            .unwrap()
            .contains("has none")
        );
    }
}
