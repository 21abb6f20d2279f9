//! Cooperation over time as `coid track`'s tables: each vehicle's
//! tracking counts (CLEAR-MOT) and the receivers' association over
//! messages.

use super::table::Table;
use crate::v2x::{OverTimeCounts, VehicleTracking};

/// `association.csv`: one row per decision (per message, over time).
pub fn association_table(o: &OverTimeCounts) -> Table {
    let mut t = Table::default();
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
    let de = |sum: f64| ratio(sum, o.de_n as f64);
    let share = |right: u64| ratio(right as f64, o.pairs_in_view as f64);
    let rows = [
        ("per-message", o.per_message, share(o.per_message_right)),
        ("over-time", o.over_time, share(o.over_time_right)),
    ];
    t.text("association", rows.iter().map(|r| r.0.to_owned()).collect());
    t.count("receptions", vec![o.receptions; 2]);
    t.number("precision", rows.iter().map(|r| r.1.precision()).collect());
    t.number("recall", rows.iter().map(|r| r.1.recall()).collect());
    t.number("f1", rows.iter().map(|r| r.1.f1()).collect());
    t.number("time_share_right", rows.iter().map(|r| r.2).collect());
    let over = |v: f64| vec![f64::NAN, v];
    t.number(
        "pairs_found_share",
        over(ratio(o.pairs_found as f64, o.pairs as f64)),
    );
    t.number(
        "time_to_first_right_s",
        over(ratio(o.time_to_first_right_sum_s, o.pairs_found as f64)),
    );
    t.count("switches", vec![0, o.switches]);
    t.number("de_single_m", over(de(o.de_single_sum_m)));
    t.number("de_fused_m", over(de(o.de_fused_sum_m)));
    t.number("de_fused_ci_m", over(de(o.de_ci_sum_m)));
    let oracle = |sum: f64| over(ratio(sum, o.oracle_n as f64));
    t.number("oracle_de_single_m", oracle(o.oracle_single_sum_m));
    t.number("oracle_de_fused_m", oracle(o.oracle_fused_sum_m));
    t.number("oracle_de_fused_ci_m", oracle(o.oracle_ci_sum_m));
    for (name, v) in o.metrics().into_iter().skip(9) {
        t.number(name, over(v));
    }
    t
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
    t.count("in_flight_at_end", count(|r| r.in_flight_at_end));
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
