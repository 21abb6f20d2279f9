//! `coid detector`: the configured detector profile measured on the
//! validation runs, per range bin, beside the figures it was configured
//! with (`docs/detectors.md`).

use anyhow::Context;

use super::{CommonArgs, label_arg, progress_bar};
use crate::experiments::validation_runs;
use crate::report::{DetectorStats, reid_table};
use crate::sensor::profile::{DetectorProfile, Mount, sensor_in_body_m};
use crate::sensor::reid::{self, DescribedViews};
use crate::{io, pipeline};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Measure this profile instead of the config's [detector] profile.
    #[arg(long, value_parser = label_arg::<DetectorProfile>("detector profile"))]
    profile: Option<DetectorProfile>,
}

/// Senses every validation run: the detector's figures into `stats`, the
/// descriptors' scenes (every pair of views of one step that share an
/// object) returned with the number of sensings.
fn measure(
    runs: &[crate::config::Settings],
    stats: &mut DetectorStats,
    (mount, sensors): (Mount, u64),
    mut on_run: impl FnMut(),
) -> anyhow::Result<(u64, Vec<reid::ScoredScene>)> {
    let mut sensings = 0;
    let mut scenes = Vec::new();
    for (k, run) in runs.iter().enumerate() {
        let mut views = DescribedViews::default();
        sensings += pipeline::sense_steps(run, |frame, sensed| {
            let ego = frame.find(&sensed.observation.ego_id);
            let length_m = ego.map_or(0.0, |i| frame.objects[i].length_m);
            stats.add(sensed, sensor_in_body_m(mount, length_m), sensors);
            views.add(frame.step, sensed);
        })
        .with_context(|| format!("validation run {} failed", k + 1))?;
        scenes.extend(views.finish());
        on_run();
    }
    Ok((sensings, scenes))
}

/// One profile at a time: every connected vehicle carries the profile
/// measured, whatever the fleet's mix, types and rigs say; says so when
/// the config sets any of them.
fn say_set_aside(settings: &crate::config::Settings, set_aside: &[&str]) {
    if !set_aside.is_empty() {
        eprintln!(
            "coid: measuring the '{}' profile on every connected vehicle: [detector] {} set \
             aside here (one profile at a time; --profile chooses another)",
            settings.detector.profile.as_str(),
            set_aside.join(", ")
        );
    }
}

pub fn detector(a: Args) -> anyhow::Result<()> {
    let (configured, claim) = a.common.prepare("-detector", io::ResultKind::Detector)?;
    let (settings, set_aside) = configured.with_one_detector_profile(a.profile);
    say_set_aside(&settings, &set_aside);
    let out = claim.out().to_owned();
    let profile = settings.detector.profile;
    // The bins, the configured figures, where the sensors sit.
    let (edges, recall, error, clutter, mount, sensors) = match settings.detector.model() {
        Some(m) => {
            let p = &m.params;
            let edges = p.bin_edges_m.clone();
            (
                edges,
                p.recall.clone(),
                p.mean_error_m.clone(),
                p.false_positives_per_frame,
                p.mount,
                p.yaw_offsets_rad.len(),
            )
        }
        None => {
            let range = settings.camera.range_m;
            let mut edges: Vec<f64> = [30.0, 50.0].into_iter().filter(|e| *e < range).collect();
            edges.push(range);
            let clutter = settings.sensor.false_positives_per_frame;
            let cameras = settings.camera.yaw_offsets_rad.len();
            (
                edges,
                Vec::new(),
                Vec::new(),
                clutter,
                Mount::Front,
                cameras,
            )
        }
    };
    let runs = validation_runs(&settings)?;
    let pb = progress_bar(
        a.common.quiet.quiet,
        runs.len() as u64,
        "{spinner} measuring the detector: run {pos}/{len} [{bar:30}] eta {eta}",
    );
    let mut stats = DetectorStats::new(edges);
    let placement = (mount, sensors as u64);
    let (sensings, scenes) = measure(&runs, &mut stats, placement, || pb.inc(1))?;
    pb.finish_and_clear();
    if sensings == 0 {
        anyhow::bail!(
            "no connected vehicle came near junction '{}' in the {}: nothing to measure (see \
             [connected], [scenario] radius_m and end_s, and [train] validation_seeds)",
            settings.scenario.junction,
            crate::label::counted(runs.len() as u64, "validation run")
        );
    }
    let table = stats.table(&recall, &error, clutter);
    let reid = settings.appearance.reid.as_ref().and_then(|r| {
        let c = r.calibration.as_ref()?;
        Some(reid_table(&r.target, &c.figures, &reid::figures(&scenes)))
    });
    let mut tables = vec![("detector.csv", &table)];
    if let Some(t) = &reid {
        tables.push(("reid.csv", t));
    }
    claim.fill(|dir| io::write_tracking(dir, &tables, |_| Ok(())))?;
    println!("{}", io::markdown::table(&table));
    if let Some(t) = &reid {
        println!("{}", io::markdown::table(t));
    }
    eprintln!(
        "coid: the '{}' detector over {} ({}); wrote {}",
        profile.as_str(),
        crate::label::counted(runs.len() as u64, "validation run"),
        crate::label::counted(sensings, "sensing"),
        out.display()
    );
    Ok(())
}
