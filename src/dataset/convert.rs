//! `coid convert pyg`: PyTorch Geometric pair data as DMGM distributes it
//! (`<source>/proc_s/<k>/data.pt` and `<source>/proc_t/<k>/data.pt`, one
//! `Data` per view) into a dataset. Each view's fields:
//!
//! - `pos` [n, 3]: each detection in the camera frame (x right, y down,
//!   z forward, metres) -> body frame x forward = z, y left = -x;
//! - `pos_world` [n, 3], optional: the same through the vehicle's GPS
//!   pose, in CARLA's left-handed world (x, y on the ground, z up) ->
//!   `world_x_m` = x, `world_y_m` = -y (right-handed, as coid's world);
//! - `x` [n, d], optional: the appearance vector;
//! - `y` [n]: object ids (equal id, same object; once per view);
//! - `label` [n], optional: COCO class ids (person, bicycle, car,
//!   motorcycle, bus, truck);
//! - `name`, optional: `<...>/<recording>_<frame>`: pairs of one
//!   recording in one split make one run, the frame its instance's step.
//!
//! The pairs are read in index order; the split of each comes from index
//! ranges the user gives. Nothing of the `.pt` files is run
//! ([`crate::io::torch`]).

use std::ops::RangeInclusive;
use std::path::PathBuf;

use super::schema::{Edge, Instance, Node, Run, TruePair, Truth};
use crate::geometry::Vec2;
use crate::graph::SceneGraph;
use crate::io::torch::{self, Field, Graph};
use crate::report::Table;

/// What a conversion reads and how it labels it.
pub struct PygSource {
    /// The folder holding one folder per view (`proc_s`, `proc_t`).
    pub dir: PathBuf,
    /// The views' folder names: the first and the second vehicle.
    pub views: [String; 2],
    /// Each split's pair indices, in order.
    pub splits: Vec<(String, RangeInclusive<u64>)>,
    /// The source's name (`dmgm`): runs are `<name>/<recording>`.
    pub name: String,
    /// The GPS accuracy the source's world positions were made with.
    pub position_sigma_m: f64,
    pub heading_sigma_rad: f64,
}

/// One pair's rows.
#[derive(Default)]
pub struct PairRows {
    pub instance: Vec<Instance>,
    pub nodes: Vec<Node>,
    pub edges: Vec<Edge>,
    pub truth: Vec<Truth>,
    pub true_pairs: Vec<TruePair>,
}

impl PairRows {
    /// The rows as each instance file's table, in file order.
    pub fn tables(self) -> [(&'static str, Table); 5] {
        [
            (Instance::FILE, Instance::table(self.instance)),
            (Node::FILE, Node::table(self.nodes)),
            (Edge::FILE, Edge::table(self.edges)),
            (Truth::FILE, Truth::table(self.truth)),
            (TruePair::FILE, TruePair::table(self.true_pairs)),
        ]
    }

    fn extend(&mut self, other: PairRows) {
        self.instance.extend(other.instance);
        self.nodes.extend(other.nodes);
        self.edges.extend(other.edges);
        self.truth.extend(other.truth);
        self.true_pairs.extend(other.true_pairs);
    }
}

/// A run of the conversion: its rows of `runs.parquet`.
pub struct ConvertedRun {
    pub split: String,
    pub scenario: String,
    pub n_instances: u64,
}

impl PygSource {
    /// Every pair index of the splits, with its split, in order; refused
    /// when ranges overlap.
    pub fn pairs(&self) -> Result<Vec<(u64, &str)>, String> {
        let mut out: Vec<(u64, &str)> = Vec::new();
        for (split, range) in &self.splits {
            out.extend(range.clone().map(|k| (k, split.as_str())));
        }
        out.sort_by_key(|&(k, _)| k);
        if let Some(w) = out.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(format!("pair {} lies in two splits' ranges", w[0].0));
        }
        Ok(out)
    }

    fn path(&self, view: usize, k: u64) -> PathBuf {
        self.dir
            .join(&self.views[view])
            .join(k.to_string())
            .join("data.pt")
    }

    /// Pair `k`'s two views, read and checked.
    pub fn read_pair(&self, k: u64) -> Result<[View; 2], String> {
        let view = |v: usize| -> Result<View, String> {
            let path = self.path(v, k);
            let graphs = torch::read_graphs(&path).map_err(|e| e.to_string())?;
            let [g] = graphs.as_slice() else {
                return Err(format!(
                    "{} holds {} graphs, not one view",
                    path.display(),
                    graphs.len()
                ));
            };
            View::of(g).map_err(|why| format!("{}: {why}", path.display()))
        };
        Ok([view(0)?, view(1)?])
    }
}

/// One vehicle's view of a pair, in coid's frames.
pub struct View {
    pub body_m: Vec<Vec2>,
    pub world_m: Option<Vec<Vec2>>,
    pub appearance: Option<Vec<Vec<f32>>>,
    pub ids: Vec<String>,
    pub classes: Vec<&'static str>,
    /// The recording and frame, from `name`.
    pub recording: Option<(String, u64)>,
}

