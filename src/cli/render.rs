//! `coid render`: chosen instances of a run drawn top-down (PNG and SVG).

use super::{CommonArgs, label_arg, show_sim_progress};
use crate::config::Settings;
use crate::evaluate::{self, CorrespondenceSource};
use crate::fusion::FusionSettings;
use crate::io;
use crate::io::markdown::fmt_num;
use crate::matching::Method;
use crate::pipeline::{self, Instance, RunError};
use crate::render::{self, SceneView};
use crate::sensor::profile::paper_rig;
use crate::sensor::{PoseNoiseLabel, PoseNoiseLevel};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Instance indices to draw (0 = the run's first instance).
    #[arg(long, value_delimiter = ',', default_value = "0")]
    instances: Vec<usize>,
    /// Method whose correspondences are drawn.
    #[arg(long, default_value = "ours", value_parser = label_arg::<Method>("method"))]
    method: Method,
    /// Pose-noise level of the drawn correspondences (one of the config's).
    #[arg(long, default_value = "gps", value_parser = label_arg::<PoseNoiseLabel>("pose-noise level"))]
    pose_noise: PoseNoiseLabel,
}

pub fn render(a: Args) -> anyhow::Result<()> {
    let (settings, claim) = a.common.prepare("-render", io::ResultKind::Render)?;
    let out = claim.out().to_owned();
    let level = *settings
        .pose_noise
        .iter()
        .find(|l| l.label == a.pose_noise)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "pose noise '{}' is not one of the config's levels",
                a.pose_noise.as_str()
            )
        })?;
    let runner = pipeline::runner(&settings, a.method)?;
    let mut drawn = Vec::new();
    let bar = a.common.sim_bar(settings.scenario.end_s);
    claim.fill(|tmp| -> anyhow::Result<()> {
        pipeline::simulate(
            &settings,
            &pipeline::Warnings::default(),
            |p| show_sim_progress(&bar, p),
            |inst| {
                if !a.instances.contains(&inst.index) {
                    return Ok(());
                }
                let stem = tmp.join(format!("instance-{:04}", inst.index));
                draw(&settings, inst, &level, &runner, &stem)?;
                drawn.push(inst.index);
                Ok(())
            },
        )?;
        let missing: Vec<usize> = a
            .instances
            .iter()
            .copied()
            .filter(|i| !drawn.contains(i))
            .collect();
        bar.finish_and_clear();
        if !missing.is_empty() {
            anyhow::bail!("the run has no instance(s) {missing:?} (it has fewer instances)");
        }
        Ok(())
    })?;
    eprintln!(
        "coid: drew {} instance(s) into {}",
        drawn.len(),
        out.display()
    );
    Ok(())
}

/// Matches one instance with `runner` and draws it to `<stem>.png/.svg`.
fn draw(
    settings: &Settings,
    inst: &Instance,
    level: &PoseNoiseLevel,
    runner: &CorrespondenceSource,
    stem: &std::path::Path,
) -> Result<(), RunError> {
    let pair = inst.at_level(
        settings.seeds.sensor,
        level,
        settings.v2x.gnss_heading_speed_sigma_mps,
    );
    let no_fusion = FusionSettings {
        variants: vec![],
        align_min_matches: settings.fusion.align_min_matches,
    };
    let e = evaluate::evaluate(&pair, runner, &no_fusion);
    let (a, b) = (&pair.first, &pair.second);
    // Each vehicle's detector profile's sensors (the paper's: [camera],
    // in front).
    let vehicles = [inst.a.source.vehicle(), inst.b.source.vehicle()];
    let sensors = vehicles.map(|v| {
        let type_id = inst
            .frame
            .find(v)
            .map_or("", |i| &inst.frame.objects[i].type_id);
        match settings
            .detector
            .model_for(settings.seeds.sensor, v, type_id)
        {
            Some(m) => m.sensors().to_vec(),
            None => paper_rig(&settings.camera),
        }
    });
    let reach_m = sensors
        .iter()
        .flatten()
        .map(|s| s.geometry.range_m)
        .fold(0.0, f64::max);
    let view = SceneView {
        scene: inst.scene,
        frame: inst.frame,
        sensors,
        egos: [(a.obs, a.truth), (b.obs, b.truth)],
        vehicles,
        matches: &e.identification.matches,
        caption: format!(
            "{} @ {} pose noise, t = {:.1} s: {} vs {}, precision {}, recall {}",
            e.method.as_str(),
            level.label.as_str(),
            inst.frame.time_s,
            a.obs.ego_id,
            b.obs.ego_id,
            fmt_num(e.counts.precision(), 2),
            fmt_num(e.counts.recall(), 2)
        ),
        half_window_m: reach_m + 10.0,
    };
    render::render_scene(&view, stem, 1000).map_err(|e| RunError::Render(e.to_string()))
}
