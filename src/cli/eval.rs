//! `coid eval`: every method on the test runs, the paper's tables and
//! plots; with `--suite`, over several scenarios, per scenario and pooled.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use indicatif::ProgressBar;

use super::{CommonArgs, ThreadsArg, progress_bar};
use crate::commands::write_eval;
use crate::config::Settings;
use crate::experiments;
use crate::io;
use crate::io::records::ModelRecord;
use crate::matching::{self, Method, MethodKind, MethodLambdas};
use crate::pipeline;
use crate::tables::RunEval;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
    #[command(flatten)]
    threads: ThreadsArg,
    /// Evaluate on the validation runs ([train] validation_seeds) instead
    /// of the test runs, into results/<config file stem>-validation: the
    /// runs every choice (lambda, the sensor-noise calibration) is made on.
    #[arg(long)]
    validation: bool,
    /// More scenario configs to evaluate beside --config, each on its own
    /// runs ([eval] traffic_seeds): the tables are written per scenario
    /// (<out>/<name>/, the name being the config's folder for a coid.toml,
    /// else its file stem) and pooled over every run (<out>/pooled/). The
    /// configs must share the models, pose-noise levels and fusion variants.
    #[arg(long, num_args = 1.., value_name = "CONFIG")]
    suite: Vec<PathBuf>,
    /// The paper's Fig. 8b for `ours`: MC-dropout samples T (1, 10, ...,
    /// 100) and the dropout rate at inference (0.1 to 0.8, T = 20), one at
    /// a time, on the validation runs and on the test runs:
    /// mc_sweep.csv and mc_sweep.png/.svg, into
    /// results/<config file stem>-mc-sweep
    #[arg(long, conflicts_with_all = ["validation", "suite"])]
    mc_sweep: bool,
    /// Where learned and learning-free matching cross: at each of these
    /// cross-view rank-1 rates of the re-identification descriptor
    /// ([appearance] descriptor = "reid"; rank1 set, auroc = "free"), the
    /// methods with the models and baseline choices of
    /// `<models_dir>/rank1-<R>` (made by `coid train --reid-rank1 R`) on
    /// the validation and the test runs: reid_sweep.csv (F1 with its 95%
    /// interval, AP), reid_sweep_differences.csv (coid - mogm, ours -
    /// gps-app-hungarian, paired) and reid_sweep.png/.svg, into
    /// results/<config file stem>-reid-sweep
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "RANK1",
        conflicts_with_all = ["validation", "suite", "mc_sweep", "dataset"]
    )]
    reid_sweep: Vec<f64>,
    /// Evaluate on a dataset's runs instead of simulating (a folder that
    /// `coid export` or `coid convert` wrote): its test runs (validation
    /// runs with --validation), its pose-noise levels; the config gives
    /// the methods and their settings. Results go to
    /// results/<dataset folder>-eval by default.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["suite", "mc_sweep"])]
    dataset: Option<PathBuf>,
}

/// One scenario of the evaluation: its name, settings and evaluated runs.
struct Scenario {
    name: String,
    settings: Settings,
    /// The runs it evaluates, each named for the progress bar and errors:
    /// its seeds' ([eval] traffic_seeds), or a dataset's test or
    /// validation runs.
    to_run: Vec<(String, Settings)>,
    runs: Vec<RunEval>,
}

/// `coid eval --reid-sweep`: each point calibrates its own descriptor, so
/// the config is read here only to refuse a bad one before the folder is
/// claimed.
fn reid_sweep(a: &Args) -> anyhow::Result<()> {
    let config = a.common.config.path();
    Settings::load(&config)?;
    let out = super::out_dir(a.common.out.out.clone(), &config, "-reid-sweep");
    let existing = io::Existing::when(a.common.force.force);
    let claim = io::Claim::new(&out, io::ResultKind::Eval, existing)?;
    let (quiet, threads) = (a.common.quiet.quiet, a.threads.get());
    let config = (config.as_path(), a.common.config.shown());
    super::reid_sweep::reid_sweep(config, &a.reid_sweep, claim, quiet, threads)
}

