//! `coid scenarios`: a seeded family of generated intersections, one
//! folder each (SUMO net, buildings, demand, `.sumocfg`, `coid.toml`).

use std::path::PathBuf;

use super::{ForceArg, QuietArg, label_arg};
use crate::bridge;
use crate::io;
use crate::scenarios::{self, Demand, Kind, Scenario};

#[derive(clap::Args)]
pub struct Args {
    /// How many scenarios to generate (folders s000, s001, ...).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    count: u64,
    /// Family seed: the same seed and count give the same bytes.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Index of the first scenario (to extend a family, or to keep two
    /// families of one seed apart; folder names have up to six digits).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=999_999))]
    first: u64,
    /// Only these kinds of layout (crossing, arterial, cluster,
    /// roundabout, ramp) [default: all, drawn as the family mixes them].
    #[arg(long, value_delimiter = ',', value_parser = label_arg::<Kind>("scenario kind"))]
    kinds: Vec<Kind>,
    /// Take the kinds in turn (scenario i is of kind i mod their number)
    /// instead of drawing them: a family with every kind evenly, for
    /// validation and test families.
    #[arg(long)]
    cycle_kinds: bool,
    /// Road users of the demand: "mix" (the shipped intersection's vehicle
    /// classes, sizes and colours) or "plain" (SUMO's default types only,
    /// one size and colour, as demand from SUMO's own tools usually is).
    /// The layouts are the same for both.
    #[arg(long, default_value = "mix", value_parser = label_arg::<Demand>("demand"))]
    demand: Demand,
    /// Output folder.
    #[arg(long, short)]
    out: PathBuf,
    #[command(flatten)]
    force: ForceArg,
    #[command(flatten)]
    quiet: QuietArg,
}

pub fn scenarios(a: Args) -> anyhow::Result<()> {
    let bar = super::progress_bar(
        a.quiet.quiet,
        a.count,
        "{spinner} scenarios [{bar:30}] {pos}/{len} elapsed {elapsed} eta {eta}",
    );
    // Into a new folder, or one that holds a family (to extend it).
    io::check_extendable(&a.out, io::ResultKind::Family, io::Existing::Replace)?;
    let end = a
        .first
        .checked_add(a.count)
        .filter(|&e| e <= 1_000_000)
        .ok_or_else(|| anyhow::anyhow!("--first + --count must stay within 1 000 000 scenarios"))?;
    let mut lines = Vec::new();
    for index in a.first..end {
        let mut s = if a.cycle_kinds {
            let kinds = if a.kinds.is_empty() {
                Kind::all()
            } else {
                &a.kinds[..]
            };
            let kind = kinds[(index % kinds.len() as u64) as usize];
            scenarios::generate(a.seed, index, &[kind])
        } else {
            scenarios::generate(a.seed, index, &a.kinds)
        };
        s.demand = a.demand;
        write(&a, &s)?;
        lines.push(format!("- {}", s.describe()));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut kinds = if a.kinds.is_empty() {
        String::new()
    } else {
        let names: Vec<&str> = a.kinds.iter().map(|k| k.as_str()).collect();
        format!(" --kinds {}", names.join(","))
    };
    if a.cycle_kinds {
        kinds.push_str(" --cycle-kinds");
    }
    if a.demand != Demand::Mix {
        kinds.push_str(&format!(" --demand {}", a.demand.as_str()));
    }
    let index = format!(
        "# Generated scenarios\n\n`coid scenarios --count {} --seed {} --first {}{kinds}`; each \
         folder runs with `coid run --config <folder>/coid.toml`.\n\n{}\n",
        a.count,
        a.seed,
        a.first,
        lines.join("\n")
    );
    io::publish_files(&a.out, |dir| io::write_texts(dir, &[("README.md", index)]))?;
    io::folder::mark_folder(&a.out, io::ResultKind::Family)?;
    eprintln!(
        "coid: {} scenarios (seed {}) in {}",
        a.count,
        a.seed,
        a.out.display()
    );
    Ok(())
}

fn write(a: &Args, s: &Scenario) -> anyhow::Result<()> {
    let claim = io::Claim::new(
        &a.out.join(&s.name),
        io::ResultKind::Scenario,
        io::Existing::when(a.force.force),
    )?;
    claim.fill(|dir| -> anyhow::Result<()> {
        io::write_texts(dir, &s.files())?;
        bridge::netconvert(dir, &s.netconvert_args())?;
        io::strip_generator_comment(&dir.join("net.net.xml"))?;
        Ok(())
    })
}
