//! Speed of the deep matcher on one pair of ~20-node graphs, one thread:
//! MC-dropout inference with T = 20 samples (a pair whose vehicles are new,
//! and a pair whose vehicles' embeddings are already computed), and one
//! training step on a batch of 32 pairs of 8-25 nodes, 2 samples each (the
//! shipped training settings).
//! `cargo bench --bench matcher` (prints medians over repeated runs).

use std::time::Instant;

use coid_sim::geometry::{Cov2, Pose2, Vec2};
use coid_sim::graph::SceneGraph;
use coid_sim::matching::deep::arch::{Architecture, MaskScope, PairLoss};
use coid_sim::matching::deep::decision::Decision;
use coid_sim::matching::deep::train::{Example, Prepared, TrainOptions, Trainer, example};
use coid_sim::matching::deep::{DeepMatcher, Inference};
use coid_sim::matching::{Correspondence, MatchView, Method, gps_relative_pose};
use coid_sim::sensor::{Appearance, Detection, PoseNoiseLabel, PoseNoiseLevel};
use coid_sim::traffic::ObjectClass;
use rand::{Rng, SeedableRng};

/// The allocator of the `coid` binary.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

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
        .map(|&(w, class)| Detection {
            position_m: pose.to_body(&w),
            cov_m2: Cov2::identity(),
            appearance: Appearance {
                class,
                colour_rgb: [0.5, 0.4, 0.3],
                length_m: 4.6,
                width_m: 1.8,
                height_m: 1.5,
            },
            motion: None,
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

    // A new pair every time: both embeddings computed (no sharing).
    let run = Inference {
        samples: 20,
        threshold: None,
        decision: Decision::Assignment,
        temperature: 1.0,
        seed: 1,
        masks: MaskScope::Shared,
        dropout: None,
        gate_chi2: 9.21,
    };
    let per_pair = DeepMatcher::untrained(Method::Ours, Architecture::default(), 1, run)
        .without_shared_embeddings();
    let relative = gps_relative_pose(&va, &vb);
    let median_ms = |m: &DeepMatcher| {
        let mut times = Vec::new();
        for k in 0..60 {
            let t = Instant::now();
            std::hint::black_box(m.distribution(&va, &vb, &relative));
            if k >= 10 {
                times.push(t.elapsed().as_secs_f64() * 1e3);
            }
        }
        median(times)
    };
    println!(
        "inference, T = 20, {} x {} nodes: median {:.2} ms",
        da.len(),
        db.len(),
        median_ms(&per_pair)
    );
    // Both vehicles already embedded in this frame (another pair of theirs):
    // only the pair part (consensus, GPS term, Sinkhorn) is computed.
    let shared = DeepMatcher::untrained(Method::Ours, Architecture::default(), 1, run);
    println!(
        "inference, T = 20, both embeddings shared: median {:.2} ms",
        median_ms(&shared)
    );

    training_step(&mut rng, level, (pa, pb));
}

/// The median time of one training step on 32 pairs of 8-25 nodes.
fn training_step(
    rng: &mut rand_chacha::ChaCha8Rng,
    level: PoseNoiseLevel,
    (pa, pb): (Pose2, Pose2),
) {
    // Training pairs: the second vehicle sees objects 2.. of the first;
    // detection j of the second is detection j + 2 of the first.
    let examples: Vec<Example> = (0..32)
        .map(|k| {
            let n = 8 + (k * 7) % 18;
            let objects = scene(n, rng);
            let (da, db) = (detections(&pa, &objects), detections(&pb, &objects[2..]));
            let graph = |d: &[Detection]| {
                SceneGraph::delaunay(&d.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap()
            };
            let (ga, gb) = (graph(&da), graph(&db));
            let view = |d, g| MatchView {
                detections: d,
                graph: g,
                pose_reported: Pose2::identity(),
                pose_noise: level,
            };
            let truth: Vec<Correspondence> = (0..db.len())
                .map(|j| Correspondence {
                    a: j + 2,
                    b: j,
                    probability: 1.0,
                    uncertainty: 0.0,
                })
                .collect();
            let (va, mut vb) = (view(&da, &ga), view(&db, &gb));
            vb.pose_reported = pb;
            example(&va, &vb, &truth).unwrap()
        })
        .collect();
    let opts = TrainOptions {
        epochs: 1,
        learning_rate: 1e-3,
        seed: 1,
        patience: 0,
        loss: PairLoss::Likelihood,
        samples: 2,
        masks: MaskScope::PerNode,
        batch_size: 32,
        gate_chi2: 9.21,
    };
    let mut trainer = Trainer::new(Method::Ours, &opts).unwrap();
    let prepared = trainer.prepare(&examples);
    let batch: Vec<&Prepared> = prepared.iter().collect();
    let mut times = Vec::new();
    for k in 0..25 {
        let t = Instant::now();
        std::hint::black_box(trainer.step(&batch, 1e-3).unwrap());
        if k >= 5 {
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    let step = median(times);
    println!(
        "training step, 32 pairs x T = 2: median {step:.1} ms ({:.2} ms per pair)",
        step / 32.0
    );
}