pub fn eval(a: Args) -> anyhow::Result<()> {
    if a.mc_sweep {
        let (settings, claim) = a.common.prepare("-mc-sweep", io::ResultKind::Eval)?;
        return super::mc_sweep::mc_sweep(&settings, claim, a.common.quiet.quiet, a.threads.get());
    }
    if !a.reid_sweep.is_empty() {
        return reid_sweep(&a);
    }
    let suffix = if a.validation { "-validation" } else { "-eval" };
    let (settings, claim) =
        a.common
            .prepare_dataset(suffix, io::ResultKind::Eval, a.dataset.as_deref())?;
    let out = claim.out().to_owned();
    let mut scenarios = match &a.dataset {
        Some(dir) => vec![dataset_scenario(dir, settings, a.validation)?],
        None => gather(&a, settings)?,
    };
    // The configured methods (by default every method of the paper's
    // Table 1 plus the practical ones).
    let methods = &scenarios[0].settings.matching.methods.clone();
    let passes = seed_passes(&scenarios[0].settings, methods)?;
    let total: usize = scenarios
        .iter()
        .map(|s| s.to_run.len() * (1 + passes.len()))
        .sum();
    let pb = progress_bar(
        a.common.quiet.quiet,
        total as u64,
        "{spinner} evaluating: run {pos}/{len} [{bar:30}] {msg} eta {eta}",
    );
    let choices = pipeline::choices(&scenarios[0].settings, methods)?;
    let lambdas = matching::method_lambdas(&choices);
    let run = (a.threads.get(), &pipeline::Warnings::default());
    for s in &mut scenarios {
        s.runs = evaluate(s, methods, &lambdas, run, &pb)?;
        evaluate_seeds(s, &passes, run, &pb)?;
    }
    pb.finish_and_clear();
    warn_empty(&scenarios);
    if let [only] = scenarios.as_slice() {
        claim.fill(|dir| write_eval(dir, &only.settings, &only.runs, &choices, None))?;
    } else {
        let names: Vec<&str> = scenarios.iter().map(|s| s.name.as_str()).collect();
        let all: Vec<RunEval> = scenarios.iter().flat_map(|s| s.runs.clone()).collect();
        claim.fill(|dir| -> anyhow::Result<()> {
            for s in &scenarios {
                write_eval(&dir.join(&s.name), &s.settings, &s.runs, &choices, None)?;
            }
            let pooled = Some(names.join(", "));
            let first = &scenarios[0].settings;
            write_eval(
                &dir.join("pooled"),
                first,
                &all,
                &choices,
                pooled.as_deref(),
            )?;
            Ok(())
        })?;
    }
    let runs: usize = scenarios.iter().map(|s| s.runs.len()).sum();
    let instances: usize = scenarios
        .iter()
        .flat_map(|s| &s.runs)
        .map(|r| r.instances)
        .sum();
    eprintln!(
        "coid: evaluated {} on {} of {} ({}); wrote {}",
        crate::label::counted(methods.len() as u64, "method"),
        crate::label::counted(
            runs as u64,
            if a.validation {
                "validation run"
            } else {
                "test run"
            }
        ),
        crate::label::counted(scenarios.len() as u64, "scenario"),
        crate::label::counted(instances as u64, "instance"),
        out.display()
    );
    Ok(())
}

/// The scenarios of the evaluation: the config's own, the scenarios its
/// config lists (`[eval] scenarios`, or `[train] validation_scenarios` with
/// `--validation`), then `--suite`; named uniquely.
fn gather(a: &Args, settings: Settings) -> anyhow::Result<Vec<Scenario>> {
    let listed = if a.validation {
        settings.train.validation_scenarios.clone()
    } else {
        settings.eval.scenarios.clone()
    };
    let config = a.common.config.path();
    let mut scenarios = vec![scenario(&config, settings, a.validation)];
    let primary = scenarios[0].settings.clone();
    for path in &listed {
        // The config's own scenario lists: its settings, that scenario.
        let mut s = primary.with_scenario_of(path)?;
        if a.validation {
            let n = s.train.runs_per_scenario.min(s.eval.traffic_seeds.len());
            s = s.with_test_seeds(&s.eval.traffic_seeds[..n]);
        }
        scenarios.push(scenario(path, s, false));
    }
    for path in &a.suite {
        let s = super::calibrated(&Settings::load(path)?, a.common.quiet.quiet)?;
        compatible(&primary, &s)
            .with_context(|| format!("{} cannot join the suite", path.display()))?;
        scenarios.push(scenario(path, s, a.validation));
    }
    let paths: Vec<&Path> = std::iter::once(config.as_path())
        .chain(listed.iter().map(PathBuf::as_path))
        .chain(a.suite.iter().map(PathBuf::as_path))
        .collect();
    distinct(&scenarios, &paths)?;
    unique_names(&mut scenarios, &paths);
    Ok(scenarios)
}

