//! A run's rows: the summary pooled over its instances (one row per
//! method, pose-noise level and fusion variant, written through its one
//! column table, [`summary_table`]) and the per-object rows.

use std::collections::BTreeMap;
use std::time::Duration;

use super::batch::Metric;
use super::table::Table;
use crate::evaluate::{Consistency, ObjectEstimate, PairCounts, ViewEstimate};
use crate::fusion::FusionVariant;
use crate::matching::Method;
use crate::sensor::PoseNoiseLabel;

/// The key of a summary row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct RowKey {
    pub method: Method,
    pub pose_noise: PoseNoiseLabel,
    pub fusion: FusionVariant,
}

/// Sums of displacement errors over a set of objects.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ErrorSums {
    pub n: usize,
    pub single_m: f64,
    pub fused_m: f64,
    /// Sum of the fused estimates' NEES (NaN once one is unknown).
    pub fused_nees: f64,
    /// Sum of their NEES against the claim hedged by the match.
    pub fused_nees_hedged: f64,
}

impl ErrorSums {
    pub fn add(&mut self, e: &ObjectEstimate) {
        self.n += 1;
        self.single_m += e.single_error_m();
        self.fused_m += e.fused_error_m();
        self.fused_nees += e.fused_nees;
        self.fused_nees_hedged += e.fused_nees_hedged;
    }

    /// Mean NEES of the fused estimates (2 when the claimed covariances
    /// are honest); NaN for an empty set.
    pub fn mean_fused_nees(&self) -> f64 {
        self.mean(self.fused_nees)
    }

    /// Mean NEES against the claim hedged by the match
    /// ([`crate::fusion::hedged_covariance`]); NaN for an empty set.
    pub fn mean_fused_nees_hedged(&self) -> f64 {
        self.mean(self.fused_nees_hedged)
    }

    /// Mean single-vehicle error; NaN for an empty set.
    pub fn mean_single_m(&self) -> f64 {
        self.mean(self.single_m)
    }

    /// Mean fused error; NaN for an empty set.
    pub fn mean_fused_m(&self) -> f64 {
        self.mean(self.fused_m)
    }

    fn mean(&self, sum: f64) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            sum / self.n as f64
        }
    }
}

/// Sums of displacement errors of (ego, object) estimates fused from
/// every view ([`ViewEstimate`]), beside their pairwise estimates.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViewSums {
    pub n: usize,
    pub single_m: f64,
    pub pairwise_m: f64,
    pub all_views_m: f64,
}

impl ViewSums {
    pub fn add(&mut self, v: &ViewEstimate) {
        self.n += 1;
        self.single_m += v.single_error_m;
        self.pairwise_m += v.pairwise_error_m;
        self.all_views_m += v.fused_error_m;
    }

    pub fn merge(&mut self, other: &ViewSums) {
        self.n += other.n;
        self.single_m += other.single_m;
        self.pairwise_m += other.pairwise_m;
        self.all_views_m += other.all_views_m;
    }

    /// (single, pairwise fused, all-views fused) means; NaN when empty.
    pub fn means(&self) -> (f64, f64, f64) {
        let m = |sum: f64| {
            if self.n == 0 {
                f64::NAN
            } else {
                sum / self.n as f64
            }
        };
        (m(self.single_m), m(self.pairwise_m), m(self.all_views_m))
    }
}

/// The group of an (ego, object) by how many vehicles of the frame see it:
/// 1, 2, 3, or 4 and more.
pub fn seen_by_group(seen_by: usize) -> usize {
    seen_by.clamp(1, 4)
}

/// The label of a [`seen_by_group`].
pub fn seen_by_label(group: usize) -> String {
    if group >= 4 {
        "4+".into()
    } else {
        group.to_string()
    }
}

/// Displacement errors over the three object sets of the protocol.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ObjectErrors {
    /// Every real object an ego detects: the same set for every method.
    pub all: ErrorSums,
    /// Those the peer detects too.
    pub covisible: ErrorSums,
    /// Those the method matched (a method-dependent set).
    pub matched: ErrorSums,
}

