//! What results look like before they are written: summary rows of a run,
//! the per-object rows, the paper's tables as named columns, a batch's
//! rows, and the data behind the plots. Plain data and the arithmetic that
//! makes it (pooling; means over Monte Carlo runs with 95% intervals from
//! Student's t quantiles, statrs); `io` writes it and `render` draws it.

use std::collections::{BTreeMap, HashMap};
use std::time::Duration;

use statrs::distribution::{ContinuousCDF, StudentsT};

use crate::evaluate::{Consistency, ObjectEstimate, PairCounts, ViewEstimate};
use crate::fusion::FusionVariant;
use crate::matching::Method;
use crate::sensor::PoseNoiseLabel;

/// The 97.5% quantile of Student's t with `dof` degrees of freedom (NaN
/// for 0).
pub fn t_975(dof: usize) -> f64 {
    StudentsT::new(0.0, 1.0, dof as f64)
        .map(|t| t.inverse_cdf(0.975))
        .unwrap_or(f64::NAN)
}

/// Mean and half-width of the 95% confidence interval (Student t) of a
/// sample, ignoring values that are not finite; the half-width is NaN for
/// fewer than two values.
pub fn mean_ci95(values: &[f64]) -> (f64, f64) {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    let n = v.len();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let mean = v.iter().sum::<f64>() / n as f64;
    if n < 2 {
        return (mean, f64::NAN);
    }
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (mean, t_975(n - 1) * (var / n as f64).sqrt())
}

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
}

impl ErrorSums {
    pub fn add(&mut self, e: &ObjectEstimate) {
        self.n += 1;
        self.single_m += e.single_error_m();
        self.fused_m += e.fused_error_m();
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
}

/// A table for a results folder: named columns of text or numbers.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    pub columns: Vec<(String, TableColumn)>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum TableColumn {
    Text(Vec<String>),
    Number(Vec<f64>),
    Count(Vec<u64>),
    Flag(Vec<bool>),
}

impl Table {
    pub fn text(&mut self, name: &str, v: Vec<String>) {
        self.columns.push((name.into(), TableColumn::Text(v)));
    }

    pub fn number(&mut self, name: &str, v: Vec<f64>) {
        self.columns.push((name.into(), TableColumn::Number(v)));
    }

    pub fn count(&mut self, name: &str, v: Vec<u64>) {
        self.columns.push((name.into(), TableColumn::Count(v)));
    }

    pub fn flag(&mut self, name: &str, v: Vec<bool>) {
        self.columns.push((name.into(), TableColumn::Flag(v)));
    }

    /// Adds `name` and `name_ci95`: per row, the mean of its per-run
    /// samples and the half-width of the 95% interval. Undefined (NaN)
    /// samples are left out.
    pub fn stat(&mut self, name: &str, samples: &[Vec<f64>]) {
        let (m, c): (Vec<f64>, Vec<f64>) = samples.iter().map(|s| mean_ci95(s)).unzip();
        self.number(name, m);
        self.number(&format!("{name}_ci95"), c);
    }

    /// Adds `name`: per row, how many of its per-run samples are defined.
    pub fn defined(&mut self, name: &str, samples: &[Vec<f64>]) {
        let n = samples
            .iter()
            .map(|s| s.iter().filter(|x| x.is_finite()).count() as u64)
            .collect();
        self.count(name, n);
    }

    /// The column `name`, if it exists.
    pub fn column(&self, name: &str) -> Option<&TableColumn> {
        self.columns.iter().find(|(n, _)| n == name).map(|(_, c)| c)
    }

    pub fn height(&self) -> usize {
        match self.columns.first() {
            Some((_, TableColumn::Text(v))) => v.len(),
            Some((_, TableColumn::Number(v))) => v.len(),
            Some((_, TableColumn::Count(v))) => v.len(),
            Some((_, TableColumn::Flag(v))) => v.len(),
            None => 0,
        }
    }
}