/// Refuses a scenario named twice (by `--suite`, `[eval] scenarios` or
/// the config itself, under any path): the same configuration and files
/// (the same digest) make the same runs, which the pooled tables would
/// count twice.
fn distinct(scenarios: &[Scenario], paths: &[&Path]) -> anyhow::Result<()> {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    for (k, s) in scenarios.iter().enumerate() {
        let digest = s.settings.digest()?;
        if let Some(&j) = seen.get(&digest) {
            anyhow::bail!(
                "{} and {} make the same runs (the same scenario and settings, digest {digest}): \
                 the pooled tables would count them twice; name each scenario once",
                paths[j].display(),
                paths[k].display()
            );
        }
        seen.insert(digest, k);
    }
    Ok(())
}

/// Says which scenarios had no instance at all (their tables are empty).
fn warn_empty(scenarios: &[Scenario]) {
    for s in scenarios
        .iter()
        .filter(|s| s.runs.iter().all(|r| r.instances == 0))
    {
        eprintln!(
            "coid: warning: {} has no instance in its {}: {}; its tables are empty",
            s.name,
            crate::label::counted(s.runs.len() as u64, "run"),
            crate::commands::run::why_no_instance(&s.settings)
        );
    }
}

/// A dataset's test (or validation) runs as the one scenario, named by
/// its folder.
fn dataset_scenario(dir: &Path, settings: Settings, validation: bool) -> anyhow::Result<Scenario> {
    let settings = settings.with_dataset_split(if validation { "validation" } else { "test" });
    let runs = if validation {
        experiments::validation_runs(&settings)?
    } else {
        experiments::test_runs(&settings)?
    };
    let to_run = runs
        .into_iter()
        .enumerate()
        .map(|(k, s)| (format!("run {}", k + 1), s))
        .collect();
    Ok(Scenario {
        name: folder_of(&dir.join("runs.parquet")).unwrap_or_else(|| "dataset".into()),
        settings,
        to_run,
        runs: Vec::new(),
    })
}

/// A scenario to evaluate on its test (or validation) runs, named by its
/// config's file stem (by its folder for a `coid.toml`).
fn scenario(path: &Path, settings: Settings, validation: bool) -> Scenario {
    // The tables' header names the runs evaluated.
    let settings = if validation {
        settings.reporting_split("validation")
    } else {
        settings
    };
    let to_run = settings
        .eval
        .traffic_seeds
        .iter()
        .map(|&seed| {
            (
                format!("seed {seed}"),
                experiments::settings_for_seed(&settings, seed),
            )
        })
        .collect();
    let stem = path
        .file_stem()
        .map_or_else(|| "scenario".into(), |s| s.to_string_lossy().into_owned());
    let folder = folder_of(path);
    let name = match folder {
        Some(f) if stem == "coid" => f,
        _ => stem,
    };
    Scenario {
        name,
        settings,
        to_run,
        runs: Vec::new(),
    }
}

/// The name of the folder that holds `path`.
fn folder_of(path: &Path) -> Option<String> {
    let full = path.canonicalize().ok()?;
    Some(full.parent()?.file_name()?.to_string_lossy().into_owned())
}

/// Folder names: a name that repeats gets its config's folder in front
/// (`s002-short`), and `-2`, `-3`, ... if it still repeats; `pooled` is
/// taken.
fn unique_names(scenarios: &mut [Scenario], paths: &[&Path]) {
    let mut count: BTreeMap<String, usize> = BTreeMap::new();
    for s in scenarios.iter() {
        *count.entry(s.name.clone()).or_insert(0) += 1;
    }
    for (s, path) in scenarios.iter_mut().zip(paths) {
        if (count[&s.name] > 1 || s.name == "pooled")
            && let Some(f) = folder_of(path)
        {
            s.name = format!("{f}-{}", s.name);
        }
    }
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    seen.insert("pooled".into(), 1);
    for s in scenarios {
        let n = seen.entry(s.name.clone()).or_insert(0);
        *n += 1;
        if *n > 1 {
            s.name = format!("{}-{n}", s.name);
        }
    }
}

