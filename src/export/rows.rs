//! What an instance becomes in the export: its rows of every instance file
//! ([`Rows`], held until written as row groups) and a method's matches.

use crate::dataset::schema::{Edge, Instance, Match, Node, TruePair, Truth};
use crate::evaluate::{FrameEval, PairAtLevel, Side};
use crate::io::{OutputError, TablesFolder};
use crate::matching::oracle;
use crate::pipeline;
use crate::report::Table;

/// The rows of the export's instance files, held until written.
#[derive(Default)]
pub(super) struct Rows {
    instances: Vec<Instance>,
    nodes: Vec<Node>,
    edges: Vec<Edge>,
    truth: Vec<Truth>,
    true_pairs: Vec<TruePair>,
    /// The width of the sensor's descriptors: a node without one
    /// beside described nodes is written as that many zeros.
    pub(super) appearance_width: crate::sensor::AppearanceWidth,
}

impl Rows {
    /// Node rows held.
    pub(super) fn held(&self) -> usize {
        self.nodes.len()
    }

    /// The held rows as each instance file's table, in file order (no
    /// longer held).
    pub(super) fn take(&mut self) -> [(&'static str, Table); 5] {
        let width = self.appearance_width;
        let rows = std::mem::replace(
            self,
            Rows {
                appearance_width: width,
                ..Rows::default()
            },
        );
        [
            (Instance::FILE, Instance::table(rows.instances)),
            (Node::FILE, Node::table(rows.nodes)),
            (Edge::FILE, Edge::table(rows.edges)),
            (Truth::FILE, Truth::table(rows.truth)),
            (TruePair::FILE, TruePair::table(rows.true_pairs)),
        ]
    }

    /// Writes every held row as row groups.
    pub(super) fn write(&mut self, out: &mut TablesFolder) -> Result<(), OutputError> {
        for (file, table) in self.take() {
            out.write(file, &table)?;
        }
        Ok(())
    }

    /// The rows of a frame's instances at one level: one row each (the
    /// reported poses), and with `graphs` (at the first level: they are the
    /// same at every level) both vehicles' nodes, edges and truth, and the
    /// true pairs.
    pub(super) fn add(
        &mut self,
        run: usize,
        insts: &[pipeline::Instance],
        pairs: &[PairAtLevel],
        graphs: bool,
    ) {
        for (inst, pair) in insts.iter().zip(pairs) {
            let at = At {
                run: run as u64,
                instance: inst.index as u64,
            };
            if graphs {
                for (side, s) in [&pair.first, &pair.second].into_iter().enumerate() {
                    self.add_side(at, side as u64, s);
                }
                for c in oracle::true_pairs(pair.first.truth, pair.second.truth) {
                    self.true_pairs.push(TruePair {
                        run: at.run,
                        instance: at.instance,
                        a: c.a as u64,
                        b: c.b as u64,
                    });
                }
            }
            self.add_instance(at, inst, pair);
        }
    }

    /// An instance's row at one level.
    fn add_instance(&mut self, at: At, inst: &pipeline::Instance, pair: &PairAtLevel) {
        let first = pair.first.view.pose_reported;
        let second = pair.second.view.pose_reported;
        let (first_true, second_true) = (pair.first.truth.ego_pose, pair.second.truth.ego_pose);
        self.instances.push(Instance {
            run: at.run,
            instance: at.instance,
            pose_noise: pair.level.label.as_str().to_owned(),
            step: inst.frame.step,
            time_s: Some(inst.frame.time_s),
            first_id: pair.first.obs.ego_id.clone(),
            second_id: pair.second.obs.ego_id.clone(),
            n_first: pair.first.obs.detections.len() as u64,
            n_second: pair.second.obs.detections.len() as u64,
            first_x_m: Some(first.position_m().x),
            first_y_m: Some(first.position_m().y),
            first_heading_rad: Some(first.heading_rad()),
            second_x_m: Some(second.position_m().x),
            second_y_m: Some(second.position_m().y),
            second_heading_rad: Some(second.heading_rad()),
            position_sigma_m: pair.level.position_sigma_m,
            first_heading_sigma_rad: pair.first.view.pose_noise.heading_sigma_rad,
            second_heading_sigma_rad: pair.second.view.pose_noise.heading_sigma_rad,
            first_true_x_m: Some(first_true.position_m().x),
            first_true_y_m: Some(first_true.position_m().y),
            first_true_heading_rad: Some(first_true.heading_rad()),
            second_true_x_m: Some(second_true.position_m().x),
            second_true_y_m: Some(second_true.position_m().y),
            second_true_heading_rad: Some(second_true.heading_rad()),
        });
    }

    /// One vehicle's nodes, their truth and its graph's edges.
    fn add_side(&mut self, at: At, side: u64, s: &Side) {
        for (k, (d, truth)) in s.obs.detections.iter().zip(&s.truth.detections).enumerate() {
            let a = &d.appearance;
            let [colour_r, colour_g, colour_b] = a.colour_rgb;
            self.nodes.push(Node {
                run: at.run,
                instance: at.instance,
                side,
                node: k as u64,
                x_m: d.position_m.x,
                y_m: d.position_m.y,
                cov_xx_m2: Some(d.cov_m2[(0, 0)]),
                cov_xy_m2: Some(d.cov_m2[(0, 1)]),
                cov_yy_m2: Some(d.cov_m2[(1, 1)]),
                class: a.class.as_str().to_owned(),
                colour_r: Some(colour_r),
                colour_g: Some(colour_g),
                colour_b: Some(colour_b),
                length_m: Some(a.length_m),
                width_m: Some(a.width_m),
                height_m: Some(a.height_m),
                heading_rad: Some(d.motion.map_or(f64::NAN, |m| m.heading_rad)),
                speed_mps: Some(d.motion.map_or(f64::NAN, |m| m.speed_mps)),
                sender: Some(truth.sender),
                world_x_m: None,
                world_y_m: None,
                // Every node has one or none does: a node without a
                // descriptor (a sender's self-report) beside described
                // nodes is written as zeros.
                appearance: match (&a.descriptor, self.appearance_width.width()) {
                    (Some(d), _) => Some(d.values.to_vec()),
                    (None, Some(w)) => Some(vec![0.0; w]),
                    (None, None) => None,
                },
            });
            let p = truth.position_m;
            self.truth.push(Truth {
                run: at.run,
                instance: at.instance,
                side,
                node: k as u64,
                object_id: truth.object_id.clone().unwrap_or_default(),
                true_x_m: Some(p.map_or(f64::NAN, |p| p.x)),
                true_y_m: Some(p.map_or(f64::NAN, |p| p.y)),
                visible_fraction: Some(truth.visible_fraction),
            });
        }
        for e in &s.view.graph.edges {
            self.edges.push(Edge {
                run: at.run,
                instance: at.instance,
                side,
                source: e.a.min(e.b) as u64,
                target: e.a.max(e.b) as u64,
                length_m: e.length_m,
            });
        }
    }
}

/// An instance of a run, as its rows name it.
#[derive(Clone, Copy)]
struct At {
    run: u64,
    instance: u64,
}

/// A frame's decided matches at one level, as rows of a matches file.
pub(super) fn matches<'a>(
    run: usize,
    pairs: &'a [PairAtLevel],
    f: &'a FrameEval,
) -> impl Iterator<Item = Match> + 'a {
    pairs.iter().zip(&f.pairs).flat_map(move |(pair, e)| {
        e.identification.matches.iter().map(move |c| Match {
            run: run as u64,
            instance: pair.instance as u64,
            pose_noise: pair.level.label.as_str().to_owned(),
            a: c.a as u64,
            b: c.b as u64,
            probability: c.probability,
            uncertainty: c.uncertainty,
        })
    })
}