/// One connected vehicle's tracker and messages over a run (`coid
/// track`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VehicleTracking {
    pub ego_id: String,
    /// Steps it was near the junction (and tracked).
    pub steps: u64,
    pub mot: crate::v2x::tracker::MotCounts,
    pub tracks_started: u64,
    /// CPMs it generated and the objects in them.
    pub messages: u64,
    pub objects_sent: u64,
    /// Of those messages, to each peer near the junction: delivered (with
    /// their latencies summed) and lost.
    pub delivered: u64,
    pub lost: u64,
    pub latency_sum_s: f64,
}

impl VehicleTracking {
    /// One receiver's fate of a message: its latency, or lost.
    pub fn delivery(&mut self, latency_s: Option<f64>) {
        match latency_s {
            Some(l) => {
                self.delivered += 1;
                self.latency_sum_s += l;
            }
            None => self.lost += 1,
        }
    }

    pub fn add(&mut self, o: &VehicleTracking) {
        self.steps += o.steps;
        self.mot.add(o.mot);
        self.tracks_started += o.tracks_started;
        self.messages += o.messages;
        self.objects_sent += o.objects_sent;
        self.delivered += o.delivered;
        self.lost += o.lost;
        self.latency_sum_s += o.latency_sum_s;
    }
}

/// What the receivers made of the messages over a run (`coid track`),
/// pooled over every (receiver, sender) link and every reception.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OverTimeCounts {
    /// Messages received and matched.
    pub receptions: u64,
    /// The frame matcher on each message alone, and the association over
    /// time, against the true pairs in view.
    pub per_message: PairCounts,
    pub over_time: PairCounts,
    /// True pairs in view, summed over receptions, and how many of them
    /// each decision had right.
    pub pairs_in_view: u64,
    pub per_message_right: u64,
    pub over_time_right: u64,
    /// True pairs (ego track, peer id) ever in view; of those, the ones
    /// the association got right at some point, and the summed time from
    /// first in view to first right (s).
    pub pairs: u64,
    pub pairs_found: u64,
    pub time_to_first_right_sum_s: f64,
    /// An ego track associated with one peer id, then with another.
    pub switches: u64,
    /// Displacement errors (m, summed) of ego tracks associated over time
    /// with a peer's: single, fused by Eq. 14-16 (independent), fused by
    /// covariance intersection; and the count.
    pub de_single_sum_m: f64,
    pub de_fused_sum_m: f64,
    pub de_ci_sum_m: f64,
    pub de_n: u64,
    /// The same for every true pair in view (the oracle's association):
    /// what fusion gives when association is not the question.
    pub oracle_single_sum_m: f64,
    pub oracle_fused_sum_m: f64,
    pub oracle_ci_sum_m: f64,
    pub oracle_n: u64,
    /// Recursive fusion: each ego track associated over time keeps a fused
    /// estimate that every reception updates with the ego track and the
    /// peer's object, by Eq. 14-16 (as if independent: both were already
    /// in it) and by covariance intersection. Summed errors (m) and
    /// normalised estimation errors squared (NEES; 2 when the claimed
    /// covariance is honest, above when it is overconfident), and, for
    /// reference, the NEES of fusing each reception once.
    pub recursive_fused_sum_m: f64,
    pub recursive_ci_sum_m: f64,
    pub recursive_nees_fused_sum: f64,
    pub recursive_nees_ci_sum: f64,
    pub once_nees_fused_sum: f64,
    pub once_nees_ci_sum: f64,
    pub recursive_n: u64,
}

impl OverTimeCounts {
    pub fn add(&mut self, o: &OverTimeCounts) {
        self.receptions += o.receptions;
        self.per_message.add(o.per_message);
        self.over_time.add(o.over_time);
        self.pairs_in_view += o.pairs_in_view;
        self.per_message_right += o.per_message_right;
        self.over_time_right += o.over_time_right;
        self.pairs += o.pairs;
        self.pairs_found += o.pairs_found;
        self.time_to_first_right_sum_s += o.time_to_first_right_sum_s;
        self.switches += o.switches;
        self.de_single_sum_m += o.de_single_sum_m;
        self.de_fused_sum_m += o.de_fused_sum_m;
        self.de_ci_sum_m += o.de_ci_sum_m;
        self.de_n += o.de_n;
        self.oracle_single_sum_m += o.oracle_single_sum_m;
        self.oracle_fused_sum_m += o.oracle_fused_sum_m;
        self.oracle_ci_sum_m += o.oracle_ci_sum_m;
        self.oracle_n += o.oracle_n;
        self.recursive_fused_sum_m += o.recursive_fused_sum_m;
        self.recursive_ci_sum_m += o.recursive_ci_sum_m;
        self.recursive_nees_fused_sum += o.recursive_nees_fused_sum;
        self.recursive_nees_ci_sum += o.recursive_nees_ci_sum;
        self.once_nees_fused_sum += o.once_nees_fused_sum;
        self.once_nees_ci_sum += o.once_nees_ci_sum;
        self.recursive_n += o.recursive_n;
    }

