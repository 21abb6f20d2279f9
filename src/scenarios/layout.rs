//! What a generated junction is made of: nodes, roads, the strips
//! beside roads where buildings may stand, flows, and the layout that
//! holds them.

use super::LANE_WIDTH_M;
use super::buildings::rectangle;
use crate::geometry::{Polygon, Vec2};

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
    pub(super) fn length_m(&self) -> f64 {
        (self.b - self.a).norm()
    }

    pub(super) fn direction(&self) -> Vec2 {
        (self.b - self.a) / self.length_m().max(1e-9)
    }

    /// The pavement's footprint, `margin_m` wider on each side.
    pub(super) fn footprint(&self, margin_m: f64) -> Polygon {
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
    pub(super) fn node(&mut self, id: &str, at_m: Vec2, control: Control) {
        self.nodes.push(Node {
            id: id.to_owned(),
            at_m,
            control,
        });
    }

    pub(super) fn at(&self, id: &str) -> Vec2 {
        self.nodes
            .iter()
            .find(|n| n.id == id)
            .map_or(Vec2::zeros(), |n| n.at_m)
    }

    /// A one-way edge `from -> to`.
    pub(super) fn road(
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
    pub(super) fn street(
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

    pub(super) fn strip(&mut self, from: &str, to: &str, half_width_m: f64) {
        let (a, b) = (self.at(from), self.at(to));
        self.strips.push(Strip { a, b, half_width_m });
    }

    /// Flows from every `(in edge, lanes)` to every out edge of another
    /// approach, the approach's rate shared evenly, with walks between
    /// the same edges when `walks`.
    pub(super) fn all_to_all(
        &mut self,
        approaches: &[(String, String, u32)],
        per_lane_s: f64,
        walks: bool,
    ) {
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
