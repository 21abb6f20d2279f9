//! The five kinds of junction, each drawn from a named stream: crossing,
//! arterial, cluster, roundabout, ramp.

use std::f64::consts::{PI, TAU};

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::layout::{Control, Flow, Layout, Strip};
use super::{JUNCTION_ID, LANE_WIDTH_M};
use crate::geometry::Vec2;

/// A unit vector at `angle_rad`.
pub(super) fn unit(angle_rad: f64) -> Vec2 {
    Vec2::new(angle_rad.cos(), angle_rad.sin())
}

/// `n` angles at least `min_gap_deg` apart, evenly spread then jittered.
pub(super) fn draw_angles(r: &mut ChaCha8Rng, n: u32, min_gap_deg: f64) -> Vec<f64> {
    let rotation = r.random_range(0.0..TAU);
    let spacing = TAU / f64::from(n);
    let min_gap = min_gap_deg.to_radians();
    loop {
        let mut a: Vec<f64> = (0..n)
            .map(|k| {
                let jitter = r.random_range(-0.3..0.3) * spacing;
                (rotation + f64::from(k) * spacing + jitter).rem_euclid(TAU)
            })
            .collect();
        a.sort_by(f64::total_cmp);
        if min_gap_rad(&a) >= min_gap {
            return a;
        }
    }
}

/// The smallest angle between consecutive directions (sorted), radians.
pub fn min_gap_rad(sorted: &[f64]) -> f64 {
    (0..sorted.len())
        .map(|k| {
            let next = if k + 1 < sorted.len() {
                sorted[k + 1]
            } else {
                sorted[0] + TAU
            };
            next - sorted[k]
        })
        .fold(PI * 2.0, f64::min)
}

/// 1, 2 or 3 lanes (35 / 45 / 20 %).
pub(super) fn draw_lanes(r: &mut ChaCha8Rng) -> u32 {
    match r.random_range(0.0..1.0) {
        x if x < 0.35 => 1,
        x if x < 0.8 => 2,
        _ => 3,
    }
}

/// 3-5 legs at least 50 degrees apart, 1-3 lanes each, a traffic light
/// (60 %) or priority.
pub(super) fn crossing(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
    let n = r.random_range(3..=5_u32);
    let angles = draw_angles(r, n, 50.0);
    let signalized = r.random_bool(0.6);
    let mut l = Layout::default();
    let control = if signalized {
        Control::TrafficLight
    } else {
        Control::Priority
    };
    l.node(JUNCTION_ID, Vec2::zeros(), control);
    let mut approaches = Vec::new();
    let mut lanes_text = Vec::new();
    for (k, &angle) in angles.iter().enumerate() {
        let lanes = draw_lanes(r);
        let length = r.random_range(150.0..220.0);
        let sidewalk = r.random_range(2.0..3.0);
        let speed = if lanes == 1 { 11.11 } else { 13.89 };
        let outer = format!("O{k}");
        l.node(&outer, unit(angle) * length, Control::Priority);
        l.street(
            &format!("L{k}"),
            (&outer, JUNCTION_ID),
            [lanes; 2],
            speed,
            sidewalk,
        );
        approaches.push((format!("L{k}in"), format!("L{k}out"), lanes));
        lanes_text.push(lanes.to_string());
    }
    l.all_to_all(&approaches, per_lane_s, true);
    let degrees: Vec<String> = angles
        .iter()
        .map(|a| format!("{:.0}", a.to_degrees()))
        .collect();
    l.description = format!(
        "{} legs at {} deg, {} lanes per direction, {}",
        angles.len(),
        degrees.join("/"),
        lanes_text.join("/"),
        if signalized {
            "traffic light"
        } else {
            "priority"
        }
    );
    l
}

