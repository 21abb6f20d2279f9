//! A scenario as the texts SUMO and coid read: netconvert's node and edge
//! files and arguments, the buildings, the demand, the `.sumocfg` and a
//! `coid.toml`.

use std::fmt::Write as _;

use super::layout::Control;
use super::{Demand, END_S, JUNCTION_ID, PENETRATION, Scenario, VTYPES};

const XML_HEAD: &str = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";

impl Scenario {
    /// One line for a person: what was drawn.
    pub fn describe(&self) -> String {
        format!(
            "{}: {}: {}, building blocks: {} (setback {:.1} m), {:.0} vehicles/h per lane, \
             {:.0} pedestrians/h{} (family seed {}, index {})",
            self.name,
            self.kind.as_str(),
            self.layout.description,
            self.buildings.len(),
            self.setback_m,
            self.vehicles_per_lane_s * 3600.0,
            self.pedestrians_s * 3600.0,
            match self.demand {
                Demand::Mix => "",
                Demand::DefaultTypes => ", SUMO's default types only",
            },
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

    /// The demand: the layout's vehicle flows (random departures from
    /// SUMO's seed), bicycles and pedestrians, of the shipped types
    /// ([`Demand::Mix`]) or of SUMO's default ones ([`Demand::DefaultTypes`]).
    pub fn routes_xml(&self) -> String {
        // Flow ids stay the same for both demands; the types differ.
        let (types, [vehicle, bicycle, ped]) = match self.demand {
            Demand::Mix => (
                VTYPES
                    .split_once("<additional>")
                    .and_then(|(_, rest)| rest.rsplit_once("</additional>"))
                    .map_or("", |(body, _)| body),
                ["mix", "bicycle", "ped"],
            ),
            Demand::DefaultTypes => (
                "\n",
                ["DEFAULT_VEHTYPE", "DEFAULT_BIKETYPE", "DEFAULT_PEDTYPE"],
            ),
        };
        let mut x = format!("{XML_HEAD}<routes>{types}");
        for (k, f) in self.layout.flows.iter().enumerate() {
            let mut kinds = vec![("mix", vehicle, f.vehicles_s)];
            if f.bicycles {
                kinds.push(("bicycle", bicycle, 0.05 * f.vehicles_s));
            }
            for (id, kind, p) in kinds {
                let _ = writeln!(
                    x,
                    "    <flow id=\"{id}_{k}\" type=\"{kind}\" begin=\"0\" end=\"3600\" \
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
                "    <personFlow id=\"ped_{k}\" type=\"{ped}\" begin=\"0\" end=\"3600\" \
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
