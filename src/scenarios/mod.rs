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

use rand::Rng;

mod buildings;
mod files;
mod kinds;
mod layout;

pub use layout::*;

use crate::geometry::Polygon;
use crate::rng::{self, Purpose};
use kinds::{arterial, cluster, crossing, ramp, roundabout};

/// The junction every generated scenario is centred on.
pub const JUNCTION_ID: &str = "C";
/// Simulated seconds a generated scenario's config runs.
pub const END_S: f64 = 150.0;
/// Share of motor vehicles that are connected in a generated scenario.
pub const PENETRATION: f64 = 0.1;
/// Lane width (netconvert's default), metres.
pub(super) const LANE_WIDTH_M: f64 = 3.2;

/// The shipped intersection's vehicle and pedestrian types.
pub(super) const VTYPES: &str = include_str!("../../sumo_nets/vtypes.add.xml");

crate::label_enum! { "demand";
    /// Which road users the demand sends.
    #[strum(serialize_all = "lowercase")]
    pub enum Demand {
        /// The shipped intersection's vehicle classes, sizes and colour
        /// mix (`sumo_nets/vtypes.add.xml`), bicycles and pedestrians.
        Mix,
        /// SUMO's default types only, as demand made with SUMO's own tools
        /// usually is: every motor vehicle one passenger car of one size
        /// and SUMO's default colour, bicycles and pedestrians of SUMO's
        /// default types. Appearance then says almost nothing; only
        /// structure and positions can tell the objects apart.
        #[strum(serialize = "plain")]
        DefaultTypes,
    }
}

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
    /// Which road users the demand sends (not drawn: [`Demand::Mix`]
    /// unless the caller says otherwise, so a family's layouts do not
    /// depend on it).
    pub demand: Demand,
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
        buildings::draw_buildings(&mut r, &layout.strips, setback_m)
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
        demand: Demand::Mix,
    }
}
#[cfg(test)]
mod tests;
