//! A family of generated junctions: SUMO plain-XML networks (nodes, edges,
//! a roundabout where there is one), building blocks, demand and a coid
//! config, drawn from a seed.
//!
//! Each scenario is centred on junction `C` at the origin and is one of
//! five kinds, the shapes real networks have:
//!
//! - `crossing`: 3, 4 or 5 legs at varied angles, 1-3 lanes per direction,
//!   a traffic light or a priority rule;
//! - `arterial`: a signalised 4-leg crossing of a 2-3 lane arterial and a
//!   1-2 lane side street, approaches widened by a turn pocket (one more
//!   lane over the last 40-90 m);
//! - `cluster`: two junctions 10-24 m apart (a staggered crossing, or a
//!   crossing of a divided road) that netconvert joins into one cluster, as
//!   OSM imports do;
//! - `roundabout`: 3-5 legs on a ring of 14-26 m radius, 1-2 ring lanes;
//! - `ramp`: a motorway merge: 2-3 lanes per carriageway at 100-120 km/h,
//!   an off-ramp to and an on-ramp from a parallel local road, `C` the
//!   merge of the on-ramp.
//!
//! All have building blocks along their roads at a varied setback (or
//! none), and demand from every approach to every exit with the shipped
//! intersection's vehicle classes and colours, bicycles and pedestrians
//! where the roads have sidewalks: between light and saturated (a quarter
//! of the urban scenarios above 720 vehicles per hour and lane, so that
//! queues grow through the run; motorways 540-1620). Connected vehicles
//! are a penetration share, never fixed routes. This module only builds the
//! texts (metres, the SUMO net frame, angles counter-clockwise from east);
//! `io` writes them and `bridge` runs netconvert.

use std::f64::consts::{PI, TAU};
use std::fmt::Write as _;

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::geometry::{Polygon, Vec2};
use crate::rng::{self, Purpose};

/// The junction every generated scenario is centred on.
pub const JUNCTION_ID: &str = "C";
/// Simulated seconds a generated scenario's config runs.
pub const END_S: f64 = 150.0;
/// Share of motor vehicles that are connected in a generated scenario.
pub const PENETRATION: f64 = 0.1;
/// Lane width (netconvert's default), metres.
const LANE_WIDTH_M: f64 = 3.2;

/// The shipped intersection's vehicle and pedestrian types.
const VTYPES: &str = include_str!("../sumo_nets/vtypes.add.xml");

crate::label_enum! { "scenario kind";
    /// The layouts of the family (see the module docs).
    #[strum(serialize_all = "lowercase")]
    pub enum Kind {
        Crossing,
        Arterial,
        Cluster,
        Roundabout,
        Ramp,
    }
}

impl Kind {
    /// Every kind, in declaration order.
    pub fn all() -> &'static [Kind] {
        <Kind as strum::VariantArray>::VARIANTS
    }

    /// How often the family draws this kind (relative).
    fn weight(self) -> f64 {
        match self {
            Kind::Crossing => 0.3,
            Kind::Arterial => 0.2,
            Kind::Cluster => 0.15,
            Kind::Roundabout => 0.2,
            Kind::Ramp => 0.15,
        }
    }
}

/// How a node is controlled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Control {
    TrafficLight,
    Priority,
}

/// A SUMO node of the plain-XML network.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    pub id: String,
    pub at_m: Vec2,
    pub control: Control,
}

/// A one-way SUMO edge of the plain-XML network.
#[derive(Clone, Debug, PartialEq)]
pub struct Road {
    pub id: String,
    pub from: String,
    pub to: String,
    pub lanes: u32,
    pub speed_mps: f64,
    /// Sidewalk width, metres (0: none).
    pub sidewalk_m: f64,
    /// The centre line from node to node (empty: straight).
    pub shape_m: Vec<Vec2>,
}

