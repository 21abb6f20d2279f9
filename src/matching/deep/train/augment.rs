//! Training pairs drawn anew each epoch (`[train] node_dropout`,
//! `position_jitter_m`): each side loses some of its detections and the
//! rest move by a little Gaussian noise, the scene graph is made again
//! over the moved positions, and the true pairs follow. A network that
//! would otherwise learn the training recordings' exact layouts sees a
//! slightly different one every epoch; validation and test pairs are
//! never touched.

use rand::Rng;
use rand_distr::{Distribution, Normal};

use super::examples::{Example, OwnedView};
use crate::geometry::Vec2;
use crate::graph::SceneGraph;

/// How each training pair is perturbed per epoch (all zero: it is not).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Augment {
    /// Each detection is left out with this probability.
    pub node_dropout: f64,
    /// Each kept detection's position moves by this standard deviation
    /// per axis, metres (body frame).
    pub position_jitter_m: f64,
}

impl Augment {
    /// No perturbation.
    pub fn is_off(&self) -> bool {
        self.node_dropout == 0.0 && self.position_jitter_m == 0.0
    }
}

/// `e` perturbed as `a` says, with draws from `rng` (two jitters and one
/// uniform per detection, first side then second, whatever is kept);
/// `None` when a side loses every detection or no true pair survives
/// (the caller keeps the pair as it is).
pub(crate) fn augmented(e: &Example, a: Augment, rng: &mut impl Rng) -> Option<Example> {
    let (first, kept_first) = side(&e.first, a, rng);
    let (second, kept_second) = side(&e.second, a, rng);
    let (first, second) = (first?, second?);
    let true_pairs: Vec<(usize, usize)> = e
        .true_pairs
        .iter()
        .filter_map(|&(x, y)| Some((kept_first[x]?, kept_second[y]?)))
        .collect();
    (!true_pairs.is_empty()).then_some(Example {
        first,
        second,
        true_pairs,
    })
}

/// One side perturbed, and where each of its detections went (`None`:
/// left out).
fn side(v: &OwnedView, a: Augment, rng: &mut impl Rng) -> (Option<OwnedView>, Vec<Option<usize>>) {
    let jitter = Normal::new(0.0, a.position_jitter_m).expect("a finite, non-negative sigma");
    let mut kept = vec![None; v.detections.len()];
    let mut detections = Vec::with_capacity(v.detections.len());
    for (i, d) in v.detections.iter().enumerate() {
        let dropped = rng.random::<f64>() < a.node_dropout;
        let offset = Vec2::new(jitter.sample(rng), jitter.sample(rng));
        if !dropped {
            let mut d = d.clone();
            d.position_m += offset;
            kept[i] = Some(detections.len());
            detections.push(d);
        }
    }
    if detections.is_empty() {
        return (None, kept);
    }
    let positions: Vec<Vec2> = detections.iter().map(|d| d.position_m).collect();
    let Ok(graph) = SceneGraph::delaunay(&positions) else {
        return (None, kept);
    };
    let view = OwnedView {
        detections,
        graph,
        pose_reported: v.pose_reported,
        pose_noise: v.pose_noise,
    };
    (Some(view), kept)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::testkit;
    use crate::rng::{self, Purpose};

    fn example() -> Example {
        let objects = testkit::world_objects();
        let all = [0, 1, 2, 3, 4, 5];
        let a = testkit::Side::of(testkit::POSE_A, &objects[..6], &all, testkit::EXACT);
        let b = testkit::Side::of(testkit::POSE_B, &objects[..6], &all, testkit::EXACT);
        let truth: Vec<_> = (0..6)
            .map(|k| crate::matching::Correspondence::with_probability(k, k, 1.0))
            .collect();
        super::super::examples::example(&a.view(), &b.view(), &truth).unwrap()
    }

    fn draw(e: &Example, a: Augment, k: u64) -> Option<Example> {
        augmented(e, a, &mut rng::stream(1, Purpose::Training, &[k]))
    }

    /// Left-out detections take their true pairs with them and the kept
    /// ones keep their partners (the same world point from both poses);
    /// the graph is Delaunay over what is kept; the same stream gives the
    /// same pair; all zero leaves the pair as it was.
    #[test]
    fn an_augmented_pair_keeps_the_partners_of_what_it_keeps() {
        let e = example();
        let (pa, pb) = (
            testkit::pose(testkit::POSE_A),
            testkit::pose(testkit::POSE_B),
        );
        let drop = Augment {
            node_dropout: 0.3,
            position_jitter_m: 0.0,
        };
        let mut smaller = 0;
        for k in 0..40 {
            let Some(p) = draw(&e, drop, k) else { continue };
            assert_eq!(Some(&p), draw(&e, drop, k).as_ref());
            for &(x, y) in &p.true_pairs {
                let wa = pa.to_parent(&p.first.detections[x].position_m);
                let wb = pb.to_parent(&p.second.detections[y].position_m);
                assert!((wa - wb).norm() < 1e-9, "pair ({x}, {y}) is two objects");
            }
            for view in [&p.first, &p.second] {
                let at: Vec<Vec2> = view.detections.iter().map(|d| d.position_m).collect();
                assert_eq!(view.graph, SceneGraph::delaunay(&at).unwrap());
            }
            smaller += usize::from(p.true_pairs.len() < 6);
        }
        assert!(smaller > 10, "{smaller} of 40 pairs lost a true pair");
        assert_eq!(draw(&e, Augment::default(), 0).as_ref(), Some(&e));
    }

    /// Jitter alone keeps every detection and pair and moves positions by
    /// about its sigma per axis.
    #[test]
    fn jitter_moves_each_detection_by_about_its_sigma() {
        let e = example();
        let a = Augment {
            node_dropout: 0.0,
            position_jitter_m: 0.5,
        };
        let mut squares = Vec::new();
        for k in 0..50 {
            let p = draw(&e, a, k).unwrap();
            assert_eq!(p.true_pairs, e.true_pairs);
            for (moved, was) in p.first.detections.iter().zip(&e.first.detections) {
                let d = moved.position_m - was.position_m;
                squares.extend([d.x * d.x, d.y * d.y]);
            }
        }
        let sigma = (squares.iter().sum::<f64>() / squares.len() as f64).sqrt();
        assert!((sigma - 0.5).abs() < 0.05, "sigma {sigma}");
    }
}
