//! What cooperation over time counts: each vehicle's tracker and messages
//! ([`VehicleTracking`], CLEAR-MOT) and what the receivers made of the
//! messages ([`OverTimeCounts`]), `coid track`'s rows before they are
//! tables.

use super::tracker::MotCounts;
use crate::evaluate::PairCounts;

/// One connected vehicle's tracker and messages over a run (`coid
/// track`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VehicleTracking {
    pub ego_id: String,
    /// Steps it was near the junction (and tracked).
    pub steps: u64,
    pub mot: MotCounts,
    pub tracks_started: u64,
    /// CPMs it generated and the objects in them.
    pub messages: u64,
    pub objects_sent: u64,
    /// Of those messages, to each peer near the junction: delivered by the
    /// end of the run (with their latencies summed), lost, and still on
    /// their way when the run ended.
    pub delivered: u64,
    pub lost: u64,
    pub latency_sum_s: f64,
    pub in_flight_at_end: u64,
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

    /// A message counted delivered (latency `latency_s`) that had not
    /// arrived when the run ended.
    pub fn still_in_flight(&mut self, latency_s: f64) {
        self.delivered -= 1;
        self.latency_sum_s -= latency_s;
        self.in_flight_at_end += 1;
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
        self.in_flight_at_end += o.in_flight_at_end;
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
}
