//! `run`: one scenario headless, its results into one folder
//! (`summary.csv`, `objects.parquet`, `summary.md`).

use std::path::PathBuf;

use anyhow::Context;

use super::{Common, Event};
use crate::config::{Overrides, Settings};
use crate::fusion::FusionVariant;
use crate::io;
use crate::matching::Method;
use crate::pipeline;
use crate::report::RunResults;
use crate::sensor::PoseNoiseLabel;

/// What to run and where its results go.
#[derive(Clone, Debug, PartialEq)]
pub struct RunRequest {
    pub common: Common,
    /// `[seeds] traffic` and `sensor` set over the configuration's.
    pub traffic_seed: Option<u64>,
    pub sensor_seed: Option<u64>,
}

impl RunRequest {
    /// A run of `config` with everything else at its default.
    pub fn of(config: super::ConfigSource) -> Self {
        Self {
            common: Common::of(config),
            traffic_seed: None,
            sensor_seed: None,
        }
    }
}

/// What a run wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct RunReport {
    /// The results folder.
    pub folder: PathBuf,
    pub instances: usize,
    /// The run in one line: instances, speed, and the headline methods at
    /// GPS noise with aligned fusion.
    pub headline: String,
    /// With no instance, why there may have been none.
    pub no_instance: Option<String>,
}

/// Runs the scenario of `request` and writes its results folder.
///
/// # Errors
/// The configuration, the results folder (taken, not writable), SUMO or
/// a stage fails; the folder is then not left half-written.
pub fn run(request: &RunRequest, mut on: impl FnMut(Event)) -> anyhow::Result<RunReport> {
    let common = &request.common;
    let threads = super::threads(common.threads)?;
    let overrides = Overrides {
        traffic_seed: request.traffic_seed,
        sensor_seed: request.sensor_seed,
        ..Default::default()
    };
    let settings = super::prepare(&common.config, &overrides, None, &mut on)?;
    let claim = common.claim("", None, io::ResultKind::Run)?;
    let out = claim.out().to_owned();
    // The folder is claimed (and checked writable) before the simulation.
    let mut folder = io::RunFolder::create(claim)?;
    let results = pipeline::run(
        &settings,
        threads,
        &pipeline::Warnings::default(),
        |p| on(Event::Simulating(p)),
        |rows| folder.objects(rows),
    )
    .context("run failed")?;
    folder.finish(&settings, &results)?;
    Ok(RunReport {
        folder: out,
        instances: results.n_instances,
        headline: headline(&results),
        no_instance: (results.n_instances == 0).then(|| why_no_instance(&settings)),
    })
}

/// The run in one line: instances, speed, and the headline methods at GPS
/// noise with aligned fusion.
fn headline(results: &RunResults) -> String {
    let rows = results.summary.rows();
    let mut line = format!(
        "coid: {} instances in {:.1} s of traffic ({:.1} s wall, SUMO bridge {:.2} ms/step)",
        results.n_instances,
        results.sim_end_s,
        results.wall_time.as_secs_f64(),
        results.bridge_time.as_secs_f64() * 1e3 / results.n_steps.max(1) as f64,
    );
    if results.network_macs > 0 {
        let gflop = 2.0 * results.network_macs as f64 / 1e9;
        line.push_str(&format!(
            "; networks {gflop:.1} GFLOP, {:.1} GFLOP/s",
            gflop / results.wall_time.as_secs_f64().max(1e-9)
        ));
    }
    for m in [Method::Ours, Method::GpsHungarian, Method::Oracle] {
        let row = rows.iter().find(|r| {
            r.key.method == m
                && r.key.pose_noise == PoseNoiseLabel::GPS
                && r.key.fusion == FusionVariant::Aligned
        });
        if let Some(r) = row {
            line.push_str(&format!(
                "; {} @gps/aligned F1 {:.3}, DE {:.2} -> {:.2} m",
                m.as_str(),
                r.f1,
                r.de_single_m,
                r.de_fused_m
            ));
        }
    }
    line
}

/// Why a run may have had no instance, naming the settings that decide
/// it: with `[v2x] mode = "cpm"` an instance is a message that arrived,
/// so a channel that loses every message, or delivers none before the
/// run ends, comes first.
pub fn why_no_instance(settings: &Settings) -> String {
    use crate::v2x::V2xMode;
    use crate::v2x::channel::LossModel;
    let sc = &settings.scenario;
    let plain = format!(
        "no two connected vehicles near junction '{}' saw a common object in {} s (see \
         [connected], [scenario] radius_m and end_s)",
        sc.junction, sc.end_s
    );
    if settings.v2x.mode != V2xMode::Cpm {
        return plain;
    }
    let ch = &settings.v2x.channel;
    let p0 = match ch.loss {
        LossModel::Independent { probability } => probability,
        LossModel::Distance {
            probability_at_0, ..
        } => probability_at_0,
    };
    if p0 >= 1.0 {
        format!(
            "the channel loses every message ([v2x.channel] loss_probability = {p0}), so none \
             arrived"
        )
    } else if ch.latency_s >= sc.end_s {
        format!(
            "no message arrives within the run: [v2x.channel] latency_s ({} s) is not shorter \
             than [scenario] end_s ({} s)",
            ch.latency_s, sc.end_s
        )
    } else {
        format!(
            "no message that arrived shared an object with its receiver's tracks (see \
             [v2x.channel] and [v2x.cpm]); or {plain}"
        )
    }
}
