//! Speed of the deep matcher on one pair of ~20-node graphs, one thread:
//! MC-dropout inference with T = 20 samples (a pair whose vehicles are new,
//! and a pair whose vehicles' embeddings are already computed), and one
//! training step on a batch of 32 pairs of 8-25 nodes, 2 samples each (the
//! shipped training settings). Beside the times, the arithmetic: the
//! multiply-adds the network's shapes imply (`matching::deep::cost`) and
//! the machine's single-thread f32 matrix-multiply peak (the `gemm` crate
//! burn's CPU backend uses: the best of square products of 256 to 1024,
//! and the rate at the second layer's own shape), with the share of the
//! peak each part achieves.
//! `cargo bench --bench matcher` (prints medians over repeated runs);
//! `COID_BENCH_PROFILE=new` (or `shared`) runs that case alone 3000 times
//! without output, for `perf record` (`published`: DGMC's network on 1000
//! pairs).

use std::time::Instant;

use coid_sim::geometry::{Cov2, Pose2, Vec2};
use coid_sim::graph::SceneGraph;
use coid_sim::matching::deep::arch::{Architecture, Backbone, MaskScope, PairLoss};
use coid_sim::matching::deep::cost::{
    GraphShape, inference_macs, plain_embedding_macs, published_macs,
};
use coid_sim::matching::deep::train::{Example, Prepared, TrainOptions, Trainer, example};
use coid_sim::matching::deep::{self, Inference, matmul};
use coid_sim::matching::{Correspondence, MatchView, Method, gps_relative_pose};
use coid_sim::sensor::{Appearance, Detection, PoseNoiseLabel, PoseNoiseLevel};
use coid_sim::traffic::ObjectClass;
use rand::{Rng, SeedableRng};

/// The allocator of the `coid` binary.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// MC-dropout inference as the bench runs it: T = 20, shared masks.
const RUN: Inference = Inference::MC_DROPOUT;

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
                descriptor: None,
            },
            motion: None,
        })
        .collect()
}

/// The best of `reps` single-thread f32 products `[m, k] x [k, n]`
/// (row-major, gemm), in GFLOP/s (2 m k n per product).
fn gemm_gflops(m: usize, k: usize, n: usize, reps: usize) -> f64 {
    let lhs: Vec<f32> = (0..m * k).map(|i| (i % 7) as f32 * 0.1).collect();
    let rhs: Vec<f32> = (0..k * n).map(|i| (i % 5) as f32 * 0.1).collect();
    let mut dst = vec![0f32; m * n];
    let mut best = f64::INFINITY;
    for _ in 0..reps {
        let t = Instant::now();
        matmul(m, k, n, &lhs, &rhs, &mut dst);
        best = best.min(t.elapsed().as_secs_f64());
        std::hint::black_box(&dst);
    }
    2.0 * (m * k * n) as f64 / best / 1e9
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// mimalloc's `mi_option_purge_delay` (as `src/main.rs` names it).
const PURGE_DELAY: libmimalloc_sys::mi_option_t = libmimalloc_sys::mi_option_use_numa_nodes - 1;

/// The allocator as the `coid` binary sets it (`src/main.rs`): memory a
/// pair frees is kept for the next instead of being returned after 10 ms
/// and faulted in (and zeroed) again.
fn allocator_as_the_binary() {
    // SAFETY: a process-wide allocator option, set before any thread runs.
    unsafe { libmimalloc_sys::mi_option_set(PURGE_DELAY, -1) };
}

/// One vehicle's view of its detections.
fn view<'a>(
    detections: &'a [Detection],
    graph: &'a SceneGraph,
    pose: Pose2,
    level: PoseNoiseLevel,
) -> MatchView<'a> {
    MatchView {
        detections,
        graph,
        pose_reported: pose,
        pose_noise: level,
    }
}