/// A stretch of pavement that buildings keep clear of: the centre line
/// from `a` to `b` and the half width of everything on it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Strip {
    pub a: Vec2,
    pub b: Vec2,
    pub half_width_m: f64,
}

impl Strip {
    fn length_m(&self) -> f64 {
        (self.b - self.a).norm()
    }

    fn direction(&self) -> Vec2 {
        (self.b - self.a) / self.length_m().max(1e-9)
    }

    /// The pavement's footprint, `margin_m` wider on each side.
    fn footprint(&self, margin_m: f64) -> Polygon {
        let d = self.direction();
        rectangle(
            (self.a + self.b) / 2.0,
            d.y.atan2(d.x),
            self.length_m() + 2.0 * margin_m,
            2.0 * (self.half_width_m + margin_m),
        )
    }
}

/// Vehicles from one edge to another, `vehicles_s` per second.
#[derive(Clone, Debug, PartialEq)]
pub struct Flow {
    pub from: String,
    pub to: String,
    pub vehicles_s: f64,
    /// Bicycles too (a twentieth of the vehicles), where bicycles may go.
    pub bicycles: bool,
}

/// The network and demand of one scenario, before buildings.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Layout {
    pub nodes: Vec<Node>,
    pub roads: Vec<Road>,
    /// The nodes and edges of a roundabout's ring, in order.
    pub roundabout: Option<(Vec<String>, Vec<String>)>,
    pub strips: Vec<Strip>,
    pub flows: Vec<Flow>,
    /// Pedestrian walks between edges with sidewalks.
    pub walks: Vec<(String, String)>,
    /// Nodes netconvert must join into one junction (within metres).
    pub join_within_m: Option<f64>,
    /// One line on the layout, for people.
    pub description: String,
}

impl Layout {
    fn node(&mut self, id: &str, at_m: Vec2, control: Control) {
        self.nodes.push(Node {
            id: id.to_owned(),
            at_m,
            control,
        });
    }

    fn at(&self, id: &str) -> Vec2 {
        self.nodes
            .iter()
            .find(|n| n.id == id)
            .map_or(Vec2::zeros(), |n| n.at_m)
    }

    /// A one-way edge `from -> to`.
    fn road(
        &mut self,
        id: &str,
        (from, to): (&str, &str),
        lanes: u32,
        speed_mps: f64,
        sidewalk_m: f64,
    ) {
        self.roads.push(Road {
            id: id.to_owned(),
            from: from.to_owned(),
            to: to.to_owned(),
            lanes,
            speed_mps,
            sidewalk_m,
            shape_m: Vec::new(),
        });
    }

    /// A two-way street between two nodes (`<id>in` towards `to`, `<id>out`
    /// back), with its pavement strip.
    fn street(
        &mut self,
        id: &str,
        (from, to): (&str, &str),
        lanes: [u32; 2],
        speed_mps: f64,
        sidewalk_m: f64,
    ) {
        self.road(
            &format!("{id}in"),
            (from, to),
            lanes[0],
            speed_mps,
            sidewalk_m,
        );
        self.road(
            &format!("{id}out"),
            (to, from),
            lanes[1],
            speed_mps,
            sidewalk_m,
        );
        self.strip(
            from,
            to,
            f64::from(lanes[0] + lanes[1]) * LANE_WIDTH_M / 2.0 + sidewalk_m,
        );
    }

    fn strip(&mut self, from: &str, to: &str, half_width_m: f64) {
        let (a, b) = (self.at(from), self.at(to));
        self.strips.push(Strip { a, b, half_width_m });
    }

    /// Flows from every `(in edge, lanes)` to every out edge of another
    /// approach, the approach's rate shared evenly, with walks between
    /// the same edges when `walks`.
    fn all_to_all(&mut self, approaches: &[(String, String, u32)], per_lane_s: f64, walks: bool) {
        let n = approaches.len();
        for (a, (from, _, lanes)) in approaches.iter().enumerate() {
            for (b, (_, to, _)) in approaches.iter().enumerate() {
                if a == b {
                    continue;
                }
                self.flows.push(Flow {
                    from: from.clone(),
                    to: to.clone(),
                    vehicles_s: per_lane_s * f64::from(*lanes) / (n - 1) as f64,
                    bicycles: true,
                });
                if walks {
                    self.walks.push((from.clone(), to.clone()));
                }
            }
        }
    }
}

