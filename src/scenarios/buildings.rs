//! Building blocks along the roads: rectangles at a setback, kept clear of
//! roads, the junction and each other.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use std::f64::consts::PI;

use super::kinds::unit;
use super::layout::Strip;
use crate::geometry::{Polygon, Vec2};

/// An oriented rectangle as a polygon.
pub(super) fn rectangle(centre: Vec2, angle_rad: f64, length_m: f64, width_m: f64) -> Polygon {
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
pub(super) fn overlap(a: &Polygon, b: &Polygon) -> bool {
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
pub(super) const CLEAR_OF_JUNCTION_M: f64 = 18.0;

/// Blocks along both sides of every strip, `setback_m` from the pavement,
/// none on any pavement, near the junction or on another block.
pub(super) fn draw_buildings(r: &mut ChaCha8Rng, strips: &[Strip], setback_m: f64) -> Vec<Polygon> {
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