/// A tensor field's shape and values.
type TensorRef<'g> = (&'g [usize], &'g [f64]);

fn tensor<'g>(g: &'g Graph, name: &str) -> Result<Option<TensorRef<'g>>, String> {
    match g.get(name) {
        None => Ok(None),
        Some(Field::Tensor { shape, values }) => Ok(Some((shape, values))),
        Some(_) => Err(format!("its '{name}' is not a tensor")),
    }
}

/// `n` rows of 3 columns.
fn points(g: &Graph, name: &str, n: usize) -> Result<Option<Vec<[f64; 3]>>, String> {
    let Some((shape, v)) = tensor(g, name)? else {
        return Ok(None);
    };
    if shape != [n, 3] {
        return Err(format!("its '{name}' has shape {shape:?}, not [{n}, 3]"));
    }
    if let Some(k) = v.iter().position(|x| !x.is_finite()) {
        return Err(format!("its '{name}' holds {} in row {}", v[k], k / 3));
    }
    Ok(Some(v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()))
}

/// coid's class of a COCO class id.
fn coco_class(id: f64) -> Option<&'static str> {
    Some(match id as i64 {
        0 => "pedestrian",
        1 => "bicycle",
        2 => "car",
        3 => "motorcycle",
        5 => "bus",
        7 => "truck",
        _ => return None,
    })
}

impl View {
    fn of(g: &Graph) -> Result<View, String> {
        let (shape, y) = tensor(g, "y")?.ok_or("it has no 'y' (object ids)")?;
        let n = shape.first().copied().unwrap_or(0);
        if shape.len() != 1 {
            return Err(format!("its 'y' has shape {shape:?}, not [n]"));
        }
        let pos = points(g, "pos", n)?.ok_or("it has no 'pos' (camera-frame positions)")?;
        let body_m = pos.iter().map(|p| Vec2::new(p[2], -p[0])).collect();
        let world_m =
            points(g, "pos_world", n)?.map(|w| w.iter().map(|p| Vec2::new(p[0], -p[1])).collect());
        let appearance = match tensor(g, "x")? {
            None => None,
            Some((shape, v)) => {
                let [rows, d] = shape else {
                    return Err(format!("its 'x' has shape {shape:?}, not [{n}, d]"));
                };
                if *rows != n || *d == 0 {
                    return Err(format!("its 'x' has shape {shape:?}, not [{n}, d]"));
                }
                Some(
                    v.chunks(*d)
                        .map(|c| c.iter().map(|&x| x as f32).collect())
                        .collect(),
                )
            }
        };
        let mut ids: Vec<String> = Vec::with_capacity(n);
        for (k, &id) in y.iter().enumerate() {
            if id.fract() != 0.0 || !id.is_finite() {
                return Err(format!("its 'y' holds {id} in row {k}, not an object id"));
            }
            let id = format!("{id:.0}");
            if let Some(first) = ids.iter().position(|x| *x == id) {
                return Err(format!(
                    "its 'y' names object {id} twice (rows {first} and {k})"
                ));
            }
            ids.push(id);
        }
        let classes = match tensor(g, "label")? {
            None => vec!["car"; n],
            Some((_, labels)) if labels.len() == n => labels
                .iter()
                .enumerate()
                .map(|(k, &l)| {
                    coco_class(l).ok_or_else(|| {
                        format!("its 'label' holds COCO class {l} in row {k}, not a road user")
                    })
                })
                .collect::<Result<_, _>>()?,
            Some((shape, _)) => return Err(format!("its 'label' has shape {shape:?}")),
        };
        let recording = match g.get("name") {
            Some(Field::Text(name)) => {
                let last = name.rsplit('/').next().unwrap_or(name);
                last.rsplit_once('_')
                    .and_then(|(r, f)| Some((r.to_owned(), f.parse().ok()?)))
            }
            _ => None,
        };
        Ok(View {
            body_m,
            world_m,
            appearance,
            ids,
            classes,
            recording,
        })
    }
}

/// Accumulates the conversion: runs (a recording's consecutive pairs in
/// one split) and their instances' rows.
#[derive(Default)]
pub struct Converter {
    pub runs: Vec<ConvertedRun>,
    pending: PairRows,
    width: Option<usize>,
}

