//! `coid run`: one scenario headless, results into one folder.

use anyhow::Context;

use super::{CommonArgs, ThreadsArg, show_sim_progress};
use crate::fusion::FusionVariant;
use crate::matching::Method;
use crate::report::RunResults;
use crate::sensor::PoseNoiseLabel;
use crate::{io, pipeline};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
    #[command(flatten)]
    threads: ThreadsArg,
    /// Override [seeds] traffic (SUMO's seed, 0 to 2147483647).
    #[arg(long, value_parser = clap::value_parser!(u64).range(0..=crate::config::MAX_TRAFFIC_SEED))]
    traffic_seed: Option<u64>,
    /// Override [seeds] sensor.
    #[arg(long)]
    sensor_seed: Option<u64>,
}

/// Runs the scenario; returns the line it printed last.
pub fn run(a: Args) -> anyhow::Result<String> {
    let overrides = crate::config::Overrides {
        traffic_seed: a.traffic_seed,
        sensor_seed: a.sensor_seed,
        ..Default::default()
    };
    let (settings, claim) = a.common.prepare_with("", io::ResultKind::Run, &overrides)?;
    // The folder is claimed (and checked writable) before the simulation.
    let out = claim.out().to_owned();
    let mut folder = io::RunFolder::create(claim)?;
    let bar = a.common.sim_bar(settings.scenario.end_s);
    let results = pipeline::run(
        &settings,
        a.threads.get(),
        &pipeline::Warnings::default(),
        |p| show_sim_progress(&bar, p),
        |rows| folder.objects(rows),
    )
    .context("run failed")?;
    bar.finish_and_clear();
    folder.finish(&settings, &results)?;
    if results.n_instances == 0 {
        eprintln!("coid: warning: no instance: {}", why_no_instance(&settings));
    }
    let line = format!("{}; wrote {}", one_line(&results), out.display());
    eprintln!("{line}");
    Ok(line)
}

/// The run in one line: instances, speed, and the headline methods at GPS
/// noise with aligned fusion.
fn one_line(results: &RunResults) -> String {
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
                && r.key.pose_noise == PoseNoiseLabel::Gps
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
pub(super) fn why_no_instance(settings: &crate::config::Settings) -> String {
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