    /// The numbers of a run, by name (for sweeps over runs): pair F1 per
    /// message and over time, share of time right over time, fused and
    /// single errors of the association over time and of the oracle's.
    pub fn metrics(&self) -> [(&'static str, f64); 15] {
        let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
        let de = |sum: f64| ratio(sum, self.de_n as f64);
        let oracle = |sum: f64| ratio(sum, self.oracle_n as f64);
        let rec = |sum: f64| ratio(sum, self.recursive_n as f64);
        [
            ("f1_per_message", self.per_message.f1()),
            ("f1_over_time", self.over_time.f1()),
            (
                "time_share_right",
                ratio(self.over_time_right as f64, self.pairs_in_view as f64),
            ),
            ("de_single_m", de(self.de_single_sum_m)),
            ("de_fused_m", de(self.de_fused_sum_m)),
            ("de_fused_ci_m", de(self.de_ci_sum_m)),
            ("oracle_de_single_m", oracle(self.oracle_single_sum_m)),
            ("oracle_de_fused_m", oracle(self.oracle_fused_sum_m)),
            ("oracle_de_fused_ci_m", oracle(self.oracle_ci_sum_m)),
            ("recursive_de_fused_m", rec(self.recursive_fused_sum_m)),
            ("recursive_de_fused_ci_m", rec(self.recursive_ci_sum_m)),
            ("recursive_nees_fused", rec(self.recursive_nees_fused_sum)),
            ("recursive_nees_fused_ci", rec(self.recursive_nees_ci_sum)),
            ("once_nees_fused", rec(self.once_nees_fused_sum)),
            ("once_nees_fused_ci", rec(self.once_nees_ci_sum)),
        ]
    }

    /// `association.csv`: one row per decision (per message, over time).
    pub fn table(&self) -> Table {
        let mut t = Table::default();
        let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
        let de = |sum: f64| ratio(sum, self.de_n as f64);
        let share = |right: u64| ratio(right as f64, self.pairs_in_view as f64);
        let rows = [
            (
                "per-message",
                self.per_message,
                share(self.per_message_right),
            ),
            ("over-time", self.over_time, share(self.over_time_right)),
        ];
        t.text("association", rows.iter().map(|r| r.0.to_owned()).collect());
        t.count("receptions", vec![self.receptions; 2]);
        t.number("precision", rows.iter().map(|r| r.1.precision()).collect());
        t.number("recall", rows.iter().map(|r| r.1.recall()).collect());
        t.number("f1", rows.iter().map(|r| r.1.f1()).collect());
        t.number("time_share_right", rows.iter().map(|r| r.2).collect());
        let over = |v: f64| vec![f64::NAN, v];
        t.number(
            "pairs_found_share",
            over(ratio(self.pairs_found as f64, self.pairs as f64)),
        );
        t.number(
            "time_to_first_right_s",
            over(ratio(
                self.time_to_first_right_sum_s,
                self.pairs_found as f64,
            )),
        );
        t.count("switches", vec![0, self.switches]);
        t.number("de_single_m", over(de(self.de_single_sum_m)));
        t.number("de_fused_m", over(de(self.de_fused_sum_m)));
        t.number("de_fused_ci_m", over(de(self.de_ci_sum_m)));
        let oracle = |sum: f64| over(ratio(sum, self.oracle_n as f64));
        t.number("oracle_de_single_m", oracle(self.oracle_single_sum_m));
        t.number("oracle_de_fused_m", oracle(self.oracle_fused_sum_m));
        t.number("oracle_de_fused_ci_m", oracle(self.oracle_ci_sum_m));
        for (name, v) in self.metrics().into_iter().skip(9) {
            t.number(name, over(v));
        }
        t
    }
}

/// `tracking.csv`: one row per connected vehicle, then `all`.
pub fn tracking_table(vehicles: &[VehicleTracking]) -> Table {
    let mut all = VehicleTracking {
        ego_id: "all".into(),
        ..VehicleTracking::default()
    };
    for v in vehicles {
        all.add(v);
    }
    let rows: Vec<&VehicleTracking> = vehicles.iter().chain(std::iter::once(&all)).collect();
    let mut t = Table::default();
    let count = |f: fn(&VehicleTracking) -> u64| rows.iter().map(|r| f(r)).collect::<Vec<u64>>();
    let number = |f: fn(&VehicleTracking) -> f64| rows.iter().map(|r| f(r)).collect::<Vec<f64>>();
    t.text("ego_id", rows.iter().map(|r| r.ego_id.clone()).collect());
    t.count("steps", count(|r| r.steps));
    t.count("ground_truth", count(|r| r.mot.ground_truth as u64));
    t.count("misses", count(|r| r.mot.misses as u64));
    t.count("false_tracks", count(|r| r.mot.false_tracks as u64));
    t.count("id_switches", count(|r| r.mot.id_switches as u64));
    t.number("mota", number(|r| r.mot.mota()));
    t.number("motp_m", number(|r| r.mot.motp_m()));
    t.count("tracks_started", count(|r| r.tracks_started));
    t.count("messages", count(|r| r.messages));
    t.count("objects_sent", count(|r| r.objects_sent));
    t.count("delivered", count(|r| r.delivered));
    t.count("lost", count(|r| r.lost));
    t.number(
        "mean_latency_s",
        number(|r| {
            if r.delivered == 0 {
                f64::NAN
            } else {
                r.latency_sum_s / r.delivered as f64
            }
        }),
    );
    t
}

/// One correspondence of a matches file (`coid score --matches`): node
/// `a` of the instance's first vehicle is node `b` of its second, at one
/// pose-noise level (every level when `pose_noise` is `None`), with the
/// matcher's probability and uncertainty (bits) when it gave them.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchRow {
    pub run: u64,
    pub instance: u64,
    pub pose_noise: Option<String>,
    pub a: u64,
    pub b: u64,
    pub probability: Option<f64>,
    pub uncertainty: Option<f64>,
}