/// One generated scenario.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// Folder name: `s000`, `s001`, ...
    pub name: String,
    pub seed: u64,
    pub index: u64,
    pub kind: Kind,
    pub layout: Layout,
    /// Building footprints (world frame, metres).
    pub buildings: Vec<Polygon>,
    /// Distance kept between the pavement and a building, metres.
    pub setback_m: f64,
    /// Motor vehicles per second entering on each lane of an approach.
    pub vehicles_per_lane_s: f64,
    /// Pedestrians per second starting a walk (0 without sidewalks).
    pub pedestrians_s: f64,
}

/// The `index`-th scenario of the family drawn from `seed`, of one of
/// `kinds` (all of them when empty).
pub fn generate(seed: u64, index: u64, kinds: &[Kind]) -> Scenario {
    let mut r = rng::stream(seed, Purpose::Scenario, &[index]);
    let kinds = if kinds.is_empty() { Kind::all() } else { kinds };
    let total: f64 = kinds.iter().map(|k| k.weight()).sum();
    let mut pick = r.random_range(0.0..total);
    let kind = *kinds
        .iter()
        .find(|k| {
            pick -= k.weight();
            pick < 0.0
        })
        .unwrap_or(&kinds[kinds.len() - 1]);
    let vehicles_per_lane_s = match kind {
        Kind::Ramp => r.random_range(0.15..0.45),
        _ if r.random_bool(0.25) => r.random_range(0.20..0.33),
        _ => r.random_range(0.03..0.20),
    };
    let layout = match kind {
        Kind::Crossing => crossing(&mut r, vehicles_per_lane_s),
        Kind::Arterial => arterial(&mut r, vehicles_per_lane_s),
        Kind::Cluster => cluster(&mut r, vehicles_per_lane_s),
        Kind::Roundabout => roundabout(&mut r, vehicles_per_lane_s),
        Kind::Ramp => ramp(&mut r, vehicles_per_lane_s),
    };
    let setback_m = r.random_range(3.0..12.0);
    let buildings = if r.random_bool(0.85) {
        draw_buildings(&mut r, &layout.strips, setback_m)
    } else {
        Vec::new()
    };
    let pedestrians_s = if layout.walks.is_empty() {
        0.0
    } else {
        r.random_range(0.02..0.12)
    };
    Scenario {
        name: format!("s{index:03}"),
        seed,
        index,
        kind,
        layout,
        buildings,
        setback_m,
        vehicles_per_lane_s,
        pedestrians_s,
    }
}

/// A unit vector at `angle_rad`.
fn unit(angle_rad: f64) -> Vec2 {
    Vec2::new(angle_rad.cos(), angle_rad.sin())
}