impl Converter {
    /// Adds pair `k` of `split` (its views `views`) as the next instance.
    pub fn add(
        &mut self,
        source: &PygSource,
        k: u64,
        split: &str,
        views: [View; 2],
    ) -> Result<(), String> {
        let recording = views[0].recording.clone();
        let scenario = match &recording {
            Some((r, _)) => format!("{}/{r}", source.name),
            None => source.name.clone(),
        };
        let same_run = self
            .runs
            .last()
            .is_some_and(|r| r.split == split && r.scenario == scenario);
        if !same_run {
            self.runs.push(ConvertedRun {
                split: split.to_owned(),
                scenario,
                n_instances: 0,
            });
        }
        let run = (self.runs.len() - 1) as u64;
        let r = self.runs.last_mut().expect("pushed above");
        let instance = r.n_instances;
        r.n_instances += 1;
        for v in &views {
            if let Some(a) = &v.appearance {
                let d = a.first().map_or(0, Vec::len);
                match self.width {
                    Some(w) if d != 0 && w != d => {
                        return Err(format!(
                            "pair {k}: appearance vectors of {d} values, earlier pairs' of {w}"
                        ));
                    }
                    None if d != 0 => self.width = Some(d),
                    _ => {}
                }
            }
        }
        let step = recording.map_or(k, |(_, f)| f);
        let rows = pair_rows(source, (run, instance, step), &views)
            .map_err(|why| format!("pair {k}: {why}"))?;
        self.pending.extend(rows);
        Ok(())
    }

    /// The rows held so far (no longer held).
    pub fn take(&mut self) -> PairRows {
        std::mem::take(&mut self.pending)
    }

    /// Node rows held.
    pub fn held(&self) -> usize {
        self.pending.nodes.len()
    }

    /// The runs' rows.
    pub fn run_table(&self, version: u64) -> Table {
        Run::table(
            self.runs
                .iter()
                .enumerate()
                .map(|(k, r)| Run {
                    schema_version: version,
                    run: k as u64,
                    split: r.split.clone(),
                    scenario: r.scenario.clone(),
                    // Nothing was drawn: the run's number keys the
                    // streams coid draws for it (the deep methods'
                    // dropout masks).
                    seed: k as u64,
                    n_instances: r.n_instances,
                    config_digest: String::new(),
                })
                .collect(),
        )
    }
}

/// One pair's rows: an instance at the level `gps` (the source's GPS
/// noise), each view's nodes, Delaunay edges and truth, and the true pairs
/// (equal object ids).
fn pair_rows(
    source: &PygSource,
    (run, instance, step): (u64, u64, u64),
    views: &[View; 2],
) -> Result<PairRows, String> {
    let mut rows = PairRows::default();
    rows.instance
        .push(instance_row(source, (run, instance, step), views));
    for (side, v) in views.iter().enumerate() {
        let side = side as u64;
        let graph = SceneGraph::delaunay(&v.body_m).map_err(|e| e.to_string())?;
        for (k, p) in v.body_m.iter().enumerate() {
            let world = v.world_m.as_ref().map(|w| w[k]);
            rows.nodes.push(Node {
                run,
                instance,
                side,
                node: k as u64,
                x_m: p.x,
                y_m: p.y,
                cov_xx_m2: None,
                cov_xy_m2: None,
                cov_yy_m2: None,
                class: v.classes[k].to_owned(),
                colour_r: None,
                colour_g: None,
                colour_b: None,
                length_m: None,
                width_m: None,
                height_m: None,
                heading_rad: None,
                speed_mps: None,
                sender: None,
                world_x_m: world.map(|w| w.x),
                world_y_m: world.map(|w| w.y),
                appearance: v.appearance.as_ref().map(|a| a[k].clone()),
            });
            rows.truth.push(Truth {
                run,
                instance,
                side,
                node: k as u64,
                object_id: v.ids[k].clone(),
                true_x_m: None,
                true_y_m: None,
                visible_fraction: None,
            });
        }
        rows.edges.extend(graph.edges.iter().map(|e| Edge {
            run,
            instance,
            side,
            source: e.a as u64,
            target: e.b as u64,
            length_m: e.length_m,
        }));
    }
    for (a, id) in views[0].ids.iter().enumerate() {
        if let Some(b) = views[1].ids.iter().position(|x| x == id) {
            rows.true_pairs.push(TruePair {
                run,
                instance,
                a: a as u64,
                b: b as u64,
            });
        }
    }
    Ok(rows)
}

/// A pair's instance row: the level `gps`, the source's GPS accuracy, no
/// reported or true poses (the nodes' world positions stand for them).
fn instance_row(
    source: &PygSource,
    (run, instance, step): (u64, u64, u64),
    views: &[View; 2],
) -> Instance {
    Instance {
        run,
        instance,
        pose_noise: "gps".to_owned(),
        step,
        time_s: None,
        first_id: source.views[0].clone(),
        second_id: source.views[1].clone(),
        n_first: views[0].ids.len() as u64,
        n_second: views[1].ids.len() as u64,
        first_x_m: None,
        first_y_m: None,
        first_heading_rad: None,
        second_x_m: None,
        second_y_m: None,
        second_heading_rad: None,
        position_sigma_m: source.position_sigma_m,
        first_heading_sigma_rad: source.heading_sigma_rad,
        second_heading_sigma_rad: source.heading_sigma_rad,
        first_true_x_m: None,
        first_true_y_m: None,
        first_true_heading_rad: None,
        second_true_x_m: None,
        second_true_y_m: None,
        second_true_heading_rad: None,
    }
}