/// One row of an export's `runs.parquet`, as `coid score` checks it.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportRunRow {
    pub run: u64,
    pub split: String,
    pub n_instances: u64,
    /// `None` in exports of schema version 1.
    pub config_digest: Option<String>,
}

/// One row of a run's `summary.csv`, as read back for a batch aggregate.
#[derive(Clone, Debug, PartialEq)]
pub struct RunRow {
    pub method: String,
    pub pose_noise: String,
    pub fusion: String,
    pub n_instances: u64,
    pub precision: f64,
    pub recall: f64,
    pub f1: f64,
    pub de_single_m: f64,
    pub de_fused_m: f64,
    pub de_single_covis_m: f64,
    pub de_fused_covis_m: f64,
    pub de_fused_matched_m: f64,
}

/// One line of a batch's `summary.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct AggregateRow {
    pub method: String,
    pub pose_noise: String,
    pub fusion: String,
    /// Runs with at least one instance: the means are over these.
    pub n_runs: usize,
    /// Complete runs without any instance (no metric is defined in them).
    pub n_runs_without_instances: usize,
    /// Runs in which the method identified at least one pair (precision is
    /// defined); the precision mean is over these.
    pub n_runs_precision: usize,
    pub n_instances: u64,
    /// (mean over runs, 95% CI half-width) of each metric.
    pub precision: (f64, f64),
    pub recall: (f64, f64),
    pub f1: (f64, f64),
    pub de_single_m: (f64, f64),
    pub de_fused_m: (f64, f64),
    pub de_single_covis_m: (f64, f64),
    pub de_fused_covis_m: (f64, f64),
    pub de_fused_matched_m: (f64, f64),
}