impl ObjectErrors {
    pub fn record(&mut self, estimates: &[ObjectEstimate]) {
        for e in estimates {
            self.all.add(e);
            if e.covisible {
                self.covisible.add(e);
            }
            if e.matched {
                self.matched.add(e);
            }
        }
    }
}

/// Running sums for one summary row.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Accumulator {
    pub instances: usize,
    pub counts: PairCounts,
    pub errors: ObjectErrors,
}

/// One line of a run's `summary.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct SummaryRow {
    pub key: RowKey,
    pub n_instances: usize,
    /// Objects of the common set (every real object an ego detects).
    pub n_objects: usize,
    /// Of those, the ones the method matched.
    pub n_matched: usize,
    pub precision: f64,
    pub recall: f64,
    pub f1: f64,
    /// Means over the common set (fused = single where unmatched).
    pub de_single_m: f64,
    pub de_fused_m: f64,
    /// Means over the covisible objects.
    pub de_single_covis_m: f64,
    pub de_fused_covis_m: f64,
    /// Means over the matched objects only (method-dependent).
    pub de_single_matched_m: f64,
    pub de_fused_matched_m: f64,
    /// Chains x~y~z across three vehicles, and the share the third pair
    /// contradicts (NaN without any chain).
    pub triple_chains: usize,
    pub inconsistent_triple_share: f64,
    /// The implied objects as a clustering (pair counting).
    pub object_precision: f64,
    pub object_recall: f64,
    pub object_f1: f64,
    /// Every (ego, real object) of the frames once: single, pairwise fused
    /// (mean over the ego's peers that see the object) and fused from every view.
    pub n_ego_objects: usize,
    pub de_single_per_ego_m: f64,
    pub de_fused_pairwise_per_ego_m: f64,
    pub de_fused_all_views_m: f64,
}

/// A run's summary: counts and errors pooled over its instances.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    pub rows: BTreeMap<RowKey, Accumulator>,
    /// Per (method, pose noise): consistency across vehicles.
    pub consistency: BTreeMap<(Method, PoseNoiseLabel), Consistency>,
    /// Fusion from every view, per row.
    pub views: BTreeMap<RowKey, ViewSums>,
}

impl Summary {
    pub fn record_views(&mut self, key: RowKey, views: &[ViewEstimate]) {
        let sums = self.views.entry(key).or_default();
        for v in views {
            sums.add(v);
        }
    }

    pub fn record_consistency(&mut self, method: Method, level: PoseNoiseLabel, c: Consistency) {
        self.consistency.entry((method, level)).or_default().add(c);
    }

    pub fn record(&mut self, key: RowKey, counts: PairCounts, estimates: &[ObjectEstimate]) {
        let acc = self.rows.entry(key).or_default();
        acc.instances += 1;
        acc.counts.add(counts);
        acc.errors.record(estimates);
    }

    /// Rows in a fixed order (method, pose noise, fusion).
    pub fn rows(&self) -> Vec<SummaryRow> {
        self.rows
            .iter()
            .map(|(key, acc)| {
                let e = &acc.errors;
                let c = self
                    .consistency
                    .get(&(key.method, key.pose_noise))
                    .copied()
                    .unwrap_or_default();
                let v = self.views.get(key).copied().unwrap_or_default();
                let (v_single, v_pairwise, v_all) = v.means();
                SummaryRow {
                    key: *key,
                    n_instances: acc.instances,
                    n_objects: e.all.n,
                    n_matched: e.matched.n,
                    precision: acc.counts.precision(),
                    recall: acc.counts.recall(),
                    f1: acc.counts.f1(),
                    de_single_m: e.all.mean_single_m(),
                    de_fused_m: e.all.mean_fused_m(),
                    de_single_covis_m: e.covisible.mean_single_m(),
                    de_fused_covis_m: e.covisible.mean_fused_m(),
                    de_single_matched_m: e.matched.mean_single_m(),
                    de_fused_matched_m: e.matched.mean_fused_m(),
                    triple_chains: c.triples.chains,
                    inconsistent_triple_share: c.triples.share(),
                    object_precision: c.objects.precision(),
                    object_recall: c.objects.recall(),
                    object_f1: c.objects.f1(),
                    n_ego_objects: v.n,
                    de_single_per_ego_m: v_single,
                    de_fused_pairwise_per_ego_m: v_pairwise,
                    de_fused_all_views_m: v_all,
                }
            })
            .collect()
    }
}

