//! `coid convert pyg` and `coid dataset`: their arguments parsed,
//! `commands::convert_pyg` and `commands::check_dataset` called, what
//! they return printed.

use std::ops::RangeInclusive;
use std::path::PathBuf;

use super::{ForceArg, QuietArg};
use crate::commands;

#[derive(clap::Args)]
pub struct ConvertArgs {
    #[command(subcommand)]
    what: ConvertWhat,
}

#[derive(clap::Subcommand)]
enum ConvertWhat {
    /// PyTorch Geometric pair data as DMGM distributes it: one folder per
    /// view (`--views`), `<view>/<k>/data.pt` per pair index k, each a
    /// `Data` with `pos` (camera frame), `y` (object ids) and, where
    /// given, `x` (appearance), `pos_world`, `label` and `name`. The .pt
    /// files are read without torch and nothing in them is run.
    Pyg(PygArgs),
}

#[derive(clap::Args)]
struct PygArgs {
    /// The folder holding the views' folders (DMGM: data/testdata).
    source: PathBuf,
    /// The dataset folder to write.
    #[arg(long, short)]
    out: PathBuf,
    /// Each split's pair indices, as `<split>=<first>..<last>` (train,
    /// validation or test), e.g. `validation=60260..64006
    /// test=64007..69468`.
    #[arg(long, num_args = 1.., required = true, value_parser = split_range)]
    splits: Vec<(String, RangeInclusive<u64>)>,
    /// The views' folder names: the first and the second vehicle.
    #[arg(long, num_args = 2, default_values = ["proc_s", "proc_t"])]
    views: Vec<String>,
    /// The source's name: runs are `<name>/<recording>`.
    #[arg(long, default_value = "dmgm")]
    name: String,
    /// The position noise (per axis, m) of the GPS poses the source's
    /// world positions went through (DMGM: 1.2).
    #[arg(long, default_value_t = 1.2, allow_negative_numbers = true)]
    gps_sigma_m: f64,
    /// Their heading noise, degrees (DMGM: 0.2).
    #[arg(long, default_value_t = 0.2, allow_negative_numbers = true)]
    gps_heading_sigma_deg: f64,
    #[command(flatten)]
    force: ForceArg,
    #[command(flatten)]
    quiet: QuietArg,
}

fn split_range(s: &str) -> Result<(String, RangeInclusive<u64>), String> {
    let (split, range) = s
        .split_once('=')
        .ok_or("expected <split>=<first>..<last>")?;
    if !["train", "validation", "test"].contains(&split) {
        return Err(format!(
            "'{split}' is not a split (train, validation, test)"
        ));
    }
    let (a, b) = range
        .split_once("..")
        .ok_or("expected <split>=<first>..<last>")?;
    let num = |x: &str| {
        x.trim()
            .parse::<u64>()
            .map_err(|_| format!("'{x}' is not a pair index"))
    };
    let (a, b) = (num(a)?, num(b)?);
    if a > b {
        return Err(format!("the range {a}..{b} is empty"));
    }
    Ok((split.to_owned(), a..=b))
}

pub fn convert(a: ConvertArgs) -> anyhow::Result<()> {
    let ConvertWhat::Pyg(a) = a.what;
    let request = commands::ConvertPygRequest {
        source: a.source,
        views: [a.views[0].clone(), a.views[1].clone()],
        splits: a.splits,
        name: a.name,
        gps_sigma_m: a.gps_sigma_m,
        gps_heading_sigma_deg: a.gps_heading_sigma_deg,
        out: a.out,
        force: a.force.force,
    };
    let mut bars = super::Bars::new(a.quiet.quiet, "converting");
    let report = commands::convert_pyg(&request, |e| bars.show(e));
    bars.clear();
    let report = report?;
    for w in report.warnings() {
        eprintln!("{w}");
    }
    println!("{}", report.line());
    Ok(())
}

#[derive(clap::Args)]
pub struct DatasetArgs {
    /// A dataset folder (coid export or coid convert).
    dir: PathBuf,
}

/// Checks a dataset and says what it holds, split by split (read one run
/// at a time).
pub fn dataset(a: DatasetArgs) -> anyhow::Result<()> {
    for line in commands::check_dataset(&a.dir)?.lines() {
        println!("{line}");
    }
    Ok(())
}