/// Aggregates runs (each its summary rows, in run order): one row per
/// (method, pose noise, fusion) in order of first appearance, with the mean
/// over the runs that have instances and the 95% interval; runs without
/// any instance are counted apart.
pub fn aggregate(runs: &[Vec<RunRow>]) -> Vec<AggregateRow> {
    type Key = (String, String, String);
    let mut order: Vec<Key> = Vec::new();
    let mut groups: HashMap<Key, Vec<&RunRow>> = HashMap::new();
    for row in runs.iter().flatten() {
        let key = (
            row.method.clone(),
            row.pose_noise.clone(),
            row.fusion.clone(),
        );
        if !groups.contains_key(&key) {
            order.push(key.clone());
        }
        groups.entry(key).or_default().push(row);
    }
    order
        .into_iter()
        .map(|key| {
            let rows = &groups[&key];
            let stat =
                |f: fn(&RunRow) -> f64| mean_ci95(&rows.iter().map(|r| f(r)).collect::<Vec<_>>());
            AggregateRow {
                n_runs: rows.iter().filter(|r| r.n_instances > 0).count(),
                n_runs_without_instances: rows.iter().filter(|r| r.n_instances == 0).count(),
                n_runs_precision: rows.iter().filter(|r| r.precision.is_finite()).count(),
                n_instances: rows.iter().map(|r| r.n_instances).sum(),
                precision: stat(|r| r.precision),
                recall: stat(|r| r.recall),
                f1: stat(|r| r.f1),
                de_single_m: stat(|r| r.de_single_m),
                de_fused_m: stat(|r| r.de_fused_m),
                de_single_covis_m: stat(|r| r.de_single_covis_m),
                de_fused_covis_m: stat(|r| r.de_fused_covis_m),
                de_fused_matched_m: stat(|r| r.de_fused_matched_m),
                method: key.0,
                pose_noise: key.1,
                fusion: key.2,
            }
        })
        .collect()
}

/// One identified pair, for calibration: the method's probability that it
/// is right, its uncertainty, and whether it was right.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScoredPair {
    pub probability: f64,
    pub uncertainty: f64,
    pub correct: bool,
}

/// Equal-width probability bins of the calibration measures.
pub const CALIBRATION_BINS: usize = 15;

/// One bin of a reliability diagram.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReliabilityBin {
    /// Mean probability of the pairs in the bin.
    pub confidence: f64,
    /// Share of them that were right.
    pub accuracy: f64,
    pub count: usize,
}

/// The non-empty bins of `pairs` by probability (15 equal-width bins of
/// [0, 1]).
pub fn reliability(pairs: &[ScoredPair]) -> Vec<ReliabilityBin> {
    let mut sums = [(0.0, 0.0, 0usize); CALIBRATION_BINS];
    for p in pairs {
        let b = ((p.probability.clamp(0.0, 1.0) * CALIBRATION_BINS as f64) as usize)
            .min(CALIBRATION_BINS - 1);
        sums[b].0 += p.probability;
        sums[b].1 += if p.correct { 1.0 } else { 0.0 };
        sums[b].2 += 1;
    }
    sums.iter()
        .filter(|s| s.2 > 0)
        .map(|&(conf, right, n)| ReliabilityBin {
            confidence: conf / n as f64,
            accuracy: right / n as f64,
            count: n,
        })
        .collect()
}

/// Expected calibration error: the count-weighted mean gap between
/// accuracy and confidence over the bins; NaN without pairs.
pub fn expected_calibration_error(pairs: &[ScoredPair]) -> f64 {
    if pairs.is_empty() {
        return f64::NAN;
    }
    reliability(pairs)
        .iter()
        .map(|b| b.count as f64 * (b.accuracy - b.confidence).abs())
        .sum::<f64>()
        / pairs.len() as f64
}

/// Brier score: the mean squared gap between probability and outcome;
/// NaN without pairs.
pub fn brier_score(pairs: &[ScoredPair]) -> f64 {
    if pairs.is_empty() {
        return f64::NAN;
    }
    pairs
        .iter()
        .map(|p| (p.probability - if p.correct { 1.0 } else { 0.0 }).powi(2))
        .sum::<f64>()
        / pairs.len() as f64
}

