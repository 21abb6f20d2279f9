//! `coid convert pyg`: PyTorch Geometric pairs recorded elsewhere (DMGM's
//! layout) into a dataset; `coid dataset`: a dataset checked and
//! summarised.

use std::collections::BTreeMap;
use std::ops::RangeInclusive;
use std::path::PathBuf;

use anyhow::{Context, bail};

use super::{ForceArg, QuietArg, progress_bar};
use crate::dataset::{self, SCHEMA, SCHEMA_VERSION, convert};
use crate::io;

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
    for (name, v) in [
        ("--gps-sigma-m", a.gps_sigma_m),
        ("--gps-heading-sigma-deg", a.gps_heading_sigma_deg),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{name} must be a number >= 0, not {v}");
        }
    }
    if a.views[0] == a.views[1] {
        bail!(
            "--views names {} twice: the two vehicles' folders differ",
            a.views[0]
        );
    }
    check_source_name(&a.name)?;
    for v in &a.views {
        if !a.source.join(v).is_dir() {
            bail!(
                "{} has no folder {v} (the views' folders, --views)",
                a.source.display()
            );
        }
    }
    let source = convert::PygSource {
        dir: a.source.clone(),
        views: [a.views[0].clone(), a.views[1].clone()],
        splits: a.splits.clone(),
        name: a.name.clone(),
        position_sigma_m: a.gps_sigma_m,
        heading_sigma_rad: a.gps_heading_sigma_deg.to_radians(),
    };
    let pairs = source.pairs().map_err(anyhow::Error::msg)?;
    let claim = io::Claim::new(
        &a.out,
        io::ResultKind::Export,
        io::Existing::when(a.force.force),
    )?;
    let templates: Vec<(&str, crate::report::Table)> =
        std::iter::once((dataset::schema::Run::FILE, crate::report::Table::default()))
            .chain(convert::PairRows::default().tables())
            .collect();
    let mut folder = io::TablesFolder::create(claim, &templates)?;
    let pb = progress_bar(
        a.quiet.quiet,
        pairs.len() as u64,
        "{spinner} converting: pair {pos}/{len} [{bar:30}] eta {eta}",
    );
    let mut conv = convert::Converter::default();
    let mut write = |conv: &mut convert::Converter| -> anyhow::Result<()> {
        for (file, table) in conv.take().tables() {
            folder.write(file, &table)?;
        }
        Ok(())
    };
    for (k, split) in pairs {
        let views = source.read_pair(k).map_err(anyhow::Error::msg)?;
        conv.add(&source, k, split, views)
            .map_err(anyhow::Error::msg)?;
        if conv.held() >= 16_384 {
            write(&mut conv)?;
        }
        pb.inc(1);
    }
    write(&mut conv)?;
    pb.finish_and_clear();
    if conv.runs.is_empty() {
        bail!(
            "no pair of {} has detections in both views: nothing to convert",
            a.source.display()
        );
    }
    folder.write(dataset::schema::Run::FILE, &conv.run_table(SCHEMA_VERSION))?;
    folder.finish(&[("schema.md", SCHEMA.to_owned())])?;
    say_converted(&conv, &a.out);
    Ok(())
}

/// The conversion's line (pairs, runs, pairs left out), after a warning
/// for each recording the splits cut.
fn say_converted(conv: &convert::Converter, out: &std::path::Path) {
    for (recording, splits) in conv.split_recordings() {
        eprintln!(
            "warning: --splits cuts recording {recording} between {}: its frames are alike, so \
             what is chosen on one split is seen again on the other",
            splits.join(" and ")
        );
    }
    let n_instances: u64 = conv.runs.iter().map(|r| r.n_instances).sum();
    let skipped = match conv.skipped.as_slice() {
        [] => String::new(),
        s => format!(
            " ({} {} left out: a vehicle saw nothing, e.g. pair {} in {})",
            s.len(),
            plural(s.len(), "pair", "pairs"),
            s[0].0,
            s[0].1
        ),
    };
    println!(
        "converted {n_instances} {} into {} {}{skipped}: {}",
        plural(n_instances as usize, "pair", "pairs"),
        conv.runs.len(),
        plural(conv.runs.len(), "run", "runs"),
        out.display()
    );
}

fn plural<'a>(n: usize, one: &'a str, many: &'a str) -> &'a str {
    if n == 1 { one } else { many }
}

/// A source's name becomes the first part of each run's scenario: one
/// plain word (letters, digits, `.`, `_`, `-`).
fn check_source_name(name: &str) -> anyhow::Result<()> {
    let plain = name
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'));
    if name.is_empty() || !plain || name.chars().all(|c| c == '.') {
        bail!(
            "--name {name:?} is not a plain word (letters, digits, '.', '_', '-'): runs are \
             named <name>/<recording>"
        );
    }
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
    let unusable = || format!("{} is not a usable dataset", a.dir.display());
    let d = dataset::Dataset::open(&a.dir).with_context(unusable)?;
    println!(
        "dataset {}: {} {}",
        a.dir.display(),
        d.runs.len(),
        plural(d.runs.len(), "run", "runs")
    );
    // Per split: runs, instances, nodes, true pairs.
    let mut counts: BTreeMap<&str, [usize; 4]> = BTreeMap::new();
    for k in 0..d.runs.len() {
        let run = d.run(k).with_context(unusable)?;
        let c = counts
            .entry(
                ["train", "validation", "test"]
                    .into_iter()
                    .find(|s| *s == run.info.split)
                    .unwrap_or("test"),
            )
            .or_default();
        c[0] += 1;
        for i in &run.instances {
            c[1] += 1;
            c[2] += i.sides[0].nodes.len() + i.sides[1].nodes.len();
            c[3] += i.true_pairs.len();
        }
    }
    for split in ["train", "validation", "test"] {
        let Some(&[runs, insts, nodes, shared]) = counts.get(split) else {
            continue;
        };
        let n = insts.max(1) as f64;
        println!(
            "  {split}: {runs} {}, {insts} instances, {:.1} nodes per vehicle, {:.1} true pairs \
             per instance",
            plural(runs, "run", "runs"),
            nodes as f64 / (2.0 * n),
            shared as f64 / n
        );
    }
    let empty: Vec<String> = d
        .runs
        .iter()
        .filter(|r| r.n_instances == 0)
        .map(|r| format!("run {} ({}, {})", r.run, r.split, r.scenario))
        .collect();
    if !empty.is_empty() {
        println!(
            "  runs without instances: {} (tables average over the runs that have some): {}",
            empty.len(),
            empty.join(", ")
        );
    }
    let levels: Vec<String> = d
        .levels
        .iter()
        .map(|l| format!("{} ({} m)", l.label.as_str(), l.position_sigma_m))
        .collect();
    println!("  pose-noise levels: {}", levels.join(", "));
    match d.appearance_width.width() {
        Some(w) => println!("  appearance vectors: {w} values per node"),
        None => println!("  appearance vectors: none"),
    }
    println!(
        "  optional columns: {}",
        if d.optional_columns.is_empty() {
            "none".to_owned()
        } else {
            d.optional_columns.join(", ")
        }
    );
    Ok(())
}