/// A signalised crossing of a 2-3 lane arterial (legs 0 and 2) and a 1-2
/// lane side street, each approach of the arterial (and half of the side
/// street's) widened by a turn pocket near the junction.
pub(super) fn arterial(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
    let rotation = r.random_range(0.0..TAU);
    let mut l = Layout::default();
    l.node(JUNCTION_ID, Vec2::zeros(), Control::TrafficLight);
    let major = r.random_range(2..=3_u32);
    let minor = r.random_range(1..=2_u32);
    let sidewalk = r.random_range(2.0..4.0);
    let mut approaches = Vec::new();
    let mut pockets = Vec::new();
    for k in 0..4_usize {
        let angle = rotation + k as f64 * PI / 2.0 + r.random_range(-12f64..12.0).to_radians();
        let is_major = k % 2 == 0;
        let lanes = if is_major { major } else { minor };
        let speed = if is_major {
            r.random_range(13.89..16.67)
        } else {
            r.random_range(11.11..13.89)
        };
        let length = r.random_range(180.0..260.0);
        let outer = format!("O{k}");
        l.node(&outer, unit(angle) * length, Control::Priority);
        let pocket = (is_major || r.random_bool(0.5)).then(|| r.random_range(40.0..90.0));
        // Both directions pass the pocket's node, so that netconvert pairs
        // them into one two-way road.
        let (first_in, last_out) = match pocket {
            Some(p) => {
                let mid = format!("P{k}");
                l.node(&mid, unit(angle) * p, Control::Priority);
                let (far_in, far_out) = (format!("L{k}farin"), format!("L{k}farout"));
                l.road(&far_in, (&outer, &mid), lanes, speed, sidewalk);
                l.road(
                    &format!("L{k}in"),
                    (&mid, JUNCTION_ID),
                    lanes + 1,
                    speed,
                    sidewalk,
                );
                l.road(
                    &format!("L{k}out"),
                    (JUNCTION_ID, &mid),
                    lanes,
                    speed,
                    sidewalk,
                );
                l.road(&far_out, (&mid, &outer), lanes, speed, sidewalk);
                pockets.push(format!("{p:.0}"));
                (far_in, far_out)
            }
            None => {
                l.road(
                    &format!("L{k}in"),
                    (&outer, JUNCTION_ID),
                    lanes,
                    speed,
                    sidewalk,
                );
                l.road(
                    &format!("L{k}out"),
                    (JUNCTION_ID, &outer),
                    lanes,
                    speed,
                    sidewalk,
                );
                (format!("L{k}in"), format!("L{k}out"))
            }
        };
        l.strip(
            &outer,
            JUNCTION_ID,
            f64::from(2 * lanes + 1) * LANE_WIDTH_M / 2.0 + sidewalk,
        );
        approaches.push((first_in, last_out, lanes));
    }
    l.all_to_all(&approaches, per_lane_s, true);
    l.description = format!(
        "arterial of {major} lanes per direction crossing a street of {minor}, \
         turn pockets of {} m, traffic light",
        pockets.join("/")
    );
    l
}

/// Two junctions `C` and `D` 10-24 m apart on a 1-3 lane main road, side
/// streets leaving from each (one on each side: a staggered crossing; or a
/// second one at `D`), joined by netconvert into one cluster; a traffic
/// light (70 %) or priority.
pub(super) fn cluster(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
    let angle = r.random_range(0.0..TAU);
    let gap = r.random_range(10.0..24.0);
    let main = draw_lanes(r);
    let side = r.random_range(1..=2_u32);
    let signalized = r.random_bool(0.7);
    let control = if signalized {
        Control::TrafficLight
    } else {
        Control::Priority
    };
    let sidewalk = r.random_range(2.0..3.0);
    let (u, v) = (unit(angle), unit(angle + PI / 2.0));
    let mut l = Layout::default();
    l.node(JUNCTION_ID, Vec2::zeros(), control);
    l.node("D", u * gap, control);
    let mut length = || r.random_range(150.0..220.0);
    let ends = [
        (JUNCTION_ID, -u, main),
        ("D", u, main),
        (JUNCTION_ID, v, side),
        ("D", -v, side),
    ];
    let mut approaches = Vec::new();
    for (k, &(at, direction, lanes)) in ends.iter().enumerate() {
        let outer = format!("O{k}");
        let end = l.at(at) + direction * length();
        l.node(&outer, end, Control::Priority);
        let speed = if lanes == 1 { 11.11 } else { 13.89 };
        l.street(&format!("L{k}"), (&outer, at), [lanes; 2], speed, sidewalk);
        approaches.push((format!("L{k}in"), format!("L{k}out"), lanes));
    }
    // The link between the two junctions.
    l.road("Kin", (JUNCTION_ID, "D"), main, 13.89, sidewalk);
    l.road("Kout", ("D", JUNCTION_ID), main, 13.89, sidewalk);
    l.strip(JUNCTION_ID, "D", f64::from(main) * LANE_WIDTH_M + sidewalk);
    l.all_to_all(&approaches, per_lane_s, true);
    l.join_within_m = Some(gap + 5.0);
    l.description = format!(
        "two junctions {gap:.0} m apart joined into one: a main road of {main} lanes per \
         direction, side streets of {side}, {}",
        if signalized {
            "traffic lights"
        } else {
            "priority"
        }
    );
    l
}

