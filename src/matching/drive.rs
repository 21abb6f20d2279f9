//! How every matcher is driven ([`Driven`], what [`super::build`]
//! returns):
//!
//! - **Canonical node order.** Both vehicles' nodes are put in an order
//!   that depends only on what each detection says (its position, then its
//!   appearance and covariance), the method runs on that order, and its
//!   answer is mapped back. So a method's answer never depends on the
//!   order in which a vehicle lists its detections: permuting them permutes
//!   the matches and changes nothing else, bit for bit, whatever the
//!   method does inside (floating-point sums, ties, MC-dropout masks drawn
//!   per node position).
//! - **Match, align, re-match.** The relative pose error of two GPS
//!   receivers is shared by every pair of their detections, which costs
//!   that score each pair on its own cannot use. For a method that uses
//!   positions, each round aligns the two vehicles on the matches of the
//!   previous one ([`crate::fusion::align`]: weighted rigid alignment with
//!   the GPS pose as its prior, Huber-weighted) and matches again with the
//!   refined pose and its posterior covariance; it stops early when the
//!   matches no longer change or too few pairs support an alignment.

use std::cmp::Ordering;

use super::deep::decision::MatchDistribution;
use super::{Correspondence, Identification, MatchView, Matcher, Method};
use crate::fusion::{Measurement, PoseEstimate, align};
use crate::graph::SceneGraph;
use crate::sensor::Detection;

/// Fewer matched pairs than this leave the relative pose as it was: two
/// points fix a rigid pose, a third checks it.
pub const REMATCH_MIN_MATCHES: usize = 3;

/// A matcher in canonical node order, with `rematch` rounds of
/// match-align-rematch.
pub struct Driven {
    inner: Box<dyn Matcher>,
    rematch: usize,
}

impl Driven {
    pub fn new(inner: Box<dyn Matcher>, rematch: usize) -> Self {
        Self { inner, rematch }
    }
}

impl Matcher for Driven {
    fn method(&self) -> Method {
        self.inner.method()
    }

    fn network_macs(&self) -> u64 {
        self.inner.network_macs()
    }

    fn uses_positions(&self) -> bool {
        self.inner.uses_positions()
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> Identification {
        let (a, b) = (Canonical::of(first), Canonical::of(second));
        let (va, vb) = (a.view(first), b.view(second));
        let id = self.rematched(&va, &vb, relative);
        let mut matches: Vec<Correspondence> = id
            .matches
            .iter()
            .map(|c| Correspondence {
                a: a.order[c.a],
                b: b.order[c.b],
                ..*c
            })
            .collect();
        matches.sort_by_key(|c| c.a);
        Identification {
            matches,
            distribution: id
                .distribution
                .map(|d| d.relabelled(&a.position(), &b.position())),
        }
    }
}

impl Driven {
    /// The inner method's answer after up to `rematch` rounds of
    /// match-align-rematch.
    fn rematched(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> Identification {
        let mut id = self.inner.identify_with(first, second, relative);
        if !self.inner.uses_positions() {
            return id;
        }
        for _ in 0..self.rematch {
            let pairs: Vec<(Measurement, Measurement)> = id
                .matches
                .iter()
                .map(|c| {
                    let m = |d: &Detection| Measurement {
                        position_m: d.position_m,
                        cov_m2: d.cov_m2,
                    };
                    (m(&first.detections[c.a]), m(&second.detections[c.b]))
                })
                .collect();
            let aligned = align(&pairs, relative, REMATCH_MIN_MATCHES);
            if !aligned.refined {
                break;
            }
            let next = self.inner.identify_with(first, second, &aligned.estimate);
            let unchanged = same_pairs(&next.matches, &id.matches);
            id = next;
            if unchanged {
                break;
            }
        }
        id
    }
}

fn same_pairs(x: &[Correspondence], y: &[Correspondence]) -> bool {
    x.len() == y.len() && x.iter().zip(y).all(|(p, q)| (p.a, p.b) == (q.a, q.b))
}

/// One vehicle's detections and graph in canonical order.
struct Canonical {
    /// Canonical node k is the caller's node `order[k]`.
    order: Vec<usize>,
    detections: Vec<Detection>,
    graph: SceneGraph,
}

impl Canonical {
    fn of(view: &MatchView) -> Self {
        let mut order: Vec<usize> = (0..view.detections.len()).collect();
        order.sort_by(|&i, &j| content_order(&view.detections[i], &view.detections[j]));
        Self {
            detections: order.iter().map(|&k| view.detections[k].clone()).collect(),
            graph: view.graph.permuted(&order),
            order,
        }
    }

    fn view<'a>(&'a self, like: &MatchView) -> MatchView<'a> {
        MatchView {
            detections: &self.detections,
            graph: &self.graph,
            ..*like
        }
    }

    /// The canonical position of each of the caller's nodes.
    fn position(&self) -> Vec<usize> {
        let mut p = vec![0; self.order.len()];
        for (k, &i) in self.order.iter().enumerate() {
            p[i] = k;
        }
        p
    }
}

