//! `coid track`: every connected vehicle's tracker and CPMs over one run.

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
    let vehicles =
        pipeline::track(&settings, |p| show_sim_progress(&bar, p)).context("run failed")?;
    bar.finish_and_clear();
    let table = report::tracking_table(&vehicles);
    io::write_tracking(
        &out,
        io::Existing::when(a.common.force, io::ResultKind::Track),
        &table,
    )?;
    let mut all = report::VehicleTracking::default();
    for v in &vehicles {
        all.add(v);
    }
    let sent = all.delivered + all.lost;
    eprintln!(
        "coid: {} connected vehicles tracked; MOTA {:.3}, MOTP {:.2} m, {} id switches; {} CPMs, {} of {} deliveries lost; wrote {}",
        vehicles.len(),
        all.mot.mota(),
        all.mot.motp_m(),
        all.mot.id_switches,
        all.messages,
        all.lost,
        sent,
        out.display()
    );
    Ok(())
}
