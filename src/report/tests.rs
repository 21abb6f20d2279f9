//! The report's tests: pooling, aggregation, intervals, calibration.

use super::stats::t_975;
use super::*;
use crate::evaluate::{ObjectEstimate, PairCounts};
use crate::fusion::FusionVariant;
use crate::matching::Method;
use crate::sensor::PoseNoiseLabel;

fn row(method: Method, f1: f64, de: f64, n_instances: u64) -> RunRow {
    let key = RowKey {
        method,
        pose_noise: PoseNoiseLabel::GPS,
        fusion: FusionVariant::Paper,
    };
    RunRow {
        key,
        n_instances,
        values: Metric::ALL.map(|m| match m {
            Metric::Precision | Metric::Recall | Metric::F1 => f1,
            Metric::DeSingle | Metric::DeSingleCovisible => de,
            Metric::DeFused | Metric::DeFusedCovisible => de / 2.0,
            Metric::DeFusedMatched => de / 4.0,
        }),
    }
}

#[test]
fn aggregation_pools_runs_per_key_in_first_seen_order() {
    let (ours, oracle) = (Method::Ours, Method::Oracle);
    let runs = vec![
        vec![row(ours, 0.8, 2.0, 10), row(oracle, 1.0, 2.0, 10)],
        vec![row(ours, 0.6, 4.0, 10), row(oracle, 1.0, f64::NAN, 10)],
        vec![row(ours, 0.7, 3.0, 10)],
        // A run without instances: counted apart, no metric.
        vec![row(ours, f64::NAN, f64::NAN, 0)],
    ];
    let agg = aggregate(&runs);
    assert_eq!(agg.len(), 2);
    let o = &agg[0];
    assert_eq!(
        (
            o.key.method,
            o.n_runs,
            o.n_runs_without_instances,
            o.n_instances
        ),
        (ours, 3, 1, 30)
    );
    // 0.8, 0.6, 0.7: mean 0.7, s = 0.1, half-width t(2) 0.1 / sqrt(3).
    let f1 = o.get(Metric::F1);
    assert!((f1.0 - 0.7).abs() < 1e-12);
    assert!(
        (f1.1 - 4.302652730 * 0.1 / 3f64.sqrt()).abs() < 1e-7,
        "{f1:?}"
    );
    assert!((o.get(Metric::DeFused).0 - 1.5).abs() < 1e-12);
    // The oracle: a NaN error is left out of its mean.
    let r = &agg[1];
    assert_eq!((r.key.method, r.n_runs), (oracle, 2));
    assert_eq!(r.get(Metric::DeSingle).0, 2.0);
    assert!(r.get(Metric::DeSingle).1.is_nan());
    assert_eq!(r.get(Metric::F1), (1.0, 0.0));
    // The table names each column once, in the file's order.
    let t = aggregate_table(&agg);
    let names: Vec<&str> = t.columns.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        &names[..9],
        [
            "method",
            "pose_noise",
            "fusion",
            "n_runs",
            "n_runs_without_instances",
            "n_instances",
            "precision",
            "precision_ci95",
            "n_runs_precision"
        ]
    );
    assert_eq!(names.len(), 6 + 2 * Metric::ALL.len() + 1);
}

#[test]
fn summary_pools_counts_and_means_errors_over_objects() {
    use crate::geometry::Vec2;
    let key = RowKey {
        method: Method::Ours,
        pose_noise: PoseNoiseLabel::GPS,
        fusion: FusionVariant::Paper,
    };
    let est = |single: f64, fused: f64| ObjectEstimate {
        ego_id: "a".into(),
        peer_id: "b".into(),
        object_id: "x".into(),
        covisible: fused < 1.0,
        matched: fused > 0.0,
        match_correct: true,
        pose_refined: false,
        truth_m: Vec2::zeros(),
        single_m: Vec2::new(single, 0.0),
        fused_m: Vec2::new(0.0, fused),
        fused_nees: fused * fused,
        fused_nees_hedged: fused * fused,
    };
    let mut s = Summary::default();
    let counts = |identified, correct, ground_truth| PairCounts {
        identified,
        correct,
        ground_truth,
    };
    s.record(key, counts(2, 1, 4), &[est(1.0, 0.5)]);
    s.record(key, counts(2, 2, 2), &[est(2.0, 1.0), est(3.0, 0.0)]);
    let rows = s.rows();
    assert_eq!(rows.len(), 1);
    let r = &rows[0];
    assert_eq!((r.n_instances, r.n_objects, r.n_matched), (2, 3, 2));
    assert_eq!((r.precision, r.recall), (0.75, 0.5));
    assert_eq!((r.de_single_m, r.de_fused_m), (2.0, 0.5));
    // Covisible: fused errors 0.5 and 0 (singles 1 and 3); matched:
    // fused 0.5 and 1 (singles 1 and 2).
    assert_eq!((r.de_single_covis_m, r.de_fused_covis_m), (2.0, 0.25));
    assert_eq!((r.de_single_matched_m, r.de_fused_matched_m), (1.5, 0.75));
}

