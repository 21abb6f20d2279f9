//! [`run`]: every configured method, pose-noise level and fusion variant
//! evaluated on every instance of a run, accumulated into the summary as
//! the frames come, the per-object rows streamed to the caller.

use std::time::Instant;

use super::frames::evaluate_frames;
use super::instance::Instance;
use super::runners::runners;
use super::{Progress, RunError, Warnings};
use crate::config::Settings;
use crate::evaluate;
use crate::io::OutputError;
use crate::report::{ObjectRow, RowKey, RunResults};
use crate::sensor::PoseNoiseLabel;

/// Runs the scenario and evaluates every configured method, pose-noise
/// level and fusion variant on every instance, frame by frame
/// ([`evaluate::evaluate_frame`], with `[matching] multi_vehicle`) on
/// `threads` threads. The summary is accumulated as the frames come;
/// every per-object row goes to `on_objects` in a fixed order (by step,
/// pose-noise level, method, instance), whatever the number of threads, and
/// is not kept. What the run has to say beside its results goes to
/// `warnings`.
pub fn run(
    settings: &Settings,
    threads: usize,
    warnings: &Warnings,
    progress: impl FnMut(Progress),
    mut on_objects: impl FnMut(&[ObjectRow]) -> Result<(), OutputError>,
) -> Result<RunResults, RunError> {
    let started = Instant::now();
    let runners = runners(settings, &settings.matching.methods)?;
    let mut results = empty_results(settings);
    let mut rows = Vec::new();
    let stats = evaluate_frames(
        settings,
        &runners,
        threads,
        warnings,
        progress,
        |instances, _, level, f| {
            rows.clear();
            record_frame(&mut results, &mut rows, instances, level, f);
            Ok(on_objects(&rows)?)
        },
    )?;
    results.n_instances = stats.n_instances;
    results.n_steps = stats.n_steps;
    results.sim_end_s = stats.sim_end_s;
    results.bridge_time = stats.bridge_time;
    results.objects_read = stats.objects_read;
    results.network_macs = runners.iter().map(|r| r.network_macs()).sum();
    results.wall_time = started.elapsed();
    Ok(results)
}

/// The results before any instance: every row is there from the start (a
/// run without any instance has them too, `n_instances` 0 and no metric,
/// so it is a complete run).
fn empty_results(settings: &Settings) -> RunResults {
    let mut results = RunResults::default();
    for &method in &settings.matching.methods {
        for level in &settings.pose_noise {
            for &fusion in &settings.fusion.variants {
                let key = RowKey {
                    method,
                    pose_noise: level.label,
                    fusion,
                };
                results.summary.rows.entry(key).or_default();
            }
        }
    }
    results
}

/// Adds one method's evaluation of a frame at one level to `results`, and
/// its per-object rows to `rows`.
fn record_frame(
    results: &mut RunResults,
    rows: &mut Vec<ObjectRow>,
    instances: &[Instance],
    pose_noise: PoseNoiseLabel,
    f: evaluate::FrameEval,
) {
    for (inst, e) in instances.iter().zip(f.pairs) {
        for (fusion, est) in e.fused {
            let key = RowKey {
                method: e.method,
                pose_noise,
                fusion,
            };
            results.summary.record(key, e.counts, &est);
            rows.extend(est.into_iter().map(|estimate| ObjectRow {
                instance: inst.index,
                step: inst.frame.step,
                time_s: inst.frame.time_s,
                key,
                estimate,
            }));
        }
    }
    for (fusion, views) in &f.views {
        let key = RowKey {
            method: f.method,
            pose_noise,
            fusion: *fusion,
        };
        results.summary.record_views(key, views);
    }
    results
        .summary
        .record_consistency(f.method, pose_noise, f.consistency);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluate::CorrespondenceSource;
    use crate::pipeline::evaluation::Evaluation;
    use crate::pipeline::tests::{settings, two_vehicle_step};

    /// Before any instance, the summary has a row per method, level and
    /// fusion variant, each without instances.
    #[test]
    fn a_run_starts_with_every_row_and_no_instance() {
        let s = settings();
        let r = empty_results(&s);
        let n = s.matching.methods.len() * s.pose_noise.len() * s.fusion.variants.len();
        assert_eq!(r.summary.rows.len(), n);
        assert!(r.summary.rows.values().all(|a| a.instances == 0));
    }

    /// A frame's evaluation counts each instance once per fusion variant,
    /// and each per-object row names its instance, step and time.
    #[test]
    fn a_frame_is_counted_per_fusion_variant_and_its_rows_name_their_instance() {
        let s = settings();
        let step = two_vehicle_step(9);
        let level = &s.pose_noise[0];
        let f = Evaluation::of(&s)
            .step(&step, &CorrespondenceSource::Oracle)
            .remove(0);
        let mut results = empty_results(&s);
        let mut rows = Vec::new();
        record_frame(&mut results, &mut rows, &step.instances(), level.label, f);
        for &fusion in &s.fusion.variants {
            let key = RowKey {
                method: crate::matching::Method::Oracle,
                pose_noise: level.label,
                fusion,
            };
            let acc = &results.summary.rows[&key];
            assert_eq!((acc.instances, acc.counts.correct), (1, 3));
            let n = rows.iter().filter(|r| r.key == key).count();
            // Both vehicles' objects: four each.
            assert_eq!(n, 8, "{key:?}");
        }
        assert!(
            rows.iter()
                .all(|r| (r.instance, r.step) == (9, 3) && (r.time_s - 0.3).abs() < 1e-12)
        );
        assert!(
            results
                .summary
                .consistency
                .contains_key(&(crate::matching::Method::Oracle, level.label))
        );
    }
}
