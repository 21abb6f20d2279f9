//! A family of generated intersections: SUMO plain-XML networks (nodes,
//! edges), building blocks, demand and a coid config, drawn from a seed.
//!
//! Each scenario is one junction `C` at the origin with 3, 4 or 5 legs at
//! varied angles, 1-3 lanes per direction per leg, a traffic light or a
//! priority rule, sidewalks (netconvert guesses the crossings), building
//! blocks along the legs at a varied setback (or none), and random flows
//! from every leg to every other at a demand level between light and
//! saturated, with the shipped intersection's vehicle classes and colours
//! and pedestrians. Connected vehicles are a penetration share, never
//! fixed routes. This module only builds the texts (metres, the SUMO net
//! frame, angles counter-clockwise from east); `io` writes them and
//! `bridge` runs netconvert.

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

/// One leg of the junction: a road from an outer node to `C` and back.
#[derive(Clone, Debug, PartialEq)]
pub struct Leg {
    /// Direction from `C` to the outer node, counter-clockwise from east.
    pub angle_rad: f64,
    pub length_m: f64,
    /// Lanes per direction.
    pub lanes: u32,
    pub speed_mps: f64,
    pub sidewalk_m: f64,
}

impl Leg {
    fn direction(&self) -> Vec2 {
        Vec2::new(self.angle_rad.cos(), self.angle_rad.sin())
    }

    /// Half the paved width: both directions' lanes and a sidewalk each side.
    fn half_width_m(&self) -> f64 {
        f64::from(self.lanes) * LANE_WIDTH_M + self.sidewalk_m
    }

    /// The road's footprint, `margin_m` wider on each side.
    fn footprint(&self, margin_m: f64) -> Polygon {
        rectangle(
            self.direction() * (self.length_m / 2.0),
            self.angle_rad,
            self.length_m + 2.0 * margin_m,
            2.0 * (self.half_width_m() + margin_m),
        )
    }
}

/// One generated scenario.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// Folder name: `s000`, `s001`, ...
    pub name: String,
    pub seed: u64,
    pub index: u64,
    pub legs: Vec<Leg>,
    pub signalized: bool,
    /// Building footprints (world frame, metres).
    pub buildings: Vec<Polygon>,
    /// Distance kept between the paved road and a building, metres.
    pub setback_m: f64,
    /// Motor vehicles per second entering on each lane of each leg.
    pub vehicles_per_lane_s: f64,
    /// Pedestrians per second starting a walk across the junction.
    pub pedestrians_s: f64,
}

/// The `index`-th scenario of the family drawn from `seed`.
pub fn generate(seed: u64, index: u64) -> Scenario {
    let mut r = rng::stream(seed, Purpose::Scenario, &[index]);
    let legs = draw_legs(&mut r);
    let signalized = r.random_bool(0.6);
    let setback_m = r.random_range(3.0..12.0);
    let buildings = if r.random_bool(0.85) {
        draw_buildings(&mut r, &legs, setback_m)
    } else {
        Vec::new()
    };
    Scenario {
        name: format!("s{index:03}"),
        seed,
        index,
        legs,
        signalized,
        buildings,
        setback_m,
        vehicles_per_lane_s: r.random_range(0.03..0.20),
        pedestrians_s: r.random_range(0.02..0.12),
    }
}

/// 3-5 legs, at least 50 degrees apart.
fn draw_legs(r: &mut ChaCha8Rng) -> Vec<Leg> {
    let n = r.random_range(3..=5_u32);
    let rotation = r.random_range(0.0..TAU);
    let spacing = TAU / f64::from(n);
    let min_gap = 50f64.to_radians();
    let angles = loop {
        let mut a: Vec<f64> = (0..n)
            .map(|k| {
                let jitter = r.random_range(-0.3..0.3) * spacing;
                (rotation + f64::from(k) * spacing + jitter).rem_euclid(TAU)
            })
            .collect();
        a.sort_by(f64::total_cmp);
        let gaps_ok = (0..a.len()).all(|k| {
            let next = if k + 1 < a.len() {
                a[k + 1]
            } else {
                a[0] + TAU
            };
            next - a[k] >= min_gap
        });
        if gaps_ok {
            break a;
        }
    };
    angles
        .into_iter()
        .map(|angle_rad| {
            let lanes = match r.random_range(0.0..1.0) {
                x if x < 0.35 => 1,
                x if x < 0.8 => 2,
                _ => 3,
            };
            Leg {
                angle_rad,
                length_m: r.random_range(150.0..220.0),
                lanes,
                speed_mps: if lanes == 1 { 11.11 } else { 13.89 },
                sidewalk_m: r.random_range(2.0..3.0),
            }
        })
        .collect()
}

