//! One instance, one method: identify the pair's correspondences, count
//! them against the truth and fuse them with every fusion variant
//! ([`evaluate`]; [`score`] for correspondences decided elsewhere, as a
//! frame's are).

use super::counts::{PairCounts, count_pairs};
use super::estimates::{FusionContext, ObjectEstimate, fuse_for_ego};
use super::{CorrespondenceSource, PairAtLevel};
use crate::fusion::{FusionSettings, FusionVariant};
use crate::matching::{Identification, Method};

/// What one method did on one instance at one pose-noise level.
#[derive(Clone, Debug)]
pub struct MethodEval {
    pub method: Method,
    pub identification: Identification,
    pub counts: PairCounts,
    /// Per configured fusion variant, both vehicles' estimates (the first
    /// vehicle's objects, then the second's).
    pub fused: Vec<(FusionVariant, Vec<ObjectEstimate>)>,
}

/// Identifies `pair`'s correspondences with `source`, counts them and
/// fuses them with every variant of `fusion`.
pub fn evaluate(
    pair: &PairAtLevel,
    source: &CorrespondenceSource,
    fusion: &FusionSettings,
) -> MethodEval {
    score(pair, source.method(), source.identify(pair), fusion)
}

/// Counts `identification`'s correspondences on `pair` and fuses them.
pub(super) fn score(
    pair: &PairAtLevel,
    method: Method,
    identification: Identification,
    fusion: &FusionSettings,
) -> MethodEval {
    let matches = &identification.matches;
    let counts = count_pairs(pair.first.truth, pair.second.truth, matches);
    let ab: Vec<(usize, usize)> = matches.iter().map(|c| (c.a, c.b)).collect();
    let ba: Vec<(usize, usize)> = matches.iter().map(|c| (c.b, c.a)).collect();
    let probability: Vec<f64> = matches.iter().map(|c| c.probability).collect();
    let fused = fusion
        .variants
        .iter()
        .map(|&variant| {
            let ctx = FusionContext::new(variant, fusion);
            let mut est = fuse_for_ego(&pair.first, &pair.second, &ab, &probability, &ctx);
            est.extend(fuse_for_ego(
                &pair.second,
                &pair.first,
                &ba,
                &probability,
                &ctx,
            ));
            (variant, est)
        })
        .collect();
    MethodEval {
        method,
        identification,
        counts,
        fused,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluate::Side;
    use crate::evaluate::testkit::{Fixed, corr, exact_view, graph, sensed, view_at};
    use crate::geometry::{Pose2, Vec2};
    use crate::matching::{Correspondence, MultiVehicle};
    use crate::sensor::{Observation, ObservationTruth, PoseNoiseLabel, PoseNoiseLevel};

    /// The same counts and, per fusion variant, the same estimates of the
    /// same objects (in any order).
    fn assert_same_evaluation(x: &MethodEval, y: &MethodEval) {
        let method = x.method;
        assert_eq!(x.counts, y.counts, "{method:?}");
        assert!(x.counts.identified > 0);
        for ((v, ex), (w, ey)) in x.fused.iter().zip(&y.fused) {
            assert_eq!(v, w);
            let key = |e: &ObjectEstimate| (e.ego_id.clone(), e.object_id.clone());
            let (mut ex, mut ey) = (ex.clone(), ey.clone());
            ex.sort_by_key(key);
            ey.sort_by_key(key);
            assert_eq!(ex.len(), ey.len());
            for (p, q) in ex.iter().zip(&ey) {
                assert_eq!(
                    (key(p), p.matched, p.match_correct),
                    (key(q), q.matched, q.match_correct)
                );
                assert!((p.fused_m - q.fused_m).norm() < 1e-9, "{method:?} {v:?}");
                assert!((p.single_m - q.single_m).norm() < 1e-12);
            }
        }
    }

    /// A learning-free method as the pipeline builds it (canonical order,
    /// two rounds of match-align-rematch).
    fn built(method: Method) -> CorrespondenceSource {
        let settings = crate::matching::MatchingSettings {
            methods: vec![],
            baselines: crate::matching::BaselineChoice::APriori,
            gate_chi2: 9.21,
            models_dir: std::path::PathBuf::new(),
            mc_samples: 20,
            dropout_masks: crate::matching::deep::arch::MaskChoice::AsTrained,
            mc_dropout: None,
            lambda: crate::matching::LambdaChoice::Fixed(0.7),
            decision: crate::matching::DecisionChoice::Validated,
            uncertainty: crate::matching::deep::decision::UncertaintyKind::Total,
            sender_as_node: false,
            multi_vehicle: MultiVehicle::Pairwise,
            rematch: 2,
            indicators: crate::matching::deep::arch::IndicatorScope::PerSample,
        };
        CorrespondenceSource::Matcher(
            crate::matching::build(method, &settings, (None, None), 1).unwrap(),
        )
    }

    /// Permuting one vehicle's detections (with its truth and graph)
    /// changes no count and no estimate of any method, fusion variant
    /// included: under GPS error, with look-alikes and objects only one
    /// vehicle sees, and match-align-rematch on.
    #[test]
    fn permuting_one_vehicles_detections_changes_no_count_and_no_estimate() {
        let pa = Pose2::new(Vec2::new(0.0, 0.0), 0.3);
        let pb = Pose2::new(Vec2::new(40.0, 12.0), 2.6);
        let mut objects: Vec<(Option<&str>, Vec2)> = ["p", "q", "r", "s", "t", "u", "v"]
            .iter()
            .enumerate()
            .map(|(k, id)| {
                (
                    Some(*id),
                    Vec2::new(12.0 + 4.0 * k as f64, (k as f64 * 1.7).sin() * 6.0),
                )
            })
            .collect();
        let (oa, ta) = sensed("a", pa, &objects[..6]);
        objects.push((None, Vec2::new(25.0, 9.0)));
        let (ob, tb) = sensed("b", pb, &objects[1..]);
        let order = [3, 0, 6, 1, 5, 2, 4];
        let (ob2, tb2) = (
            Observation {
                ego_id: ob.ego_id.clone(),
                detections: order.iter().map(|&k| ob.detections[k].clone()).collect(),
            },
            ObservationTruth {
                ego_pose: tb.ego_pose,
                detections: order.iter().map(|&k| tb.detections[k].clone()).collect(),
            },
        );
        let (ga, gb, gb2) = (graph(&oa), graph(&ob), graph(&ob2));
        let gps =
            |p: Pose2, dx: f64| Pose2::new(p.position_m() + Vec2::new(dx, -0.7), p.heading_rad());
        let level = exact_view(&oa, &ga, pa).pose_noise;
        let first = Side {
            view: exact_view(&oa, &ga, gps(pa, 0.4)),
            obs: &oa,
            truth: &ta,
        };
        let second = |obs, truth, graph| Side {
            view: exact_view(obs, graph, gps(pb, -1.1)),
            obs,
            truth,
        };
        let pair = |second| PairAtLevel {
            instance: 0,
            first,
            second,
            level,
        };
        let (before, after) = (pair(second(&ob, &tb, &gb)), pair(second(&ob2, &tb2, &gb2)));
        let fusion = FusionSettings {
            variants: vec![FusionVariant::Paper, FusionVariant::Aligned],
            align_min_matches: 3,
        };
        for source in [
            built(Method::GpsAppHungarian),
            built(Method::Mogm),
            CorrespondenceSource::Oracle,
        ] {
            let (x, y) = (
                evaluate(&before, &source, &fusion),
                evaluate(&after, &source, &fusion),
            );
            assert_same_evaluation(&x, &y);
        }
    }

    #[test]
    fn zero_noise_gives_zero_error_single_and_fused_and_the_oracle_is_perfect() {
        // Two egos with exact measurements and exact poses.
        let pa = Pose2::new(Vec2::new(0.0, 0.0), 0.3);
        let pb = Pose2::new(Vec2::new(30.0, 10.0), 2.0);
        let objects = [
            (Some("x"), Vec2::new(15.0, 8.0)),
            (Some("y"), Vec2::new(20.0, -2.0)),
            (Some("z"), Vec2::new(10.0, 15.0)),
        ];
        let (oa, ta) = sensed("a", pa, &objects);
        let (ob, tb) = sensed("b", pb, &objects);
        let (ga, gb) = (graph(&oa), graph(&ob));
        let level = PoseNoiseLevel {
            label: PoseNoiseLabel::NONE,
            position_sigma_m: 0.0,
            heading_sigma_rad: 0.0,
            correlation_s: None,
        };
        let pair = PairAtLevel {
            instance: 0,
            first: Side {
                view: view_at(&oa, &ga, pa, level),
                obs: &oa,
                truth: &ta,
            },
            second: Side {
                view: view_at(&ob, &gb, pb, level),
                obs: &ob,
                truth: &tb,
            },
            level,
        };
        let fusion = FusionSettings {
            variants: vec![FusionVariant::Paper, FusionVariant::Aligned],
            align_min_matches: 3,
        };
        let e = evaluate(&pair, &CorrespondenceSource::Oracle, &fusion);
        assert_eq!(
            (e.counts.correct, e.counts.identified, e.counts.ground_truth),
            (3, 3, 3)
        );
        assert_eq!(e.fused.len(), 2);
        for (_, est) in &e.fused {
            assert_eq!(est.len(), 6);
            for x in est {
                assert!(
                    x.single_error_m() < 1e-9 && x.fused_error_m() < 1e-9,
                    "{x:?}"
                );
                assert!(x.match_correct);
            }
        }
    }

    proptest::proptest! {
        /// Whatever a method pairs, the object set of the displacement
        /// error (every real object an ego detects) and its single-vehicle
        /// estimates are the same; unmatched objects keep their single
        /// estimate as the fused one.
        #[test]
        fn the_object_set_does_not_depend_on_the_method(
            seen_a in proptest::collection::vec(proptest::bool::ANY, 6),
            seen_b in proptest::collection::vec(proptest::bool::ANY, 6),
            shuffle in proptest::collection::vec(0usize..100, 13),
        ) {
            let world: Vec<(Option<&str>, Vec2)> = ["o0", "o1", "o2", "o3", "o4", "o5"]
                .iter()
                .enumerate()
                .map(|(k, id)| (Some(*id), Vec2::new(10.0 + 4.0 * k as f64, (k as f64 * 1.7).sin() * 9.0)))
                .chain([(None, Vec2::new(25.0, 30.0))]) // a false positive
                .collect();
            let pick = |seen: &[bool]| -> Vec<(Option<&str>, Vec2)> {
                world.iter().enumerate().filter(|(k, _)| *k == 6 || seen[*k]).map(|(_, o)| *o).collect()
            };
            let (pa, pb) = (Pose2::new(Vec2::zeros(), 0.2), Pose2::new(Vec2::new(50.0, 5.0), 2.9));
            let (oa, ta) = sensed("a", pa, &pick(&seen_a));
            let (ob, tb) = sensed("b", pb, &pick(&seen_b));
            let (ga, gb) = (graph(&oa), graph(&ob));
            let pair = PairAtLevel {
                instance: 0,
                first: Side { view: exact_view(&oa, &ga, pa), obs: &oa, truth: &ta },
                second: Side { view: exact_view(&ob, &gb, pb), obs: &ob, truth: &tb },
                level: exact_view(&oa, &ga, pa).pose_noise,
            };
            // A random one-to-one matching, right or wrong.
            let (n, m) = (oa.detections.len(), ob.detections.len());
            let mut cols: Vec<usize> = (0..m).collect();
            for (k, &r) in shuffle.iter().enumerate().take(m) {
                cols.swap(k, r % m);
            }
            let random: Vec<Correspondence> = (0..n.min(m))
                .filter(|i| shuffle[i + 6] % 3 != 0)
                .map(|i| corr(i, cols[i]))
                .collect();
            let fusion = FusionSettings {
                variants: vec![FusionVariant::Paper, FusionVariant::Aligned],
                align_min_matches: 2,
            };
            let sources = [CorrespondenceSource::Oracle, CorrespondenceSource::Matcher(Box::new(Fixed(vec![]))), CorrespondenceSource::Matcher(Box::new(Fixed(random)))];
            let sets: Vec<Vec<(String, String, bool, Vec2)>> = sources
                .iter()
                .flat_map(|s| evaluate(&pair, s, &fusion).fused)
                .map(|(_, est)| {
                    for e in &est {
                        if !e.matched {
                            proptest::prop_assert_eq!(e.fused_m, e.single_m);
                        }
                    }
                    Ok(est.into_iter().map(|e| (e.ego_id, e.object_id, e.covisible, e.single_m)).collect())
                })
                .collect::<Result<_, _>>()?;
            let real = |seen: &[bool]| seen.iter().filter(|s| **s).count();
            proptest::prop_assert_eq!(sets[0].len(), real(&seen_a) + real(&seen_b));
            for s in &sets[1..] {
                proptest::prop_assert_eq!(s, &sets[0]);
            }
        }
    }
}
