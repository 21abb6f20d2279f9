//! The scenario lists of each role (`[train] scenarios`,
//! `validation_scenarios`, `[eval] scenarios`): folders expanded into
//! scenario configs, no scenario in two roles. The only part of `config`
//! that lists folders.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::ConfigError;
use super::check::Checker;
use super::raw::{RawEval, RawTrain};

/// The scenario configs of each role, folders expanded.
pub(super) struct ScenarioLists {
    pub(super) train: Vec<PathBuf>,
    pub(super) validation: Vec<PathBuf>,
    pub(super) test: Vec<PathBuf>,
}

/// Expands the scenario lists and checks that no scenario (no SUMO
/// configuration) has two roles: training, validation and test scenarios
/// are disjoint.
pub(super) fn scenario_lists(
    c: &Checker,
    t: &RawTrain,
    e: &RawEval,
) -> Result<ScenarioLists, ConfigError> {
    let lists = ScenarioLists {
        train: expand_scenarios(c, "train.scenarios", &t.scenarios)?,
        validation: expand_scenarios(c, "train.validation_scenarios", &t.validation_scenarios)?,
        test: expand_scenarios(c, "eval.scenarios", &e.scenarios)?,
    };
    let mut role: BTreeMap<PathBuf, &'static str> = BTreeMap::new();
    for (key, list) in [
        ("train.scenarios", &lists.train),
        ("train.validation_scenarios", &lists.validation),
        ("eval.scenarios", &lists.test),
    ] {
        for path in list {
            let sumocfg = scenario_identity(path).map_err(|m| c.invalid(key, m))?;
            if let Some(other) = role.get(&sumocfg).filter(|&&o| o != key) {
                return Err(c.invalid(
                    key,
                    format!(
                        "{} is also in {other} (the same SUMO scenario {}): training, \
                         validation and test scenarios must be disjoint",
                        path.display(),
                        sumocfg.display()
                    ),
                ));
            }
            role.insert(sumocfg, key);
        }
    }
    Ok(lists)
}

/// The files of a scenario list: a file stays, a scenario folder stands
/// for its `coid.toml`, another folder for every scenario folder in it
/// (sorted).
fn expand_scenarios(
    c: &Checker,
    key: &'static str,
    list: &[PathBuf],
) -> Result<Vec<PathBuf>, ConfigError> {
    let mut out = Vec::new();
    for p in list.iter().map(|p| c.resolve(p)) {
        if p.is_file() {
            out.push(p);
        } else if p.join("coid.toml").is_file() {
            // A scenario folder itself.
            out.push(p.join("coid.toml"));
        } else if p.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(&p)
                .map_err(|e| c.invalid(key, format!("cannot list {}: {e}", p.display())))?
                .filter_map(|d| d.ok().map(|d| d.path().join("coid.toml")))
                .filter(|f| f.is_file())
                .collect();
            if found.is_empty() {
                return Err(c.invalid(
                    key,
                    format!("{} holds no scenario folder with a coid.toml", p.display()),
                ));
            }
            found.sort();
            out.extend(found);
        } else {
            return Err(c.invalid(key, format!("no such file or folder: {}", p.display())));
        }
    }
    Ok(out)
}

/// What makes two scenario configs the same scenario: the SUMO
/// configuration they run (canonical path), read from `[scenario] sumocfg`
/// without loading the rest.
fn scenario_identity(path: &Path) -> Result<PathBuf, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let table: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| format!("{}: {}", path.display(), e.message()))?;
    let sumocfg = table
        .get("scenario")
        .and_then(|s| s.get("sumocfg"))
        .and_then(|v| v.as_str())
        .ok_or_else(|| format!("{} has no [scenario] sumocfg", path.display()))?;
    let full = path.parent().unwrap_or(Path::new(".")).join(sumocfg);
    full.canonicalize()
        .map_err(|e| format!("{}: {}: {e}", path.display(), full.display()))
}
