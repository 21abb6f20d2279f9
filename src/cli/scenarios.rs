//! `coid scenarios`: a seeded family of generated intersections, one
//! folder each (SUMO net, buildings, demand, `.sumocfg`, `coid.toml`).

use std::path::PathBuf;

use crate::bridge;
use crate::io;
use crate::scenarios::{self, Scenario};

#[derive(clap::Args)]
pub struct Args {
    /// How many scenarios to generate (folders s000, s001, ...).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    count: u64,
    /// Family seed: the same seed and count give the same bytes.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Index of the first scenario (to extend a family, or to keep two
    /// families of one seed apart).
    #[arg(long, default_value_t = 0)]
    first: u64,
    /// Output folder.
    #[arg(long, short)]
    out: PathBuf,
    /// Replace scenario folders that exist.
    #[arg(long)]
    force: bool,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

pub fn scenarios(a: Args) -> anyhow::Result<()> {
    let bar = super::progress_bar(
        a.quiet,
        a.count,
        "{spinner} scenarios [{bar:30}] {pos}/{len} elapsed {elapsed} eta {eta}",
    );
    let mut lines = Vec::new();
    for index in a.first..a.first + a.count {
        let s = scenarios::generate(a.seed, index);
        write(&a, &s)?;
        lines.push(format!("- {}", s.describe()));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let index = format!(
        "# Generated scenarios\n\n`coid scenarios --count {} --seed {} --first {}`; each folder \
         runs with `coid run --config <folder>/coid.toml`.\n\n{}\n",
        a.count,
        a.seed,
        a.first,
        lines.join("\n")
    );
    io::publish_files(&a.out, |dir| io::write_texts(dir, &[("README.md", index)]))?;
    eprintln!(
        "coid: {} scenarios (seed {}) in {}",
        a.count,
        a.seed,
        a.out.display()
    );
    Ok(())
}

fn write(a: &Args, s: &Scenario) -> anyhow::Result<()> {
    io::atomic_dir(&a.out.join(&s.name), a.force, |dir| -> anyhow::Result<()> {
        io::write_texts(dir, &s.files())?;
        bridge::netconvert(dir, &Scenario::netconvert_args())?;
        io::strip_generator_comment(&dir.join("net.net.xml"))?;
        Ok(())
    })
}