/// One row of `objects.parquet`.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectRow {
    pub instance: usize,
    pub step: u64,
    pub time_s: f64,
    pub key: RowKey,
    pub estimate: ObjectEstimate,
}

/// What a run keeps: its summary, accumulated as it goes, and its
/// counters (the per-object rows are streamed to disk, not kept).
#[derive(Clone, Debug, Default)]
pub struct RunResults {
    pub summary: Summary,
    pub n_instances: usize,
    pub n_steps: u64,
    pub sim_end_s: f64,
    /// Wall time spent inside the bridge's step calls.
    pub bridge_time: Duration,
    /// Road users read over all steps (for the per-object bridge cost).
    pub objects_read: u64,
    /// Wall time of the whole run.
    pub wall_time: Duration,
    /// Multiply-adds of every method's network over the run
    /// ([`crate::matching::Matcher::network_macs`]).
    pub network_macs: u64,
}

/// A run's `summary.csv` as a table: its one list of columns (the metrics
/// a batch aggregates named by [`Metric`]).
pub fn summary_table(rows: &[SummaryRow]) -> Table {
    let mut t = Table::default();
    let key = |f: fn(&RowKey) -> &'static str| rows.iter().map(|r| f(&r.key).to_owned()).collect();
    t.text(super::batch::KEY_COLUMNS[0], key(|k| k.method.as_str()));
    t.text(super::batch::KEY_COLUMNS[1], key(|k| k.pose_noise.as_str()));
    t.text(super::batch::KEY_COLUMNS[2], key(|k| k.fusion.as_str()));
    let count = |f: fn(&SummaryRow) -> usize| rows.iter().map(|r| f(r) as u64).collect();
    let number = |f: fn(&SummaryRow) -> f64| rows.iter().map(f).collect();
    t.count("n_instances", count(|r| r.n_instances));
    t.count("n_objects", count(|r| r.n_objects));
    t.count("n_matched", count(|r| r.n_matched));
    t.number(Metric::Precision.column(), number(|r| r.precision));
    t.number(Metric::Recall.column(), number(|r| r.recall));
    t.number(Metric::F1.column(), number(|r| r.f1));
    t.number(Metric::DeSingle.column(), number(|r| r.de_single_m));
    t.number(Metric::DeFused.column(), number(|r| r.de_fused_m));
    t.number(
        Metric::DeSingleCovisible.column(),
        number(|r| r.de_single_covis_m),
    );
    t.number(
        Metric::DeFusedCovisible.column(),
        number(|r| r.de_fused_covis_m),
    );
    t.number("de_single_matched_m", number(|r| r.de_single_matched_m));
    t.number(
        Metric::DeFusedMatched.column(),
        number(|r| r.de_fused_matched_m),
    );
    t.count("triple_chains", count(|r| r.triple_chains));
    t.number(
        "inconsistent_triple_share",
        number(|r| r.inconsistent_triple_share),
    );
    t.number("object_precision", number(|r| r.object_precision));
    t.number("object_recall", number(|r| r.object_recall));
    t.number("object_f1", number(|r| r.object_f1));
    t.count("n_ego_objects", count(|r| r.n_ego_objects));
    t.number("de_single_per_ego_m", number(|r| r.de_single_per_ego_m));
    t.number(
        "de_fused_pairwise_per_ego_m",
        number(|r| r.de_fused_pairwise_per_ego_m),
    );
    t.number("de_fused_all_views_m", number(|r| r.de_fused_all_views_m));
    t
}