fn main() {
    allocator_as_the_binary();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let objects = scene(20, &mut rng);
    let (pa, pb) = (Pose2::identity(), Pose2::new(Vec2::new(30.0, 20.0), 2.0));
    let (da, db) = (detections(&pa, &objects), detections(&pb, &objects[2..]));
    let ga = SceneGraph::delaunay(&da.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap();
    let gb = SceneGraph::delaunay(&db.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap();
    let level = PoseNoiseLevel {
        label: PoseNoiseLabel::GPS,
        position_sigma_m: 1.2,
        heading_sigma_rad: 0.2f64.to_radians(),
        correlation_s: None,
    };
    let (va, vb) = (view(&da, &ga, pa, level), view(&db, &gb, pb, level));

    // A new pair every time: both embeddings computed (an object moved
    // by a tenth of a millimetre more in every call, so that nothing is
    // reused from a call before).
    let run = RUN;
    let matcher = deep::untrained(Method::Ours, 1, run);
    let relative = gps_relative_pose(&va, &vb);
    let moved: Vec<_> = (0..60)
        .map(|k| {
            let mut moved = objects.to_vec();
            moved[3].0.x += 1e-4 * (k + 1) as f64;
            let (da, db) = (detections(&pa, &moved), detections(&pb, &moved[2..]));
            let graph = |d: &[Detection]| {
                SceneGraph::delaunay(&d.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap()
            };
            let (ga, gb) = (graph(&da), graph(&db));
            (da, db, ga, gb)
        })
        .collect();
    // For a profiler: one case only, 3000 times, nothing printed.
    if let Ok(which) = std::env::var("COID_BENCH_PROFILE") {
        if which == "published" {
            published_pair(&objects, (pa, pb), level, None);
            return;
        }
        // Both vehicles already embedded (another pair of theirs): only
        // the pair part (consensus, GPS term, Sinkhorn) is computed.
        for _ in 0..3000 {
            std::hint::black_box(matcher.identify_with(&va, &vb, &relative));
        }
        return;
    }
    let (mut new_times, mut shared_times) = (Vec::new(), Vec::new());
    // The two are timed in turn, so that a busy machine slows both alike.
    for (k, (da, db, ga, gb)) in moved.iter().enumerate() {
        let (va_k, vb_k) = (view(da, ga, pa, level), view(db, gb, pb, level));
        let relative_k = gps_relative_pose(&va_k, &vb_k);
        let t = Instant::now();
        std::hint::black_box(matcher.identify_with(&va_k, &vb_k, &relative_k));
        let new_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        std::hint::black_box(matcher.identify_with(&va, &vb, &relative));
        let shared_ms = t.elapsed().as_secs_f64() * 1e3;
        if k >= 10 {
            new_times.push(new_ms);
            shared_times.push(shared_ms);
        }
    }
    let (new_ms, shared_ms) = (median(new_times), median(shared_times));
    let peak = against_the_peak(&va, &vb, new_ms, shared_ms);
    published_pair(&objects, (pa, pb), level, Some(peak));

    training_step(&mut rng, level, (pa, pb));
}

/// The inference times against the arithmetic they do: the multiply-adds
/// counted from the network's shapes, and the matrix-multiply peak
/// (returned, GFLOP/s).
fn against_the_peak(va: &MatchView, vb: &MatchView, new_ms: f64, shared_ms: f64) -> f64 {
    // The peak: the best of large square products (cache sizes differ).
    let peak = [256, 512, 1024]
        .into_iter()
        .map(|n| gemm_gflops(n, n, n, 4_000_000_000 / (n * n * n) + 5))
        .fold(0.0, f64::max);
    let (sa, sb) = (GraphShape::of(va), GraphShape::of(vb));
    let at_shape = gemm_gflops(sa.nodes * 20, 256, sa.cells * 32, 200);
    println!(
        "f32 matrix multiply, one thread (gemm): peak {peak:.1} GFLOP/s (best of 256^3 to 1024^3); \
         {at_shape:.1} GFLOP/s at the second layer's cell product {} x 256 x {}",
        sa.nodes * 20,
        sa.cells * 32
    );
    let macs = inference_macs(&Architecture::default(), sa, sb, 20);
    let rate = |macs: u64, ms: f64| {
        let gflops = 2.0 * macs as f64 / (ms * 1e6);
        format!(
            "{:.1} MFLOP counted on the tensor path's shapes, {gflops:.1} GFLOP/s, {:.0} % of peak",
            2.0 * macs as f64 / 1e6,
            100.0 * gflops / peak
        )
    };
    println!(
        "inference, T = 20, {} x {} nodes ({} and {} kernel cells): median {new_ms:.2} ms ({})",
        sa.nodes,
        sb.nodes,
        sa.cells,
        sb.cells,
        rate(macs.new_pair(), new_ms)
    );
    let arch = Architecture::default();
    let plain = plain_embedding_macs(&arch, sa, 20) + plain_embedding_macs(&arch, sb, 20);
    let embed_ms = new_ms - shared_ms;
    let plain_gflops = 2.0 * plain / (embed_ms * 1e6);
    println!(
        "  of which both embeddings (new pair - shared): {embed_ms:.2} ms; the plain second \
         layer's {:.1} MFLOP expected: {plain_gflops:.1} GFLOP/s, {:.0} % of peak",
        2.0 * plain / 1e6,
        100.0 * plain_gflops / peak
    );
    println!(
        "inference, T = 20, both embeddings shared: median {shared_ms:.2} ms ({})",
        rate(macs.shared_pair(), shared_ms)
    );
    peak
}

/// DGMC's network with the shipped weights of the paper's method
/// (`coid`: masks per node, as trained; DGMC, `coid+non` and `coid+unc`
/// cost the same) on the same pair, T = 20: the plain inference path
/// against its counted arithmetic. Every call sees a new pair (an
/// object moved by a tenth of a millimetre more, the same graphs), so
/// nothing is reused from a call before.
/// `peak`: `None` for a profiler (1000 pairs, nothing printed).
fn published_pair(
    objects: &[(Vec2, ObjectClass)],
    (pa, pb): (Pose2, Pose2),
    level: PoseNoiseLevel,
    peak: Option<f64>,
) {
    let Some(Backbone::Published(cfg)) = Method::Coid.backbone() else {
        unreachable!("coid is DGMC's network");
    };
    let run = Inference {
        masks: MaskScope::PerNode,
        ..RUN
    };
    let bytes = include_bytes!("../models/coid.bpk");
    let matcher = deep::matcher(
        Method::Coid,
        coid_sim::sensor::AppearanceWidth::NONE,
        deep::arch::NetworkShape::default(),
        bytes,
        run,
    )
    .unwrap();
    let pairs: Vec<_> = (0..if peak.is_some() { 60 } else { 1000 })
        .map(|k| {
            let mut moved = objects.to_vec();
            moved[3].0.x += 1e-4 * (k + 1) as f64;
            let (da, db) = (detections(&pa, &moved), detections(&pb, &moved[2..]));
            let graph = |d: &[Detection]| {
                SceneGraph::delaunay(&d.iter().map(|d| d.position_m).collect::<Vec<_>>()).unwrap()
            };
            let (ga, gb) = (graph(&da), graph(&db));
            (da, db, ga, gb)
        })
        .collect();
    let mut times = Vec::new();
    for (k, (da, db, ga, gb)) in pairs.iter().enumerate() {
        let va = MatchView {
            detections: da,
            graph: ga,
            pose_reported: pa,
            pose_noise: level,
        };
        let vb = MatchView {
            detections: db,
            graph: gb,
            pose_reported: pb,
            pose_noise: level,
        };
        let t = Instant::now();
        std::hint::black_box(matcher.identify(&va, &vb));
        if k >= 10 {
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    let Some(peak) = peak else {
        return;
    };
    let ms = median(times);
    let macs = published_macs(&cfg, [objects.len(), objects.len() - 2], 20, true);
    let gflops = 2.0 * macs.new_pair() as f64 / (ms * 1e6);
    println!(
        "DGMC's network (shipped coid weights, masks per node), T = 20, {} x {} nodes, a new \
         pair: median {ms:.2} ms ({:.1} MFLOP counted on the plain path's shapes, {gflops:.1} \
         GFLOP/s, {:.0} % of peak)",
        objects.len(),
        objects.len() - 2,
        2.0 * macs.new_pair() as f64 / 1e6,
        100.0 * gflops / peak
    );
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
        appearance_width: coid_sim::sensor::AppearanceWidth::NONE,
        no_match: coid_sim::matching::deep::arch::NoMatchWeights::Entries,
        network: coid_sim::matching::deep::arch::NetworkShape::default(),
        augment: coid_sim::matching::deep::train::augment::Augment::default(),
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
