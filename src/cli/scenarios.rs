//! `coid scenarios`: a seeded family of generated intersections, one
//! folder each (SUMO net, buildings, demand, `.sumocfg`, `coid.toml`).
//! A family is written like every other output: staged, then published
//! whole (a new family as one folder, the scenarios that extend a family
//! with its README at once).

use std::path::{Path, PathBuf};

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
    /// Output folder: a new family, or one to extend (scenarios of the
    /// same --seed; --force replaces those it already has).
    #[arg(long, short)]
    out: PathBuf,
    #[command(flatten)]
    force: ForceArg,
    #[command(flatten)]
    quiet: QuietArg,
}

/// A family's scenarios: each folder's name and its description.
type Lines = Vec<(String, String)>;

/// The family README's heading; its next paragraph names the commands
/// that wrote the family.
const README_HEAD: &str = "# Generated scenarios\n\n";

/// What each folder runs with, after the commands.
const RUN_WITH: &str = "; each folder runs with `coid run --config <folder>/coid.toml`.";

pub fn scenarios(a: Args) -> anyhow::Result<()> {
    let end = a
        .first
        .checked_add(a.count)
        .filter(|&e| e <= 1_000_000)
        .ok_or_else(|| anyhow::anyhow!("--first + --count must stay within 1 000 000 scenarios"))?;
    let family: Vec<Scenario> = (a.first..end).map(|index| scenario(&a, index)).collect();
    // Into a new folder, or one that holds a family (to extend it).
    io::check_extendable(&a.out, io::ResultKind::Family, io::Existing::Replace)?;
    let bar = super::progress_bar(
        a.quiet.quiet,
        a.count,
        "{spinner} scenarios [{bar:30}] {pos}/{len} elapsed {elapsed} eta {eta}",
    );
    let write_all = |dir: &Path, readme: String| -> anyhow::Result<()> {
        for s in &family {
            write(&dir.join(&s.name), s)?;
            bar.inc(1);
        }
        io::write_texts(dir, &[("README.md", readme)])?;
        Ok(())
    };
    if a.out.is_dir() {
        let (commands, held) = check_extension(&a, &family)?;
        // The family's scenarios by name, those written now replacing
        // those of the same name.
        let mut lines: std::collections::BTreeMap<String, String> = held.into_iter().collect();
        lines.extend(family.iter().map(|s| (s.name.clone(), s.describe())));
        let lines: Vec<(String, String)> = lines.into_iter().collect();
        let readme = readme(&commands, &command(&a), &lines);
        io::publish_files(&a.out, |dir| write_all(dir, readme))?;
    } else {
        let claim = io::Claim::new(&a.out, io::ResultKind::Family, io::Existing::Refuse)?;
        let lines: Vec<(String, String)> = family
            .iter()
            .map(|s| (s.name.clone(), s.describe()))
            .collect();
        write_all(claim.dir(), readme(&[], &command(&a), &lines))?;
        claim.publish()?;
    }
    bar.finish_and_clear();
    eprintln!(
        "coid: {} (seed {}) in {}",
        crate::label::counted(a.count, "scenario"),
        a.seed,
        a.out.display()
    );
    Ok(())
}

/// Scenario `index` of the family `a` asks for.
fn scenario(a: &Args, index: u64) -> Scenario {
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
    s
}

/// The command that writes what `a` asks for.
fn command(a: &Args) -> String {
    let mut c = format!(
        "coid scenarios --count {} --seed {} --first {}",
        a.count, a.seed, a.first
    );
    if !a.kinds.is_empty() {
        let names: Vec<&str> = a.kinds.iter().map(|k| k.as_str()).collect();
        c.push_str(&format!(" --kinds {}", names.join(",")));
    }
    if a.cycle_kinds {
        c.push_str(" --cycle-kinds");
    }
    if a.demand != Demand::Mix {
        c.push_str(&format!(" --demand {}", a.demand.as_str()));
    }
    c
}