/// How well the uncertainty tells wrong pairs from right ones: the
/// probability that a wrong pair has a higher uncertainty than a right one
/// (ties count half; the area under the ROC curve). NaN unless there are
/// both.
pub fn uncertainty_auroc(pairs: &[ScoredPair]) -> f64 {
    let wrong: Vec<f64> = pairs
        .iter()
        .filter(|p| !p.correct)
        .map(|p| p.uncertainty)
        .collect();
    let mut right: Vec<f64> = pairs
        .iter()
        .filter(|p| p.correct)
        .map(|p| p.uncertainty)
        .collect();
    if wrong.is_empty() || right.is_empty() {
        return f64::NAN;
    }
    right.sort_by(f64::total_cmp);
    let below = |u: f64| right.partition_point(|&r| r < u) as f64;
    let not_above = |u: f64| right.partition_point(|&r| r <= u) as f64;
    let score: f64 = wrong
        .iter()
        .map(|&u| below(u) + 0.5 * (not_above(u) - below(u)))
        .sum();
    score / (wrong.len() * right.len()) as f64
}

/// A pose-noise level's reliability diagram: (level, bins).
pub type LevelReliability = (String, Vec<ReliabilityBin>);

/// One point of the lambda sweep: (lambda, precision, recall, F1).
pub type SweepPoint = (f64, f64, f64, f64);

/// The data behind `coid eval`'s plots.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlotData {
    /// Per level: (level, points) of `ours`.
    pub lambda_sweep: Vec<(String, Vec<SweepPoint>)>,
    /// Methods, and per level the (mean, ci) F1 of each method.
    pub methods: Vec<String>,
    pub f1: Vec<(String, Vec<(f64, f64)>)>,
    /// Per level: pooled single and fused errors of `ours` (aligned fusion
    /// when configured, else paper).
    pub errors: Vec<(String, Vec<f64>, Vec<f64>)>,
    /// Per deep method: per level, its reliability diagram.
    pub reliability: Vec<(String, Vec<LevelReliability>)>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(method: &str, noise: &str, f1: f64, de: f64) -> RunRow {
        RunRow {
            method: method.into(),
            pose_noise: noise.into(),
            fusion: "paper".into(),
            n_instances: 10,
            precision: f1,
            recall: f1,
            f1,
            de_single_m: de,
            de_fused_m: de / 2.0,
            de_single_covis_m: de,
            de_fused_covis_m: de / 2.0,
            de_fused_matched_m: de / 4.0,
        }
    }

    #[test]
    fn aggregation_pools_runs_per_key_in_first_seen_order() {
        let runs = vec![
            vec![row("ours", "gps", 0.8, 2.0), row("oracle", "gps", 1.0, 2.0)],
            vec![
                row("ours", "gps", 0.6, 4.0),
                row("oracle", "gps", 1.0, f64::NAN),
            ],
            vec![row("ours", "gps", 0.7, 3.0)],
        ];
        let agg = aggregate(&runs);
        assert_eq!(agg.len(), 2);
        let ours = &agg[0];
        assert_eq!(
            (ours.method.as_str(), ours.n_runs, ours.n_instances),
            ("ours", 3, 30)
        );
        // 0.8, 0.6, 0.7: mean 0.7, s = 0.1, half-width t(2) 0.1 / sqrt(3).
        assert!((ours.f1.0 - 0.7).abs() < 1e-12);
        assert!(
            (ours.f1.1 - 4.302652730 * 0.1 / 3f64.sqrt()).abs() < 1e-7,
            "{:?}",
            ours.f1
        );
        assert!((ours.de_fused_m.0 - 1.5).abs() < 1e-12);
        // The oracle: a NaN error is left out of its mean.
        let oracle = &agg[1];
        assert_eq!((oracle.method.as_str(), oracle.n_runs), ("oracle", 2));
        assert_eq!(oracle.de_single_m.0, 2.0);
        assert!(oracle.de_single_m.1.is_nan());
        assert_eq!(oracle.f1, (1.0, 0.0));
    }

    #[test]
    fn summary_pools_counts_and_means_errors_over_objects() {
        use crate::geometry::Vec2;
        let key = RowKey {
            method: Method::Ours,
            pose_noise: PoseNoiseLabel::Gps,
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
}
