//! Speed of the deep matcher on one pair of ~20-node graphs, one thread:
//! MC-dropout inference with T = 20 samples, and one training step.
//! `cargo bench --bench matcher` (prints medians over repeated runs).

use std::time::Instant;

use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use coid_sim::config::{PoseNoiseLabel, PoseNoiseLevel};
use coid_sim::geometry::{Cov2, Pose2, Vec2};
use coid_sim::graph::SceneGraph;
use coid_sim::matching::deep::model::{self, Architecture, GraphTensors, Network};
use coid_sim::matching::deep::train::example;
use coid_sim::matching::deep::{DeepMatcher, draw_masks, variant};
use coid_sim::matching::{MatchView, Method};
use coid_sim::sensor::{Appearance, Detection};
use coid_sim::traffic::ObjectClass;
use rand::{Rng, SeedableRng};

fn scene(n: usize, rng: &mut rand_chacha::ChaCha8Rng) -> Vec<(Vec2, ObjectClass)> {
    (0..n)
        .map(|k| {
            (
                Vec2::new(rng.random_range(-40.0..40.0), rng.random_range(-40.0..40.0)),
                ObjectClass::ALL[k % 7],
            )
        })
        .collect()
}

fn detections(pose: &Pose2, objects: &[(Vec2, ObjectClass)]) -> Vec<Detection> {
    objects
        .iter()
        .enumerate()
        .map(|(k, &(w, class))| Detection {
            position_m: pose.to_body(&w),
            cov_m2: Cov2::identity(),
            appearance: Appearance {
                class,
                colour_rgb: [0.5, 0.4, 0.3],
                length_m: 4.6,
                width_m: 1.8,
                height_m: 1.5,
            },
            truth_id: Some(k.to_string()),
            visible_fraction: 1.0,
        })
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let objects = scene(20, &mut rng);
    let (pa, pb) = (Pose2::identity(), Pose2::new(Vec2::new(30.0, 20.0), 2.0));
    let (da, db) = (detections(&pa, &objects), detections(&pb, &objects[2..]));
    let ga = SceneGraph::delaunay(&da.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap();
    let gb = SceneGraph::delaunay(&db.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap();
    let level = PoseNoiseLevel {
        label: PoseNoiseLabel::Gps,
        position_sigma_m: 1.2,
        heading_sigma_rad: 0.2f64.to_radians(),
    };
    let va = MatchView {
        detections: &da,
        graph: &ga,
        pose_reported: pa,
        pose_noise: level,
    };
    let vb = MatchView {
        detections: &db,
        graph: &gb,
        pose_reported: pb,
        pose_noise: level,
    };

    let arch = Architecture::default();
    let net = Network::new(&arch, &Device::flex());
    let matcher = DeepMatcher::new(Method::Ours, net, arch, 20, None, 1);
    let mut times = Vec::new();
    for k in 0..60 {
        let t = Instant::now();
        std::hint::black_box(matcher.distribution(&va, &vb));
        if k >= 10 {
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    println!(
        "inference, T = 20, {} x {} nodes: median {:.2} ms",
        da.len(),
        db.len(),
        median(times)
    );

    let (mut arch, terms) = variant(Method::Ours).unwrap();
    if let Ok(v) = std::env::var("SINK") {
        arch.sinkhorn_iters = v.parse().unwrap();
    }
    if std::env::var("NOCONS").is_ok() {
        arch.consensus = false;
    }
    let device = Device::flex().autodiff();
    device.seed(1);
    let mut net = Network::new(&arch, &device);
    let mut optim = AdamConfig::new().init();
    let ex = example(&va, &vb).unwrap();
    let mut stream = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let mut times = Vec::new();
    for k in 0..60 {
        let t = Instant::now();
        let g1 = GraphTensors::new(&ex.g1, &device);
        let g2 = GraphTensors::new(&ex.g2, &device);
        let masks = draw_masks(&mut stream, &arch, 1, ex.g1.n, ex.g2.n, &device);
        let cost = Tensor::<3>::from_data(
            TensorData::new(ex.position_cost.clone(), [1, ex.g1.n, ex.g2.n]),
            &device,
        );
        let log_p = net.forward(&g1, &g2, masks, cost, arch.sinkhorn_iters);
        let y = Tensor::<2>::from_data(
            TensorData::new(ex.y_star.clone(), [ex.g1.n, ex.g2.n]),
            &device,
        );
        let non =
            Tensor::<2>::from_data(TensorData::new(ex.non.clone(), [ex.g1.n, ex.g2.n]), &device);
        let loss = model::loss(log_p, y, non, ex.n_true, terms);
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        net = optim.step(1e-3, net, grads);
        if k >= 10 {
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    println!("training step, T = 1: median {:.2} ms", median(times));
}