/// The family's README: the commands that wrote it (`earlier`, then
/// `this`), and one line per scenario folder (`lines`: name and
/// description, sorted).
fn readme(earlier: &[String], this: &str, lines: &[(String, String)]) -> String {
    let commands: Vec<String> = earlier
        .iter()
        .map(String::as_str)
        .chain([this])
        .map(|c| format!("`{c}`"))
        .collect();
    let list: Vec<String> = lines
        .iter()
        .filter(|(_, d)| !d.is_empty())
        .map(|(_, d)| format!("- {d}"))
        .collect();
    format!(
        "{README_HEAD}{}{RUN_WITH}\n\n{}\n",
        commands.join(", then "),
        list.join("\n")
    )
}

/// Checks that the family at `a.out` may take `family`: every scenario it
/// holds is of the same family seed, and a scenario folder it already has
/// is replaced only with `--force`, and only when coid wrote it as it is.
/// Returns the commands its README names and its scenarios' lines.
fn check_extension(a: &Args, family: &[Scenario]) -> anyhow::Result<(Vec<String>, Lines)> {
    let (readme, lines) = io::read_family(&a.out)?;
    for (name, described) in &lines {
        if let Some(seed) = family_seed(described)
            && seed != a.seed
        {
            anyhow::bail!(
                "{} holds scenarios of family seed {seed} ({name}): extend it with --seed \
                 {seed}, or write seed {} to another --out",
                a.out.display(),
                a.seed
            );
        }
    }
    for s in family {
        if !lines.iter().any(|(name, _)| name == &s.name) {
            continue;
        }
        let dir = a.out.join(&s.name);
        if !a.force.force {
            anyhow::bail!(
                "{} exists (pass --force to replace the family's scenarios from --first {})",
                dir.display(),
                a.first
            );
        }
        io::ResultKind::Scenario
            .check(&dir)
            .map_err(|why| anyhow::anyhow!("--force does not replace {}: {why}", dir.display()))?;
    }
    Ok((commands_of(&readme), lines))
}

/// The family seed a scenario's description names ("... (family seed 4,
/// index 2)").
fn family_seed(described: &str) -> Option<u64> {
    let (_, tail) = described.rsplit_once("(family seed ")?;
    tail.split(',').next()?.trim().parse().ok()
}

/// The commands a family README names (in its first paragraph).
fn commands_of(readme: &str) -> Vec<String> {
    let Some(body) = readme.strip_prefix(README_HEAD) else {
        return Vec::new();
    };
    let first = body.split(RUN_WITH).next().unwrap_or_default();
    first
        .split('`')
        .skip(1)
        .step_by(2)
        .filter(|c| c.starts_with("coid scenarios"))
        .map(str::to_owned)
        .collect()
}

/// Writes scenario `s` into `dir` (a new folder inside the staged family).
fn write(dir: &Path, s: &Scenario) -> anyhow::Result<()> {
    let claim = io::Claim::new(dir, io::ResultKind::Scenario, io::Existing::Refuse)?;
    claim.fill(|dir| -> anyhow::Result<()> {
        io::write_texts(dir, &s.files())?;
        bridge::netconvert(dir, &s.netconvert_args())?;
        io::strip_generator_comment(&dir.join("net.net.xml"))?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A family README names its commands and its scenarios; an extended
    /// one keeps the earlier commands, which are read back from it.
    #[test]
    fn a_family_readme_names_every_command_and_scenario() {
        let lines = |names: &[&str]| -> Vec<(String, String)> {
            names
                .iter()
                .map(|n| (n.to_string(), format!("{n}: x (family seed 4, index 0)")))
                .collect()
        };
        let first = readme(
            &[],
            "coid scenarios --count 2 --seed 4 --first 0",
            &lines(&["s000"]),
        );
        assert_eq!(
            first,
            "# Generated scenarios\n\n`coid scenarios --count 2 --seed 4 --first 0`; each \
             folder runs with `coid run --config <folder>/coid.toml`.\n\n- s000: x (family \
             seed 4, index 0)\n"
        );
        let commands = commands_of(&first);
        assert_eq!(commands, ["coid scenarios --count 2 --seed 4 --first 0"]);
        let second = readme(
            &commands,
            "coid scenarios --count 1 --seed 4 --first 2",
            &lines(&["s000", "s002"]),
        );
        assert!(second.contains("--first 0`, then `coid scenarios --count 1 --seed 4 --first 2`"));
        assert_eq!(commands_of(&second).len(), 2);
        assert_eq!(family_seed("s002: x (family seed 4, index 2)"), Some(4));
        assert_eq!(family_seed("s002: x"), None);
    }
}
