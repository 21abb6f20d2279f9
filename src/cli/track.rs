//! `coid track`: every connected vehicle's tracker, its CPMs over the
//! channel, and what the receivers make of them, over one run.

use anyhow::Context;

use super::{CommonArgs, show_sim_progress};
use crate::{io, pipeline, report};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
}

pub fn track(a: Args) -> anyhow::Result<()> {
    let (settings, out) = a.common.prepare("-track", io::ResultKind::Track)?;
    let bar = a.common.sim_bar(settings.scenario.end_s);
    let results =
        pipeline::track(&settings, |p| show_sim_progress(&bar, p)).context("run failed")?;
    bar.finish_and_clear();
    let tracking = report::tracking_table(&results.vehicles);
    let association = results.over_time.table();
    let existing = io::Existing::when(a.common.force, io::ResultKind::Track);
    io::write_tracking(&out, existing, &tracking, &association)?;
    let mut all = report::VehicleTracking::default();
    for v in &results.vehicles {
        all.add(v);
    }
    let o = &results.over_time;
    eprintln!(
        "coid: {} connected vehicles tracked, MOTA {:.3}; {} CPMs, {} of {} deliveries lost; \
         {} receptions: pair F1 {:.3} per message, {:.3} over time; wrote {}",
        results.vehicles.len(),
        all.mot.mota(),
        all.messages,
        all.lost,
        all.delivered + all.lost,
        o.receptions,
        o.per_message.f1(),
        o.over_time.f1(),
        out.display()
    );
    Ok(())
}
