//! The generated family's tests.

use std::f64::consts::TAU;

use super::buildings::{CLEAR_OF_JUNCTION_M, overlap, rectangle};
use super::kinds::min_gap_rad;
use super::*;
use crate::geometry::Vec2;

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

/// Plain demand: the same layout and flows (same ids, same rates), but
/// SUMO's default vehicle, bicycle and pedestrian types instead of the
/// shipped mix; nothing else of the scenario changes.
#[test]
fn plain_demand_keeps_the_flows_with_sumos_default_types() {
    let mix = generate(5, 3, &[Kind::Crossing]);
    let mut default_types = mix.clone();
    default_types.demand = Demand::DefaultTypes;
    let (m, p) = (mix.routes_xml(), default_types.routes_xml());
    assert!(!p.contains("vType"), "no shipped types");
    assert!(!p.contains("type=\"mix\""));
    assert_eq!(
        m.matches("<flow id=").count(),
        p.matches("type=\"DEFAULT_VEHTYPE\"").count() + p.matches("DEFAULT_BIKETYPE").count()
    );
    assert_eq!(
        m.matches("<personFlow").count(),
        p.matches("type=\"DEFAULT_PEDTYPE\"").count()
    );
    let rates = |x: &str| -> Vec<String> {
        x.lines()
            .filter(|l| l.contains("<flow") || l.contains("<personFlow"))
            .filter_map(|l| l.split_once("probability=").map(|(_, r)| r.to_owned()))
            .collect()
    };
    assert_eq!(rates(&m), rates(&p));
    assert_eq!(mix.nodes_xml(), default_types.nodes_xml());
    assert!(default_types.describe().contains("default types"));
    assert!(!mix.describe().contains("default types"));
}
