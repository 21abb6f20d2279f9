//! `coid eval`: every method on the test runs, the paper's tables and
//! plots.

use anyhow::Context;

use super::{CommonArgs, progress_bar};
use crate::experiments;
use crate::io::{self, OutputError};
use crate::matching::Method;
use crate::{pipeline, render, tables};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Evaluate on the validation runs ([train] validation_seeds) instead
    /// of the test runs, into results/<config file stem>-validation: the
    /// runs every choice (lambda, the sensor-noise calibration) is made on.
    #[arg(long)]
    validation: bool,
}

pub fn eval(a: Args) -> anyhow::Result<()> {
    let suffix = if a.validation { "-validation" } else { "-eval" };
    let (mut settings, out) = a.common.prepare(suffix)?;
    if a.validation {
        // The tables' header names the runs evaluated.
        settings.eval.traffic_seeds = settings.train.validation_seeds.clone();
    }
    let seeds = settings.eval.traffic_seeds.clone();
    let pb = progress_bar(
        a.common.quiet.quiet,
        seeds.len() as u64,
        "{spinner} evaluating: run {pos}/{len} [{bar:30}] {msg} eta {eta}",
    );
    // Every method of the paper's Table 1 plus the practical ones.
    let methods = Method::all();
    let lambdas = pipeline::lambdas(&settings, methods)?;
    let mut runs = Vec::new();
    for &seed in &seeds {
        let run = experiments::settings_for_seed(&settings, seed);
        pb.set_message(format!("seed {seed}"));
        let r = experiments::eval_run(&run, methods, &lambdas, |_| {})
            .with_context(|| format!("test run with seed {seed} failed"))?;
        runs.push(r);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let tables = tables::eval_tables(&settings, &runs, &lambdas);
    let plots = tables::plot_data(&settings, &runs, &lambdas);
    io::write_eval(
        &out,
        &settings,
        &tables.files(),
        &lambdas,
        a.common.force,
        |dir| {
            render::eval_plots(dir, &plots).map_err(|e| OutputError::Picture {
                path: dir.to_owned(),
                message: e.to_string(),
            })
        },
    )?;
    let instances: usize = runs.iter().map(|r| r.instances).sum();
    eprintln!(
        "coid: evaluated {} methods on {} {} runs ({instances} instances); wrote {}",
        methods.len(),
        runs.len(),
        if a.validation { "validation" } else { "test" },
        out.display()
    );
    Ok(())
}
