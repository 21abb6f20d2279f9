//! `eval`: every method on the test (or validation) runs of one or more
//! scenarios, or of a dataset, the paper's tables and plots per scenario
//! and pooled; each deep method again with the weights of every other
//! training seed `[eval] training_seeds` lists.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;

use super::{Common, ConfigSource, Event, write_eval};
use crate::config::{Overrides, Settings};
use crate::experiments;
use crate::io;
use crate::io::records::ModelRecord;
use crate::matching::{self, Method, MethodKind, MethodLambdas};
use crate::pipeline;
use crate::tables::RunEval;

/// What to evaluate and where the tables go.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalRequest {
    pub common: Common,
    /// The validation runs (`[train] validation_seeds`, a dataset's
    /// validation runs) instead of the test runs.
    pub validation: bool,
    /// More scenario configs beside the configuration, each on its own
    /// runs: tables per scenario and pooled over every run.
    pub suite: Vec<PathBuf>,
    /// A dataset's runs instead of simulated ones.
    pub dataset: Option<PathBuf>,
}

impl EvalRequest {
    /// An evaluation of `config` on its test runs, everything else at its
    /// default.
    pub fn of(config: ConfigSource) -> Self {
        Self {
            common: Common::of(config),
            validation: false,
            suite: Vec::new(),
            dataset: None,
        }
    }
}

/// What an evaluation wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalReport {
    /// The results folder.
    pub folder: PathBuf,
    pub methods: usize,
    /// Runs evaluated, over every scenario.
    pub runs: usize,
    pub scenarios: usize,
    pub instances: usize,
    /// Whether they were validation runs.
    pub validation: bool,
}

impl EvalReport {
    /// The evaluation in one line, as `coid eval` ends.
    pub fn line(&self) -> String {
        format!(
            "coid: evaluated {} on {} of {} ({}); wrote {}",
            crate::label::counted(self.methods as u64, "method"),
            crate::label::counted(
                self.runs as u64,
                if self.validation {
                    "validation run"
                } else {
                    "test run"
                }
            ),
            crate::label::counted(self.scenarios as u64, "scenario"),
            crate::label::counted(self.instances as u64, "instance"),
            self.folder.display()
        )
    }
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

/// The runs through, over every scenario and seed pass, as events.
struct Runs<'a> {
    done: usize,
    total: usize,
    on: &'a mut dyn FnMut(Event),
}

impl Runs<'_> {
    /// Says that `current` is next.
    fn next(&mut self, current: &str) {
        (self.on)(Event::Runs {
            done: self.done,
            total: self.total,
            current,
        });
    }

    /// Counts one more run through.
    fn one_done(&mut self) {
        self.done += 1;
    }
}

/// Evaluates every configured method on the runs of `request` and writes
/// the tables (per scenario and pooled with a suite).
///
/// # Errors
/// A configuration, the dataset, the models folder or a seed folder is
/// refused, a scenario cannot join the suite, a run fails, or the results
/// folder is taken; nothing is then written.
pub fn eval(request: &EvalRequest, mut on: impl FnMut(Event)) -> anyhow::Result<EvalReport> {
    let common = &request.common;
    let threads = super::threads(common.threads)?;
    let suffix = if request.validation {
        "-validation"
    } else {
        "-eval"
    };
    let dataset = request.dataset.as_deref();
    let settings = super::prepare(&common.config, &Overrides::default(), dataset, &mut on)?;
    let claim = common.claim(suffix, dataset, io::ResultKind::Eval)?;
    let out = claim.out().to_owned();
    let mut scenarios = match dataset {
        Some(dir) => vec![dataset_scenario(dir, settings, request.validation)?],
        None => gather(request, settings, &mut on)?,
    };
    // The configured methods (by default every method of the paper's
    // Table 1 plus the practical ones).
    let methods = &scenarios[0].settings.matching.methods.clone();
    let passes = seed_passes(&scenarios[0].settings, methods, &mut on)?;
    let total: usize = scenarios
        .iter()
        .map(|s| s.to_run.len() * (1 + passes.len()))
        .sum();
    let choices = pipeline::choices(&scenarios[0].settings, methods)?;
    let lambdas = matching::method_lambdas(&choices);
    let run = (threads, &pipeline::Warnings::default());
    let mut runs = Runs {
        done: 0,
        total,
        on: &mut on,
    };
    for s in &mut scenarios {
        s.runs = evaluate(s, methods, &lambdas, run, &mut runs)?;
        evaluate_seeds(s, &passes, run, &mut runs)?;
    }
    warn_empty(&scenarios, &mut on);
    write(claim, &scenarios, &choices)?;
    Ok(EvalReport {
        folder: out,
        methods: methods.len(),
        runs: scenarios.iter().map(|s| s.runs.len()).sum(),
        scenarios: scenarios.len(),
        instances: scenarios
            .iter()
            .flat_map(|s| &s.runs)
            .map(|r| r.instances)
            .sum(),
        validation: request.validation,
    })
}