/// A total order on detections by what they say: position, then
/// appearance, then covariance (two detections equal in all of these are
/// interchangeable to every method).
fn content_order(x: &Detection, y: &Detection) -> Ordering {
    let key = |d: &Detection| {
        let a = &d.appearance;
        [
            d.position_m.x,
            d.position_m.y,
            a.class as u8 as f64,
            a.colour_rgb[0],
            a.colour_rgb[1],
            a.colour_rgb[2],
            a.length_m,
            a.width_m,
            a.height_m,
            d.cov_m2[(0, 0)],
            d.cov_m2[(0, 1)],
            d.cov_m2[(1, 1)],
        ]
    };
    let (kx, ky) = (key(x), key(y));
    kx.iter()
        .zip(&ky)
        .map(|(p, q)| p.total_cmp(q))
        .find(|o| o.is_ne())
        .unwrap_or(Ordering::Equal)
}

impl MatchDistribution {
    /// The same distribution over the caller's node indices: `row_at[i]`
    /// is the row of the caller's node i in `self` (likewise columns).
    pub fn relabelled(&self, row_at: &[usize], col_at: &[usize]) -> MatchDistribution {
        let (n1, n2) = (self.n1, self.n2);
        let (row_of, col_of) = (inverse(row_at), inverse(col_at));
        let rows = |i: usize| if i == n1 { n1 } else { row_at[i] };
        let cols = |j: usize| if j == n2 { n2 } else { col_at[j] };
        let mut mean = Vec::with_capacity(self.mean.len());
        for i in 0..=n1 {
            for j in 0..=n2 {
                mean.push(self.mean[rows(i) * (n2 + 1) + cols(j)]);
            }
        }
        let mut aleatoric = Vec::with_capacity(self.aleatoric.len());
        for &r in row_at {
            aleatoric.extend(col_at.iter().map(|&c| self.aleatoric[r * n2 + c]));
        }
        let mut assigned: Vec<(usize, usize)> = self
            .assigned
            .iter()
            .map(|&(i, j)| (row_of[i], col_of[j]))
            .collect();
        assigned.sort_unstable();
        MatchDistribution {
            n1,
            n2,
            mean,
            aleatoric,
            assigned,
            decision: self.decision,
            temperature: self.temperature,
            min_probability: self.min_probability,
        }
    }
}

/// The inverse of a permutation.
fn inverse(p: &[usize]) -> Vec<usize> {
    let mut q = vec![0; p.len()];
    for (k, &i) in p.iter().enumerate() {
        q[i] = k;
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Pose2, Vec2};
    use crate::matching::GpsHungarian;
    use crate::matching::testkit::{self, GPS, Side};
    use crate::traffic::ObjectClass;

    /// Three look-alike pedestrians 3 m apart, seen by both vehicles (the
    /// second also sees a fourth, 3 m after the row), and five objects
    /// that look unlike anything else. The second vehicle's GPS is 2 m off
    /// along the row: matched once, each pedestrian pairs with its
    /// neighbour (1 m off) instead of itself (2 m off), as many pairs
    /// either way; aligned on the first matching, where the five distinct
    /// objects outweigh the row, and matched again, every pair is right.
    #[test]
    fn match_align_rematch_recovers_pairs_that_one_pass_misses() {
        let grey = [0.5; 3];
        let mut world: Vec<(Vec2, ObjectClass, [f64; 3])> = (0..4)
            .map(|k| {
                (
                    Vec2::new(20.0 + 3.0 * f64::from(k), 4.0),
                    ObjectClass::Pedestrian,
                    grey,
                )
            })
            .collect();
        world.extend([
            (Vec2::new(12.0, -8.0), ObjectClass::Truck, [0.8, 0.1, 0.1]),
            (Vec2::new(30.0, 14.0), ObjectClass::Bus, [0.9, 0.8, 0.1]),
            (Vec2::new(38.0, -6.0), ObjectClass::Van, [0.1, 0.2, 0.8]),
            (Vec2::new(8.0, 12.0), ObjectClass::Bicycle, [0.1, 0.6, 0.2]),
            (
                Vec2::new(44.0, 8.0),
                ObjectClass::Motorcycle,
                [0.95, 0.95, 0.95],
            ),
        ]);
        let a = Side::of(testkit::POSE_A, &world, &[0, 1, 2, 4, 5, 6, 7, 8], GPS);
        let mut b = Side::of((60.0, 10.0, 3.0), &world, &[0, 1, 2, 3, 4, 5, 6, 7, 8], GPS);
        // The row runs along x; the second vehicle's GPS puts everything it
        // sees 2 m further along it.
        b.pose = Pose2::new(b.pose.position_m() - Vec2::new(2.0, 0.0), 3.0);
        let hungarian = || -> Box<dyn Matcher> {
            Box::new(GpsHungarian {
                gate_chi2: 9.21,
                appearance: true,
                descriptor_weight: 1.0,
            })
        };
        let right = |rematch: usize| {
            let m = Driven::new(hungarian(), rematch)
                .identify(&a.view(), &b.view())
                .matches;
            (testkit::correct(&a, &b, &m), m.len())
        };
        assert_eq!(right(0), (5, 8), "one pass: the three pedestrians shifted");
        assert_eq!(right(2), (8, 8), "aligned and matched again: all right");
        // A method that does not use positions is not re-matched.
        assert!(!crate::matching::Mogm::default().uses_positions());
    }
}