/// An oriented rectangle as a polygon.
fn rectangle(centre: Vec2, angle_rad: f64, length_m: f64, width_m: f64) -> Polygon {
    let (u, v) = (
        Vec2::new(angle_rad.cos(), angle_rad.sin()),
        Vec2::new(-angle_rad.sin(), angle_rad.cos()),
    );
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

/// Blocks along both sides of every leg, `setback_m` from the paved road,
/// none on another road or on another block.
fn draw_buildings(r: &mut ChaCha8Rng, legs: &[Leg], setback_m: f64) -> Vec<Polygon> {
    // Blocks may touch the setback line of their own leg, not cross it.
    let roads: Vec<Polygon> = legs.iter().map(|l| l.footprint(setback_m - 0.05)).collect();
    let clear_m = legs.iter().map(Leg::half_width_m).fold(0.0, f64::max) + setback_m + 5.0;
    let mut blocks: Vec<Polygon> = Vec::new();
    for leg in legs {
        let (u, v) = (
            leg.direction(),
            Vec2::new(-leg.angle_rad.sin(), leg.angle_rad.cos()),
        );
        for side in [1.0, -1.0] {
            let mut s = clear_m + r.random_range(0.0..10.0);
            while s < leg.length_m - 20.0 {
                let length = r.random_range(15.0..40.0);
                let depth = r.random_range(12.0..30.0);
                let offset = leg.half_width_m() + setback_m + depth / 2.0;
                let centre = u * (s + length / 2.0) + v * (side * offset);
                let block = rectangle(centre, leg.angle_rad, length, depth);
                let free = block.vertices_m.iter().all(|c| c.norm() > clear_m)
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

fn inbound(k: usize) -> String {
    format!("L{k}in")
}

fn outbound(k: usize) -> String {
    format!("L{k}out")
}

const XML_HEAD: &str = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";

impl Scenario {
    /// One line for a person: what was drawn.
    pub fn describe(&self) -> String {
        let angles: Vec<String> = self
            .legs
            .iter()
            .map(|l| format!("{:.0}", l.angle_rad.to_degrees()))
            .collect();
        let lanes: Vec<String> = self.legs.iter().map(|l| l.lanes.to_string()).collect();
        format!(
            "{}: {} legs at {} deg, {} lanes per direction, {}, building blocks: {} (setback {:.1} m), \
             {:.0} vehicles/h per lane, {:.0} pedestrians/h (family seed {}, index {})",
            self.name,
            self.legs.len(),
            angles.join("/"),
            lanes.join("/"),
            if self.signalized {
                "traffic light"
            } else {
                "priority"
            },
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
        let kind = if self.signalized {
            "traffic_light"
        } else {
            "priority"
        };
        let _ = writeln!(
            x,
            "    <node id=\"{JUNCTION_ID}\" x=\"0.00\" y=\"0.00\" type=\"{kind}\"/>"
        );
        for (k, leg) in self.legs.iter().enumerate() {
            let p = leg.direction() * leg.length_m;
            let _ = writeln!(
                x,
                "    <node id=\"O{k}\" x=\"{:.2}\" y=\"{:.2}\" type=\"priority\"/>",
                p.x, p.y
            );
        }
        x + "</nodes>\n"
    }

    /// netconvert's edge file: both directions of every leg, with sidewalks.
    pub fn edges_xml(&self) -> String {
        let mut x = format!("{XML_HEAD}<edges>\n");
        for (k, leg) in self.legs.iter().enumerate() {
            for (id, from, to) in [
                (inbound(k), format!("O{k}"), JUNCTION_ID.to_owned()),
                (outbound(k), JUNCTION_ID.to_owned(), format!("O{k}")),
            ] {
                let _ = writeln!(
                    x,
                    "    <edge id=\"{id}\" from=\"{from}\" to=\"{to}\" numLanes=\"{}\" \
                     speed=\"{:.2}\" sidewalkWidth=\"{:.2}\"/>",
                    leg.lanes, leg.speed_mps, leg.sidewalk_m
                );
            }
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

    /// The demand: the shipped types, vehicle flows from every leg to every
    /// other (random departures from SUMO's seed), bicycles, pedestrians.
    pub fn routes_xml(&self) -> String {
        let types = VTYPES
            .split_once("<additional>")
            .and_then(|(_, rest)| rest.rsplit_once("</additional>"))
            .map_or("", |(body, _)| body);
        let mut x = format!("{XML_HEAD}<routes>{types}");
        let n = self.legs.len();
        let share = 1.0 / (n - 1) as f64;
        for (a, leg) in self.legs.iter().enumerate() {
            for b in (0..n).filter(|&b| b != a) {
                let rate = self.vehicles_per_lane_s * f64::from(leg.lanes) * share;
                for (kind, p) in [("mix", rate), ("bicycle", 0.05 * rate)] {
                    let _ = writeln!(
                        x,
                        "    <flow id=\"{kind}_{a}_{b}\" type=\"{kind}\" begin=\"0\" end=\"3600\" \
                         probability=\"{:.5}\" from=\"{}\" to=\"{}\" departLane=\"best\" \
                         departSpeed=\"max\"/>",
                        p.min(1.0),
                        inbound(a),
                        outbound(b)
                    );
                }
                let _ = writeln!(
                    x,
                    "    <personFlow id=\"ped_{a}_{b}\" type=\"ped\" begin=\"0\" end=\"3600\" \
                     probability=\"{:.5}\"><walk from=\"{}\" to=\"{}\"/></personFlow>",
                    self.pedestrians_s / (n * (n - 1)) as f64,
                    inbound(a),
                    outbound(b)
                );
            }
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
    pub fn netconvert_args() -> Vec<String> {
        [
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
        .to_vec()
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

/// Smallest angle between consecutive legs, radians (for checks).
pub fn min_leg_gap_rad(legs: &[Leg]) -> f64 {
    let mut a: Vec<f64> = legs.iter().map(|l| l.angle_rad).collect();
    a.sort_by(f64::total_cmp);
    (0..a.len())
        .map(|k| {
            let next = if k + 1 < a.len() {
                a[k + 1]
            } else {
                a[0] + TAU
            };
            next - a[k]
        })
        .fold(PI * 2.0, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_texts_other_seed_other_texts() {
        let a = generate(5, 3);
        let b = generate(5, 3);
        assert_eq!(a.files(), b.files());
        assert_ne!(generate(6, 3).files(), a.files());
        assert_ne!(generate(5, 4).files(), a.files());
    }

    #[test]
    fn the_family_covers_the_ranges_and_keeps_its_rules() {
        let family: Vec<Scenario> = (0..60).map(|i| generate(11, i)).collect();
        let legs: Vec<usize> = family.iter().map(|s| s.legs.len()).collect();
        for n in 3..=5 {
            assert!(legs.contains(&n), "no scenario with {n} legs");
        }
        for lanes in 1..=3 {
            assert!(
                family
                    .iter()
                    .any(|s| s.legs.iter().any(|l| l.lanes == lanes))
            );
        }
        assert!(family.iter().any(|s| s.signalized) && family.iter().any(|s| !s.signalized));
        assert!(family.iter().any(|s| s.buildings.is_empty()));
        assert!(family.iter().any(|s| s.buildings.len() > 8));
        for s in &family {
            assert!(min_leg_gap_rad(&s.legs) >= 50f64.to_radians() - 1e-9);
            // No building on a road (paved width plus the setback) or on
            // another building.
            for (k, b) in s.buildings.iter().enumerate() {
                for leg in &s.legs {
                    assert!(!overlap(&leg.footprint(s.setback_m - 0.1), b), "{}", s.name);
                }
                for other in &s.buildings[k + 1..] {
                    assert!(!overlap(b, other), "{}", s.name);
                }
            }
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
    fn demand_names_every_leg_pair_once() {
        let s = generate(2, 0);
        let n = s.legs.len();
        let routes = s.routes_xml();
        assert_eq!(routes.matches("<flow id=\"mix_").count(), n * (n - 1));
        assert_eq!(routes.matches("<personFlow").count(), n * (n - 1));
        assert!(routes.contains("vTypeDistribution id=\"mix\""));
    }
}