/// 3-5 legs on a ring of 14-26 m radius with 1-2 lanes, `C` the ring node
/// of the first leg.
pub(super) fn roundabout(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
    let n = r.random_range(3..=5_u32);
    let angles = draw_angles(r, n, 60.0);
    let radius = r.random_range(14.0..26.0);
    let ring_lanes = if radius > 20.0 && r.random_bool(0.5) {
        2
    } else {
        1
    };
    let sidewalk = r.random_range(2.0..3.0);
    let mut l = Layout::default();
    let ring: Vec<String> = (0..angles.len())
        .map(|k| {
            if k == 0 {
                JUNCTION_ID.to_owned()
            } else {
                format!("R{k}")
            }
        })
        .collect();
    for (id, &angle) in ring.iter().zip(&angles) {
        l.node(id, unit(angle) * radius, Control::Priority);
    }
    let mut ring_edges = Vec::new();
    for k in 0..ring.len() {
        let (a, b) = (&ring[k], &ring[(k + 1) % ring.len()]);
        let id = format!("ring{k}");
        l.road(&id, (a, b), ring_lanes, 8.33, 0.0);
        // An arc, counter-clockwise (right-hand traffic), in strips.
        let (from, mut to) = (angles[k], angles[(k + 1) % angles.len()]);
        if to <= from {
            to += TAU;
        }
        let arc: Vec<Vec2> = (0..=8)
            .map(|t| unit(from + (to - from) * f64::from(t) / 8.0) * radius)
            .collect();
        for w in arc.windows(2) {
            let half_width_m = f64::from(ring_lanes) * LANE_WIDTH_M;
            l.strips.push(Strip {
                a: w[0],
                b: w[1],
                half_width_m,
            });
        }
        if let Some(road) = l.roads.last_mut() {
            road.shape_m = arc;
        }
        ring_edges.push(id);
    }
    let mut approaches = Vec::new();
    for (k, &angle) in angles.iter().enumerate() {
        let lanes = r.random_range(1..=2_u32);
        let outer = format!("O{k}");
        let length = r.random_range(150.0..220.0);
        l.node(&outer, unit(angle) * (radius + length), Control::Priority);
        l.street(
            &format!("L{k}"),
            (&outer, &ring[k]),
            [lanes; 2],
            13.89,
            sidewalk,
        );
        approaches.push((format!("L{k}in"), format!("L{k}out"), lanes));
    }
    l.all_to_all(&approaches, per_lane_s, true);
    l.description = format!(
        "roundabout of {radius:.0} m radius, {ring_lanes} ring lane(s), {} legs",
        angles.len()
    );
    l.roundabout = Some((ring, ring_edges));
    l
}

/// A motorway of 2-3 lanes per carriageway: eastbound, an off-ramp to a
/// parallel local road, then `C` where an on-ramp from it merges, an
/// acceleration lane after; westbound passes by.
pub(super) fn ramp(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
    let angle = r.random_range(0.0..TAU);
    let lanes = r.random_range(2..=3_u32);
    let speed = r.random_range(27.78..33.33);
    let median = r.random_range(4.0..8.0);
    let local_offset = median + r.random_range(45.0..70.0);
    let half = 350.0;
    let (u, v) = (unit(angle), unit(angle + PI / 2.0));
    let east = |x: f64| u * x - v * median;
    let local = |x: f64| u * x - v * local_offset;
    let mut l = Layout::default();
    for (id, at) in [
        ("WE", east(-half)),
        ("X", east(-180.0)),
        (JUNCTION_ID, Vec2::zeros() - v * median),
        ("A", east(160.0)),
        ("EE", east(half)),
        ("EW", u * half + v * median),
        ("WW", -u * half + v * median),
        ("LW", local(-half)),
        ("F1", local(-110.0)),
        ("F2", local(-50.0)),
        ("LE", local(half)),
    ] {
        l.node(id, at, Control::Priority);
    }
    let carriageway = f64::from(lanes) * LANE_WIDTH_M / 2.0 + 1.0;
    for (id, ends, n) in [
        ("M1", ("WE", "X"), lanes),
        ("M2", ("X", JUNCTION_ID), lanes),
        ("M3", (JUNCTION_ID, "A"), lanes + 1),
        ("M4", ("A", "EE"), lanes),
        ("MW", ("EW", "WW"), lanes),
    ] {
        l.road(id, ends, n, speed, 0.0);
        l.strip(ends.0, ends.1, carriageway + LANE_WIDTH_M / 2.0);
    }
    l.road("OFF", ("X", "F1"), 1, 16.67, 0.0);
    l.strip("X", "F1", LANE_WIDTH_M);
    l.road("ON", ("F2", JUNCTION_ID), 1, 16.67, 0.0);
    l.strip("F2", JUNCTION_ID, LANE_WIDTH_M);
    let sidewalk = r.random_range(2.0..3.0);
    for (id, ends) in [
        ("Q1", ("LW", "F1")),
        ("Q2", ("F1", "F2")),
        ("Q3", ("F2", "LE")),
    ] {
        l.street(id, ends, [1, 1], 13.89, sidewalk);
    }
    let through = per_lane_s * f64::from(lanes);
    let local_rate = 0.3 * per_lane_s;
    for (from, to, rate, bicycles) in [
        ("M1", "M4", 0.8 * through, false),
        ("M1", "Q3in", 0.1 * through, false),
        ("M1", "Q1out", 0.1 * through, false),
        ("MW", "MW", through, false),
        ("Q1in", "M4", local_rate, false),
        ("Q3out", "M4", local_rate, false),
        ("Q1in", "Q3in", local_rate, true),
        ("Q3out", "Q1out", local_rate, true),
    ] {
        l.flows.push(Flow {
            from: from.to_owned(),
            to: to.to_owned(),
            vehicles_s: rate,
            bicycles,
        });
    }
    l.walks = vec![
        ("Q1in".to_owned(), "Q3in".to_owned()),
        ("Q3out".to_owned(), "Q1out".to_owned()),
    ];
    l.description = format!(
        "motorway merge: {lanes} lanes per carriageway at {:.0} km/h, off- and on-ramp to a \
         local road {:.0} m away",
        speed * 3.6,
        local_offset
    );
    l
}