/// `n` angles at least `min_gap_deg` apart, evenly spread then jittered.
fn draw_angles(r: &mut ChaCha8Rng, n: u32, min_gap_deg: f64) -> Vec<f64> {
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
fn draw_lanes(r: &mut ChaCha8Rng) -> u32 {
    match r.random_range(0.0..1.0) {
        x if x < 0.35 => 1,
        x if x < 0.8 => 2,
        _ => 3,
    }
}

/// 3-5 legs at least 50 degrees apart, 1-3 lanes each, a traffic light
/// (60 %) or priority.
fn crossing(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
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
fn arterial(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
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
fn cluster(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
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
fn roundabout(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
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
fn ramp(r: &mut ChaCha8Rng, per_lane_s: f64) -> Layout {
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

/// An oriented rectangle as a polygon.
fn rectangle(centre: Vec2, angle_rad: f64, length_m: f64, width_m: f64) -> Polygon {
    let (u, v) = (unit(angle_rad), unit(angle_rad + PI / 2.0));
    let (l, w) = (length_m / 2.0, width_m / 2.0);
    Polygon {
        vertices_m: vec![
            centre + u * l + v * w,
            centre - u * l + v * w,
            centre - u * l - v * w,
            centre + u * l - v * w,
        ],
    }
}

/// Whether two convex polygons share area (or touch).
fn overlap(a: &Polygon, b: &Polygon) -> bool {
    let edges = |p: &Polygon| -> Vec<(Vec2, Vec2)> {
        let n = p.vertices_m.len();
        (0..n)
            .map(|k| (p.vertices_m[k], p.vertices_m[(k + 1) % n]))
            .collect()
    };
    edges(b).iter().any(|(p, q)| a.blocks_segment(p, q))
        || edges(a).iter().any(|(p, q)| b.blocks_segment(p, q))
}

/// No building within this distance of the junction, metres.
const CLEAR_OF_JUNCTION_M: f64 = 18.0;

/// Blocks along both sides of every strip, `setback_m` from the pavement,
/// none on any pavement, near the junction or on another block.
fn draw_buildings(r: &mut ChaCha8Rng, strips: &[Strip], setback_m: f64) -> Vec<Polygon> {
    // Blocks may touch the setback line of a road, not cross it.
    let roads: Vec<Polygon> = strips
        .iter()
        .map(|s| s.footprint(setback_m - 0.05))
        .collect();
    let mut blocks: Vec<Polygon> = Vec::new();
    for strip in strips {
        let u = strip.direction();
        let v = Vec2::new(-u.y, u.x);
        for side in [1.0, -1.0] {
            let mut s = r.random_range(0.0..10.0);
            while s < strip.length_m() - 20.0 {
                let length = r.random_range(15.0..40.0);
                let depth = r.random_range(12.0..30.0);
                let offset = strip.half_width_m + setback_m + depth / 2.0;
                let centre = strip.a + u * (s + length / 2.0) + v * (side * offset);
                let block = rectangle(centre, u.y.atan2(u.x), length, depth);
                let free = block
                    .vertices_m
                    .iter()
                    .all(|c| c.norm() > CLEAR_OF_JUNCTION_M)
                    && !roads.iter().any(|road| overlap(road, &block))
                    && !blocks.iter().any(|b| overlap(b, &block));
                if free {
                    blocks.push(block);
                }
                s += length + r.random_range(4.0..12.0);
            }
        }
    }
    blocks
}

const XML_HEAD: &str = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";

impl Scenario {
    /// One line for a person: what was drawn.
    pub fn describe(&self) -> String {
        format!(
            "{}: {}: {}, building blocks: {} (setback {:.1} m), {:.0} vehicles/h per lane, \
             {:.0} pedestrians/h (family seed {}, index {})",
            self.name,
            self.kind.as_str(),
            self.layout.description,
            self.buildings.len(),
            self.setback_m,
            self.vehicles_per_lane_s * 3600.0,
            self.pedestrians_s * 3600.0,
            self.seed,
            self.index,
        )
    }

    /// netconvert's node file.
    pub fn nodes_xml(&self) -> String {
        let mut x = format!("{XML_HEAD}<nodes>\n");
        for n in &self.layout.nodes {
            let kind = match n.control {
                Control::TrafficLight => "traffic_light",
                Control::Priority => "priority",
            };
            let _ = writeln!(
                x,
                "    <node id=\"{}\" x=\"{:.2}\" y=\"{:.2}\" type=\"{kind}\"/>",
                n.id, n.at_m.x, n.at_m.y
            );
        }
        x + "</nodes>\n"
    }

    /// netconvert's edge file: every one-way edge (sidewalks where it has
    /// them), and the roundabout's ring.
    pub fn edges_xml(&self) -> String {
        let mut x = format!("{XML_HEAD}<edges>\n");
        for e in &self.layout.roads {
            let sidewalk = if e.sidewalk_m > 0.0 {
                format!(" sidewalkWidth=\"{:.2}\"", e.sidewalk_m)
            } else {
                String::new()
            };
            let shape = if e.shape_m.is_empty() {
                String::new()
            } else {
                let points: Vec<String> = e
                    .shape_m
                    .iter()
                    .map(|p| format!("{:.2},{:.2}", p.x, p.y))
                    .collect();
                format!(" shape=\"{}\"", points.join(" "))
            };
            let _ = writeln!(
                x,
                "    <edge id=\"{}\" from=\"{}\" to=\"{}\" numLanes=\"{}\" \
                 speed=\"{:.2}\"{sidewalk}{shape}/>",
                e.id, e.from, e.to, e.lanes, e.speed_mps
            );
        }
        if let Some((nodes, edges)) = &self.layout.roundabout {
            let _ = writeln!(
                x,
                "    <roundabout nodes=\"{}\" edges=\"{}\"/>",
                nodes.join(" "),
                edges.join(" ")
            );
        }
        x + "</edges>\n"
    }

    /// The building polygons (type `building`, as SUMO's OSM import names
    /// them).
    pub fn buildings_xml(&self) -> String {
        let mut x = format!("{XML_HEAD}<additional>\n");
        for (k, b) in self.buildings.iter().enumerate() {
            let shape: Vec<String> = b
                .vertices_m
                .iter()
                .chain(b.vertices_m.first())
                .map(|p| format!("{:.2},{:.2}", p.x, p.y))
                .collect();
            let _ = writeln!(
                x,
                "    <poly id=\"b{k}\" type=\"building\" color=\"200,180,150\" fill=\"1\" \
                 layer=\"-1\" shape=\"{}\"/>",
                shape.join(" ")
            );
        }
        x + "</additional>\n"
    }

    /// The demand: the shipped types, the layout's vehicle flows (random
    /// departures from SUMO's seed), bicycles, pedestrians.
    pub fn routes_xml(&self) -> String {
        let types = VTYPES
            .split_once("<additional>")
            .and_then(|(_, rest)| rest.rsplit_once("</additional>"))
            .map_or("", |(body, _)| body);
        let mut x = format!("{XML_HEAD}<routes>{types}");
        for (k, f) in self.layout.flows.iter().enumerate() {
            let mut kinds = vec![("mix", f.vehicles_s)];
            if f.bicycles {
                kinds.push(("bicycle", 0.05 * f.vehicles_s));
            }
            for (kind, p) in kinds {
                let _ = writeln!(
                    x,
                    "    <flow id=\"{kind}_{k}\" type=\"{kind}\" begin=\"0\" end=\"3600\" \
                     probability=\"{:.5}\" from=\"{}\" to=\"{}\" departLane=\"best\" \
                     departSpeed=\"max\"/>",
                    p.min(1.0),
                    f.from,
                    f.to
                );
            }
        }
        let walks = &self.layout.walks;
        for (k, (from, to)) in walks.iter().enumerate() {
            let _ = writeln!(
                x,
                "    <personFlow id=\"ped_{k}\" type=\"ped\" begin=\"0\" end=\"3600\" \
                 probability=\"{:.5}\"><walk from=\"{from}\" to=\"{to}\"/></personFlow>",
                self.pedestrians_s / walks.len() as f64,
            );
        }
        x + "</routes>\n"
    }

    /// The SUMO configuration.
    pub fn sumocfg_xml(&self) -> String {
        format!(
            "{XML_HEAD}<configuration>\n    <input>\n        <net-file value=\"net.net.xml\"/>\n        \
             <route-files value=\"routes.rou.xml\"/>\n        \
             <additional-files value=\"buildings.poly.xml\"/>\n    </input>\n    <time>\n        \
             <begin value=\"0\"/>\n        <step-length value=\"0.5\"/>\n    </time>\n    \
             <processing>\n        <pedestrian.model value=\"striping\"/>\n    </processing>\n    \
             <report>\n        <no-step-log value=\"true\"/>\n        \
             <no-warnings value=\"true\"/>\n    </report>\n</configuration>\n"
        )
    }

    /// A coid config holding only what a user would write.
    pub fn coid_toml(&self) -> String {
        format!(
            "# {}\n[scenario]\nsumocfg = \"scenario.sumocfg\"\njunction = \"{JUNCTION_ID}\"\n\
             end_s = {END_S:.1}\n\n[connected]\npenetration = {PENETRATION}\n",
            self.describe()
        )
    }

    /// netconvert's arguments for the plain files in the scenario folder.
    pub fn netconvert_args(&self) -> Vec<String> {
        let mut args: Vec<String> = [
            "--node-files",
            "net.nod.xml",
            "--edge-files",
            "net.edg.xml",
            "--crossings.guess",
            "true",
            "--walkingareas",
            "true",
            "--tls.default-type",
            "static",
            "--junctions.corner-detail",
            "5",
            "--no-turnarounds",
            "true",
            "--offset.disable-normalization",
            "true",
            "--output-file",
            "net.net.xml",
        ]
        .map(str::to_owned)
        .to_vec();
        if let Some(within) = self.layout.join_within_m {
            args.extend([
                "--junctions.join".to_owned(),
                "true".to_owned(),
                "--junctions.join-dist".to_owned(),
                format!("{within:.1}"),
                "--tls.join".to_owned(),
                "true".to_owned(),
            ]);
        }
        args
    }

    /// Every text file of the folder except the net, by name.
    pub fn files(&self) -> Vec<(&'static str, String)> {
        vec![
            ("net.nod.xml", self.nodes_xml()),
            ("net.edg.xml", self.edges_xml()),
            ("buildings.poly.xml", self.buildings_xml()),
            ("routes.rou.xml", self.routes_xml()),
            ("scenario.sumocfg", self.sumocfg_xml()),
            ("coid.toml", self.coid_toml()),
            ("README.md", format!("{}\n", self.describe())),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_texts_other_seed_other_texts() {
        let a = generate(5, 3, &[]);
        let b = generate(5, 3, &[]);
        assert_eq!(a.files(), b.files());
        assert_ne!(generate(6, 3, &[]).files(), a.files());
        assert_ne!(generate(5, 4, &[]).files(), a.files());
    }

    #[test]
    fn kinds_can_be_chosen_and_the_family_draws_every_kind() {
        let family: Vec<Scenario> = (0..80).map(|i| generate(11, i, &[])).collect();
        for &kind in Kind::all() {
            assert!(family.iter().any(|s| s.kind == kind), "no {kind:?}");
            assert!((0..5).all(|i| generate(11, i, &[kind]).kind == kind));
        }
        let two = [Kind::Roundabout, Kind::Ramp];
        assert!((0..20).all(|i| two.contains(&generate(3, i, &two).kind)));
    }

    /// Every flow and walk names edges of the network, every edge joins
    /// two nodes, no building stands on a road or on another building or
    /// near the junction, and the ring of a roundabout is closed.
    #[test]
    fn every_layout_keeps_its_rules() {
        for i in 0..60 {
            let s = generate(11, i, &[]);
            let l = &s.layout;
            let node = |id: &str| l.nodes.iter().any(|n| n.id == id);
            let road = |id: &str| l.roads.iter().any(|r| r.id == id);
            assert!(node(JUNCTION_ID), "{}", s.describe());
            for r in &l.roads {
                assert!(node(&r.from) && node(&r.to) && r.from != r.to, "{}", r.id);
            }
            for f in &l.flows {
                assert!(road(&f.from) && road(&f.to) && f.vehicles_s > 0.0, "{f:?}");
            }
            for (a, b) in &l.walks {
                assert!(road(a) && road(b));
            }
            for (k, b) in s.buildings.iter().enumerate() {
                for strip in &l.strips {
                    assert!(
                        !overlap(&strip.footprint(s.setback_m - 0.1), b),
                        "{}",
                        s.name
                    );
                }
                for other in &s.buildings[k + 1..] {
                    assert!(!overlap(b, other), "{}", s.name);
                }
                assert!(b.vertices_m.iter().all(|c| c.norm() > CLEAR_OF_JUNCTION_M));
            }
            assert_eq!(l.roundabout.is_some(), s.kind == Kind::Roundabout);
            if let Some((nodes, edges)) = &l.roundabout {
                assert_eq!(nodes.len(), edges.len());
                for (k, e) in edges.iter().enumerate() {
                    let r = l.roads.iter().find(|r| &r.id == e).unwrap();
                    assert_eq!((&r.from, &r.to), (&nodes[k], &nodes[(k + 1) % nodes.len()]));
                }
            }
            assert_eq!(l.join_within_m.is_some(), s.kind == Kind::Cluster);
        }
    }

    #[test]
    fn the_crossings_cover_the_ranges() {
        let family: Vec<Scenario> = (0..40)
            .map(|i| generate(11, i, &[Kind::Crossing]))
            .collect();
        let legs: Vec<usize> = family.iter().map(|s| s.layout.nodes.len() - 1).collect();
        for n in 3..=5 {
            assert!(legs.contains(&n), "no crossing with {n} legs");
        }
        for lanes in 1..=3 {
            assert!(
                family
                    .iter()
                    .any(|s| s.layout.roads.iter().any(|r| r.lanes == lanes))
            );
        }
        let lights = |s: &Scenario| s.layout.nodes[0].control == Control::TrafficLight;
        assert!(family.iter().any(lights) && !family.iter().all(lights));
        assert!(family.iter().any(|s| s.buildings.is_empty()));
        assert!(family.iter().any(|s| s.buildings.len() > 8));
        assert!(family.iter().any(|s| s.vehicles_per_lane_s > 0.2));
        for s in &family {
            let mut angles: Vec<f64> = s.layout.nodes[1..]
                .iter()
                .map(|n| n.at_m.y.atan2(n.at_m.x).rem_euclid(TAU))
                .collect();
            angles.sort_by(f64::total_cmp);
            assert!(min_gap_rad(&angles) >= 50f64.to_radians() - 1e-9);
        }
    }

    #[test]
    fn overlap_of_rectangles() {
        let a = rectangle(Vec2::zeros(), 0.0, 10.0, 4.0);
        assert!(overlap(&a, &rectangle(Vec2::new(4.0, 0.0), 0.3, 4.0, 4.0)));
        assert!(!overlap(
            &a,
            &rectangle(Vec2::new(12.0, 0.0), 0.3, 4.0, 4.0)
        ));
        // One inside the other.
        assert!(overlap(&a, &rectangle(Vec2::zeros(), 0.0, 2.0, 1.0)));
    }

    #[test]
    fn demand_names_every_approach_pair_once() {
        let s = generate(2, 0, &[Kind::Crossing]);
        let n = s.layout.nodes.len() - 1;
        let routes = s.routes_xml();
        assert_eq!(routes.matches("<flow id=\"mix_").count(), n * (n - 1));
        assert_eq!(routes.matches("<personFlow").count(), n * (n - 1));
        assert!(routes.contains("vTypeDistribution id=\"mix\""));
        // No bicycle on the motorway.
        let ramp = generate(2, 0, &[Kind::Ramp]).routes_xml();
        assert!(ramp.contains("from=\"M1\""));
        assert!(
            !ramp
                .lines()
                .any(|l| l.contains("type=\"bicycle\"") && l.contains("from=\"M1\""))
        );
    }
}