/// Pooling needs the same methods, weights and levels in every scenario.
fn compatible(first: &Settings, other: &Settings) -> anyhow::Result<()> {
    let labels = |s: &Settings| s.pose_noise.iter().map(|l| l.label).collect::<Vec<_>>();
    if labels(first) != labels(other) {
        anyhow::bail!("its pose-noise levels differ from the first config's");
    }
    if first.fusion.variants != other.fusion.variants {
        anyhow::bail!("its fusion variants differ from the first config's");
    }
    // The same folder may be named by different paths.
    let models = |s: &Settings| {
        let dir = &s.matching.models_dir;
        dir.canonicalize().unwrap_or_else(|_| dir.clone())
    };
    if models(first) != models(other)
        || first.matching.lambda != other.matching.lambda
        || first.matching.uncertainty != other.matching.uncertainty
    {
        anyhow::bail!("its models, lambda or uncertainty type differ from the first config's");
    }
    Ok(())
}

/// Every run of one scenario, each on `threads` threads, its warnings
/// said to `warnings`.
fn evaluate(
    s: &Scenario,
    methods: &[Method],
    lambdas: &MethodLambdas,
    (threads, warnings): (usize, &pipeline::Warnings),
    pb: &ProgressBar,
) -> anyhow::Result<Vec<RunEval>> {
    let mut runs = Vec::new();
    for (name, run) in &s.to_run {
        pb.set_message(format!("{} {name}", s.name));
        let r = experiments::eval_run(run, methods, lambdas, threads, warnings, |_| {})
            .with_context(|| format!("{}: {name} failed", s.name))?;
        runs.push(r);
        pb.inc(1);
    }
    Ok(runs)
}

/// The deep methods evaluated again with the weights of another training
/// seed (`[eval] training_seeds`), from the models folder's `seed-<N>/`.
struct SeedPass {
    seed: u64,
    models_dir: PathBuf,
    methods: Vec<Method>,
}

/// The passes `[eval] training_seeds` asks for beyond the models folder's
/// own weights: each seed other than a deep method's own, with the deep
/// methods it has weights for (a seed without a method's weights is
/// named in a warning and left out of that method's rows). Refused when
/// a deep method's own seed is not listed, or a seed's folder holds
/// weights of another seed or of another recipe.
fn seed_passes(settings: &Settings, methods: &[Method]) -> anyhow::Result<Vec<SeedPass>> {
    let seeds = &settings.eval.training_seeds;
    let dir = &settings.matching.models_dir;
    let deep: Vec<Method> = methods
        .iter()
        .copied()
        .filter(|m| matches!(m.kind(), MethodKind::Deep))
        .collect();
    if seeds.is_empty() || deep.is_empty() {
        return Ok(Vec::new());
    }
    let mut passes: Vec<SeedPass> = Vec::new();
    // Seeds are trained one command at a time: a method without a seed's
    // weights averages the seeds it has (its rows' `training_seeds`).
    let mut missing: BTreeMap<u64, Vec<&'static str>> = BTreeMap::new();
    // The recipe the missing seeds must repeat: the configuration the
    // models folder's own weights were trained with.
    let mut recipe = None;
    for &m in &deep {
        let record = io::read_model_record(dir, m)?;
        let own = record.seed;
        if !seeds.contains(&own) {
            anyhow::bail!(
                "the weights of '{}' in {} were trained with seed {own}, which [eval] \
                 training_seeds ({seeds:?}) does not list",
                m.as_str(),
                dir.display()
            );
        }
        for &seed in seeds.iter().filter(|&&s| s != own) {
            let seed_dir = io::seed_models_dir(dir, seed);
            if !io::weights_path(&seed_dir, m).exists() {
                let owner = m.weights_owner().as_str();
                let list = missing.entry(seed).or_default();
                if !list.contains(&owner) {
                    list.push(owner);
                }
                if recipe.is_none() {
                    recipe = Some(record.config.clone());
                }
                continue;
            }
            check_seed_folder(dir, &record, &seed_dir, m, seed)?;
            match passes.iter_mut().find(|p| p.seed == seed) {
                Some(p) => p.methods.push(m),
                None => passes.push(SeedPass {
                    seed,
                    models_dir: seed_dir,
                    methods: vec![m],
                }),
            }
        }
    }
    let recipe = recipe.unwrap_or_default();
    for (seed, methods) in missing {
        eprintln!(
            "coid: warning: [eval] training_seeds lists {seed}, but {} has no weights of {} \
             (train them with the recipe of the weights beside it: `coid train -c {recipe} \
             --seed {seed} --methods {} --out {}`); their rows average the seeds they have",
            io::seed_models_dir(dir, seed).display(),
            methods.join(", "),
            methods.join(","),
            dir.display()
        );
    }
    passes.sort_by_key(|p| p.seed);
    Ok(passes)
}

