//! One run's instances put together from their rows as the reader reads
//! them: an instance from its rows at every level, its nodes, their
//! truth and the true pairs, each checked against what came before
//! (node counts, an object once per vehicle, a pair of one object), and
//! each vehicle's pose at every level.

use super::read::{
    DatasetError, DatasetInstance, DatasetNode, DatasetSide, InstanceLevel, SIDES, refuse,
};
use super::schema::{Instance, Node, TruePair, Truth};
use std::sync::Arc;

use crate::geometry::{Cov2, Pose2, Vec2, fit_rigid};

/// An instance from its rows (one per level), before its nodes: poses are
/// set once the nodes are read ([`set_poses`]).
pub(super) fn instance_of(rows: &[Instance]) -> DatasetInstance {
    let r = &rows[0];
    let pose = |x: Option<f64>, y: Option<f64>, h: Option<f64>| {
        Some(Pose2::new(Vec2::new(x?, y?), h?)).filter(|p| p.position_m().x.is_finite())
    };
    let true_poses = [
        pose(r.first_true_x_m, r.first_true_y_m, r.first_true_heading_rad),
        pose(
            r.second_true_x_m,
            r.second_true_y_m,
            r.second_true_heading_rad,
        ),
    ];
    let true_heading_rad = [r.first_true_heading_rad, r.second_true_heading_rad];
    DatasetInstance {
        instance: r.instance,
        step: r.step,
        time_s: r.time_s,
        levels: Vec::new(),
        true_poses,
        true_heading_rad: [0, 1].map(|s| true_heading_rad[s].filter(|_| true_poses[s].is_some())),
        sides: [
            DatasetSide {
                id: r.first_id.clone(),
                nodes: Vec::with_capacity(r.n_first as usize),
            },
            DatasetSide {
                id: r.second_id.clone(),
                nodes: Vec::with_capacity(r.n_second as usize),
            },
        ],
        true_pairs: Vec::new(),
    }
}

/// A node row as plain values (a NaN heading or speed: none reported).
pub(super) fn node_of(n: Node) -> DatasetNode {
    let three = |a: Option<f64>, b: Option<f64>, c: Option<f64>| Some([a?, b?, c?]);
    let cov =
        three(n.cov_xx_m2, n.cov_xy_m2, n.cov_yy_m2).map(|[xx, xy, yy]| Cov2::new(xx, xy, xy, yy));
    let motion = n
        .heading_rad
        .zip(n.speed_mps)
        .filter(|(h, s)| h.is_finite() && s.is_finite());
    DatasetNode {
        position_m: Vec2::new(n.x_m, n.y_m),
        cov_m2: cov,
        class: crate::label::parse("object class", &n.class).expect("checked as read"),
        colour_rgb: three(n.colour_r, n.colour_g, n.colour_b),
        size_m: three(n.length_m, n.width_m, n.height_m),
        motion,
        sender: n.sender.unwrap_or(false),
        world_m: n.world_x_m.zip(n.world_y_m).map(|(x, y)| Vec2::new(x, y)),
        appearance: n.appearance.map(Arc::from),
        object_id: String::new(),
        true_m: None,
        visible_fraction: None,
    }
}

/// Each vehicle has as many nodes as its instance rows say.
pub(super) fn check_node_counts(
    inst: &DatasetInstance,
    r: &Instance,
    run: u64,
) -> Result<(), DatasetError> {
    for (s, declared) in [r.n_first, r.n_second].into_iter().enumerate() {
        let n = inst.sides[s].nodes.len() as u64;
        if n != declared {
            return Err(refuse(
                Node::FILE,
                format!(
                    "run {run}, instance {}: {n} nodes of the {} vehicle, instances.parquet says \
                     {declared}",
                    inst.instance, SIDES[s]
                ),
            ));
        }
    }
    Ok(())
}

pub(super) fn add_truth(
    inst: &mut DatasetInstance,
    t: Truth,
    row: usize,
) -> Result<(), DatasetError> {
    let Some(side) = inst.sides.get_mut(t.side as usize) else {
        return Err(refuse(
            Truth::FILE,
            format!("row {}, column 'side': {}, not 0 or 1", row + 1, t.side),
        ));
    };
    let Some(node) = side.nodes.get_mut(t.node as usize) else {
        return Err(refuse(
            Truth::FILE,
            format!(
                "row {}, column 'node': node {} is not in nodes.parquet",
                row + 1,
                t.node
            ),
        ));
    };
    node.object_id = t.object_id;
    node.true_m = t
        .true_x_m
        .zip(t.true_y_m)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .map(|(x, y)| Vec2::new(x, y));
    node.visible_fraction = t.visible_fraction;
    Ok(())
}