/// The tables: of the one scenario, or of each and pooled over all.
fn write(
    claim: io::Claim,
    scenarios: &[Scenario],
    choices: &BTreeMap<Method, matching::DeepChoice>,
) -> anyhow::Result<()> {
    if let [only] = scenarios {
        claim.fill(|dir| write_eval(dir, &only.settings, &only.runs, choices, None))?;
        return Ok(());
    }
    let names: Vec<&str> = scenarios.iter().map(|s| s.name.as_str()).collect();
    let all: Vec<RunEval> = scenarios.iter().flat_map(|s| s.runs.clone()).collect();
    claim.fill(|dir| -> anyhow::Result<()> {
        for s in scenarios {
            write_eval(&dir.join(&s.name), &s.settings, &s.runs, choices, None)?;
        }
        let pooled = Some(names.join(", "));
        write_eval(
            &dir.join("pooled"),
            &scenarios[0].settings,
            &all,
            choices,
            pooled.as_deref(),
        )?;
        Ok(())
    })?;
    Ok(())
}

/// The scenarios of the evaluation: the config's own, the scenarios its
/// config lists (`[eval] scenarios`, or `[train] validation_scenarios` with
/// `--validation`), then `--suite`; named uniquely.
fn gather(
    request: &EvalRequest,
    settings: Settings,
    on: &mut impl FnMut(Event),
) -> anyhow::Result<Vec<Scenario>> {
    let listed = if request.validation {
        settings.train.validation_scenarios.clone()
    } else {
        settings.eval.scenarios.clone()
    };
    let config = request.common.config.path();
    let mut scenarios = vec![scenario(&config, settings, request.validation)];
    if let ConfigSource::Text { .. } = request.common.config {
        request
            .common
            .config
            .stem()
            .clone_into(&mut scenarios[0].name);
    }
    let primary = scenarios[0].settings.clone();
    for path in &listed {
        // The config's own scenario lists: its settings, that scenario.
        let mut s = primary.with_scenario_of(path)?;
        if request.validation {
            let n = s.train.runs_per_scenario.min(s.eval.traffic_seeds.len());
            s = s.with_test_seeds(&s.eval.traffic_seeds[..n]);
        }
        scenarios.push(scenario(path, s, false));
    }
    for path in &request.suite {
        let s = super::calibrated(&Settings::load(path)?, on)?;
        compatible(&primary, &s)
            .with_context(|| format!("{} cannot join the suite", path.display()))?;
        scenarios.push(scenario(path, s, request.validation));
    }
    let paths: Vec<&Path> = std::iter::once(config.as_path())
        .chain(listed.iter().map(PathBuf::as_path))
        .chain(request.suite.iter().map(PathBuf::as_path))
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
fn warn_empty(scenarios: &[Scenario], on: &mut impl FnMut(Event)) {
    for s in scenarios
        .iter()
        .filter(|s| s.runs.iter().all(|r| r.instances == 0))
    {
        on(Event::Warning(&format!(
            "coid: warning: {} has no instance in its {}: {}; its tables are empty",
            s.name,
            crate::label::counted(s.runs.len() as u64, "run"),
            super::run::why_no_instance(&s.settings)
        )));
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
    through: &mut Runs,
) -> anyhow::Result<Vec<RunEval>> {
    let mut runs = Vec::new();
    for (name, run) in &s.to_run {
        through.next(&format!("{} {name}", s.name));
        let r = experiments::eval_run(run, methods, lambdas, threads, warnings, |_| {})
            .with_context(|| format!("{}: {name} failed", s.name))?;
        runs.push(r);
        through.one_done();
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
fn seed_passes(
    settings: &Settings,
    methods: &[Method],
    on: &mut impl FnMut(Event),
) -> anyhow::Result<Vec<SeedPass>> {
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
        on(Event::Warning(&format!(
            "coid: warning: [eval] training_seeds lists {seed}, but {} has no weights of {} \
             (train them with the recipe of the weights beside it: `coid train -c {recipe} \
             --seed {seed} --methods {} --out {}`); their rows average the seeds they have",
            io::seed_models_dir(dir, seed).display(),
            methods.join(", "),
            methods.join(","),
            dir.display()
        )));
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
    through: &mut Runs,
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
        let runs = evaluate(&seeded, &pass.methods, &lambdas, run, through)?;
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