/// Refuses a seed folder whose weights of `m` are not seed `seed` of the
/// recipe of the models folder's own (`own`, their record in `dir`).
fn check_seed_folder(
    dir: &Path,
    own: &ModelRecord,
    seed_dir: &Path,
    m: Method,
    seed: u64,
) -> anyhow::Result<()> {
    let other = io::read_model_record(seed_dir, m)?;
    let found = other.seed;
    if found != seed {
        anyhow::bail!(
            "{} holds weights of '{}' trained with seed {found}, not {seed}",
            seed_dir.display(),
            m.as_str()
        );
    }
    // A row's mean over seeds is a spread over seeds of one
    // recipe, never over recipes.
    let differ = own.recipe_differences(&other);
    if !differ.is_empty() {
        anyhow::bail!(
            "{} holds weights of '{}' trained with another recipe than those in {} \
             ({} differ); train seed {seed} again with theirs: `coid train -c {} \
             --seed {seed} --methods {} --out {}`",
            seed_dir.display(),
            m.as_str(),
            dir.display(),
            differ.join(", "),
            own.config,
            m.weights_owner().as_str(),
            dir.display()
        );
    }
    Ok(())
}

/// Runs every seed pass on the scenario's runs and records each deep
/// method's Table 1 counts per training seed (its own seed's too) in
/// them.
fn evaluate_seeds(
    s: &mut Scenario,
    passes: &[SeedPass],
    run: (usize, &pipeline::Warnings),
    pb: &ProgressBar,
) -> anyhow::Result<()> {
    if passes.is_empty() {
        return Ok(());
    }
    let dir = s.settings.matching.models_dir.clone();
    for run in &mut s.runs {
        let keys: Vec<_> = run
            .table1
            .iter()
            .filter(|(k, _)| matches!(k.method.kind(), MethodKind::Deep))
            .map(|(&k, &c)| (k, c))
            .collect();
        for (k, c) in keys {
            run.by_seed
                .insert((k, io::trained_seed(&dir, k.method)?), c);
        }
    }
    for pass in passes {
        let settings = s.settings.with_models(&pass.models_dir);
        let choices = pipeline::choices(&settings, &pass.methods)?;
        let lambdas = matching::method_lambdas(&choices);
        let to_run = s
            .to_run
            .iter()
            .map(|(name, run)| (name.clone(), run.with_models(&pass.models_dir)))
            .collect();
        let seeded = Scenario {
            name: format!("{} (training seed {})", s.name, pass.seed),
            settings,
            to_run,
            runs: Vec::new(),
        };
        let runs = evaluate(&seeded, &pass.methods, &lambdas, run, pb)?;
        for (into, from) in s.runs.iter_mut().zip(runs) {
            for (k, c) in from.table1 {
                into.by_seed.insert((k, pass.seed), c);
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shipped default config (models named relative to `configs/`)
    /// and a user's config elsewhere (models from the compiled-in defaults)
    /// use the same models, so they can be pooled.
    #[test]
    fn the_shipped_config_and_a_user_config_are_compatible() {
        // Named as a user in the project folder names it (tests run there).
        let shipped = Settings::load(Path::new("configs/default.toml")).unwrap();
        let user = Settings::from_toml(
            "[scenario]\nend_s = 10.0\n",
            Path::new("/tmp/somewhere/user.toml"),
        )
        .unwrap();
        compatible(&shipped, &user).unwrap();
        let mut fewer = user.clone();
        fewer.pose_noise.pop();
        assert!(compatible(&shipped, &fewer).is_err());
    }
}