#[test]
fn t_quantiles_match_the_tables() {
    // Two-sided 95% points of Student's t (standard tables, 9 digits).
    for (dof, t) in [
        (1, 12.706204736),
        (3, 3.182446305),
        (9, 2.262157163),
        (30, 2.042272456),
        (60, 2.000297822),
        (100, 1.983971519),
        (1000, 1.962339081),
    ] {
        assert!((t_975(dof) - t).abs() < 1e-6, "dof {dof}: {}", t_975(dof));
    }
    assert!(t_975(0).is_nan());
}

#[test]
fn intervals_of_known_samples() {
    // 1..5: mean 3, s = sqrt(2.5), half-width t(4) s / sqrt(5).
    let (m, ci) = mean_ci95(&[1.0, 2.0, 3.0, 4.0, 5.0]);
    assert_eq!(m, 3.0);
    assert!(
        (ci - 2.776445105 * 2.5f64.sqrt() / 5f64.sqrt()).abs() < 1e-8,
        "{ci}"
    );
    // Non-finite values are left out; one value has no interval.
    let (m, ci) = mean_ci95(&[2.0, f64::NAN, 4.0]);
    assert_eq!(m, 3.0);
    assert!((ci - 12.706204736 * 1.0).abs() < 1e-6, "{ci}");
    let (m, ci) = mean_ci95(&[7.0]);
    assert_eq!(m, 7.0);
    assert!(ci.is_nan());
    assert!(mean_ci95(&[]).0.is_nan());
    // A constant sample has a zero-width interval.
    assert_eq!(mean_ci95(&[0.5; 4]), (0.5, 0.0));
}

fn scored(probability: f64, uncertainty: f64, correct: bool) -> ScoredPair {
    ScoredPair {
        probability,
        uncertainty,
        correct,
    }
}

/// Six pairs in three bins: 0.95 (2 of 3 right), 0.55 (1 of 2), 0.15
/// (0 of 1). By hand: ECE = 3/6 |2/3 - 0.95| + 2/6 |0.5 - 0.55| +
/// 1/6 |0 - 0.15| = 0.183333; Brier = (2 (0.05)^2 + 0.95^2 + 0.45^2 +
/// 0.55^2 + 0.15^2) / 6 = 0.239167.
#[test]
fn calibration_of_a_hand_made_set() {
    let pairs = [
        scored(0.95, 0.1, true),
        scored(0.95, 0.2, true),
        scored(0.95, 0.5, false),
        scored(0.55, 0.6, true),
        scored(0.55, 0.7, false),
        scored(0.15, 0.6, false),
    ];
    assert!((expected_calibration_error(&pairs) - 0.183_333_333).abs() < 1e-9);
    assert!((brier_score(&pairs) - 0.239_166_667).abs() < 1e-9);
    let bins = reliability(&pairs);
    assert_eq!(bins.len(), 3);
    assert_eq!((bins[2].count, bins[2].accuracy), (3, 2.0 / 3.0));
    // Wrong pairs' uncertainties 0.5, 0.7, 0.6 against right 0.1, 0.2,
    // 0.6: 2 + 3 + 2.5 of 9 pairs ordered right.
    assert!((uncertainty_auroc(&pairs) - 7.5 / 9.0).abs() < 1e-12);
    // A perfectly calibrated set.
    let fair: Vec<ScoredPair> = (0..10).map(|k| scored(0.7, 0.3, k < 7)).collect();
    assert!(expected_calibration_error(&fair).abs() < 1e-12);
    assert!(uncertainty_auroc(&fair[..7]).is_nan());
    assert!(expected_calibration_error(&[]).is_nan());
}

/// Pairing removes what the runs share: a method 0.01 better on every
/// run of very different runs has an interval above 0 (its intervals
/// over runs, unpaired, overlap widely); differences that go both ways
/// cover 0; the same inputs give the same interval.
#[test]
fn paired_bootstrap_sees_a_small_consistent_difference_and_not_a_random_one() {
    let b: Vec<f64> = (0..10).map(|k| 0.5 + 0.04 * f64::from(k)).collect();
    let a: Vec<f64> = b.iter().map(|x| x + 0.01).collect();
    let (ma, ca) = mean_ci95(&a);
    let (mb, cb) = mean_ci95(&b);
    assert!(ma - ca < mb + cb, "the unpaired intervals overlap");
    let d = paired_bootstrap(&a, &b, 1);
    assert_eq!(d.n, 10);
    assert!((d.mean - 0.01).abs() < 1e-12);
    assert!(d.lo > 0.0 && d.hi < 0.0101, "{d:?}");
    assert_eq!(d.sign(), Some(true));
    assert_eq!(paired_bootstrap(&b, &a, 1).sign(), Some(false));
    let noisy: Vec<f64> = b
        .iter()
        .enumerate()
        .map(|(k, x)| x + if k % 2 == 0 { 0.05 } else { -0.05 })
        .collect();
    let d = paired_bootstrap(&noisy, &b, 1);
    assert!(d.lo < 0.0 && d.hi > 0.0, "{d:?}");
    assert_eq!(d.sign(), None);
    assert_eq!(paired_bootstrap(&noisy, &b, 1), d);
    // A run undefined on either side is left out; one run: no interval.
    let d = paired_bootstrap(&[0.5, f64::NAN], &[0.4, 0.3], 1);
    assert_eq!(d.n, 1);
    assert!(d.lo.is_nan() && d.sign().is_none());
}