/// No object is behind two nodes of one vehicle.
pub(super) fn check_unique_objects(inst: &DatasetInstance, run: u64) -> Result<(), DatasetError> {
    for (s, side) in inst.sides.iter().enumerate() {
        let mut ids: Vec<&str> = side
            .nodes
            .iter()
            .map(|n| n.object_id.as_str())
            .filter(|id| !id.is_empty())
            .collect();
        ids.sort_unstable();
        if let Some(w) = ids.windows(2).find(|w| w[0] == w[1]) {
            return Err(refuse(
                Truth::FILE,
                format!(
                    "object '{}' behind two nodes of the {} vehicle of run {run}, instance {}",
                    w[0], SIDES[s], inst.instance
                ),
            ));
        }
    }
    Ok(())
}

pub(super) fn add_true_pair(
    inst: &mut DatasetInstance,
    p: &TruePair,
    row: usize,
) -> Result<(), DatasetError> {
    let (a, b) = (p.a as usize, p.b as usize);
    for (s, node) in [(0, a), (1, b)] {
        if node >= inst.sides[s].nodes.len() {
            return Err(refuse(
                TruePair::FILE,
                format!(
                    "row {}: node {node} of the {} vehicle is not in nodes.parquet",
                    row + 1,
                    SIDES[s]
                ),
            ));
        }
        let again = inst
            .true_pairs
            .iter()
            .any(|&(x, y)| if s == 0 { x == node } else { y == node });
        if again {
            return Err(refuse(
                TruePair::FILE,
                format!(
                    "row {}: node {node} of the {} vehicle of run {}, instance {} is matched a \
                     second time",
                    row + 1,
                    SIDES[s],
                    p.run,
                    p.instance
                ),
            ));
        }
    }
    let (ia, ib) = (
        &inst.sides[0].nodes[a].object_id,
        &inst.sides[1].nodes[b].object_id,
    );
    if ia.is_empty() || ia != ib {
        let shown = |id: &str| {
            if id.is_empty() {
                "no object: a false positive, or a node without a truth row".to_owned()
            } else {
                format!("object '{id}'")
            }
        };
        return Err(refuse(
            TruePair::FILE,
            format!(
                "row {}: pairs node {a} ({}) with node {b} ({}), not one object",
                row + 1,
                shown(ia),
                shown(ib)
            ),
        ));
    }
    inst.true_pairs.push((a, b));
    Ok(())
}

/// Each level's reported poses (as given; else fitted to the vehicle's
/// nodes' world positions, the same at every level) and claimed accuracy;
/// refused when a vehicle has neither, or has true node positions but no
/// true pose.
pub(super) fn set_poses(
    inst: &mut DatasetInstance,
    rows: &[Instance],
    run: u64,
) -> Result<(), DatasetError> {
    let fitted: [Option<Pose2>; 2] = std::array::from_fn(|s| {
        let nodes = &inst.sides[s].nodes;
        let pairs: Option<Vec<(Vec2, Vec2)>> = nodes
            .iter()
            .map(|n| n.world_m.map(|w| (n.position_m, w)))
            .collect();
        pairs.and_then(|p| fit_rigid(&p))
    });
    let no_pose = |s: usize, why: &str| {
        refuse(
            Instance::FILE,
            format!(
                "run {run}, instance {}: the {} vehicle {}",
                inst.instance,
                SIDES[s],
                why.replace("{side}", SIDES[s])
            ),
        )
    };
    for r in rows {
        let given = [
            (r.first_x_m, r.first_y_m, r.first_heading_rad),
            (r.second_x_m, r.second_y_m, r.second_heading_rad),
        ]
        .map(|(x, y, h)| Some(Pose2::new(Vec2::new(x?, y?), h?)));
        let mut reported = [Pose2::identity(); 2];
        for s in 0..2 {
            reported[s] = given[s].or(fitted[s]).ok_or_else(|| {
                no_pose(
                    s,
                    "has no reported pose ({side}_x_m, ...) and its nodes no world positions \
                     (world_x_m, world_y_m) to fit one to",
                )
            })?;
        }
        let as_given = [r.first_heading_rad, r.second_heading_rad];
        let heading = |s: usize| match (given[s], as_given[s]) {
            (Some(_), Some(h)) => h,
            _ => reported[s].heading_rad(),
        };
        inst.levels.push(InstanceLevel {
            label: crate::label::parse("pose-noise level", &r.pose_noise)
                .expect("checked when opened"),
            position_sigma_m: r.position_sigma_m,
            heading_sigma_rad: [r.first_heading_sigma_rad, r.second_heading_sigma_rad],
            reported,
            reported_heading_rad: [heading(0), heading(1)],
        });
    }
    for s in 0..2 {
        let knows_truth = inst.sides[s].nodes.iter().any(|n| n.true_m.is_some());
        if knows_truth && inst.true_poses[s].is_none() {
            return Err(no_pose(
                s,
                "has nodes with true positions but no true pose ({side}_true_x_m, ...) to \
                 score them in its frame",
            ));
        }
    }
    Ok(())
}
