//! The files the binary carries (the shipped weights, the default scenario,
//! the defaults), written out once into
//! this build's folder of the user's data folder ([`paths::install_dir`]),
//! where the defaults' relative paths point: so an installed or moved
//! `coid` works from any folder and reads exactly the files it was built
//! with.

use std::path::{Path, PathBuf};

use super::{OutputError, io};
use crate::config::DEFAULTS_TOML;
use crate::paths;

include!(concat!(env!("OUT_DIR"), "/assets.rs"));

/// Written last: a folder without it is incomplete.
const STAMP: &str = ".coid-assets";

/// This build's folder, written out first if it is missing or incomplete
/// (into a temporary sibling, then renamed, so that concurrent first uses
/// never see half a folder).
pub fn install() -> Result<PathBuf, OutputError> {
    let dir = paths::install_dir().map_err(|e| OutputError::Install(e.to_string()))?;
    if is_complete(&dir) {
        return Ok(dir);
    }
    let parent = dir.parent().map(Path::to_owned).unwrap_or_default();
    std::fs::create_dir_all(&parent).map_err(io(&parent))?;
    let staged = tempfile::Builder::new()
        .prefix(".install-")
        .tempdir_in(&parent)
        .map_err(io(&parent))?;
    write_all(staged.path())?;
    if dir.exists() && !is_complete(&dir) {
        std::fs::remove_dir_all(&dir).map_err(io(&dir))?;
    }
    let staged = staged.keep();
    if let Err(e) = std::fs::rename(&staged, &dir) {
        let _ = std::fs::remove_dir_all(&staged);
        // Another process may have put a complete one there first.
        if !is_complete(&dir) {
            return Err(io(&dir)(e));
        }
    }
    Ok(dir)
}

/// Whether `dir` holds this build's files: its stamp, and the defaults
/// this binary was compiled with (a folder written by a build whose
/// defaults differed is written again, never read for its stale ones).
fn is_complete(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join(STAMP)).is_ok_and(|s| s.trim() == paths::ASSETS_ID)
        && std::fs::read(dir.join("configs/default.toml"))
            .is_ok_and(|b| b == DEFAULTS_TOML.as_bytes())
}

fn write_all(root: &Path) -> Result<(), OutputError> {
    let mut files: Vec<(&str, &[u8])> = ASSETS.to_vec();
    files.push(("configs/default.toml", DEFAULTS_TOML.as_bytes()));
    for (name, bytes) in files {
        let path = root.join(name);
        if let Some(p) = path.parent() {
            std::fs::create_dir_all(p).map_err(io(p))?;
        }
        std::fs::write(&path, bytes).map_err(io(&path))?;
    }
    let stamp = root.join(STAMP);
    std::fs::write(&stamp, paths::ASSETS_ID).map_err(io(&stamp))
}

/// The bytes of a carried file (`models/ours.toml`, ...).
#[cfg(test)]
fn carried(name: &str) -> Option<&'static [u8]> {
    ASSETS.iter().find(|(n, _)| *n == name).map(|(_, b)| *b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::Method;

    #[test]
    fn the_binary_carries_every_shipped_model_and_the_default_scenario() {
        let names: Vec<&str> = ASSETS.iter().map(|(n, _)| *n).collect();
        // Every deep method the defaults run or train (the +gps deep
        // baselines are neither: not shipped, trained on demand).
        let defaults = crate::config::Settings::defaults().unwrap();
        let deep = Method::all()
            .iter()
            .filter(|m| matches!(m.kind(), crate::matching::MethodKind::Deep))
            .filter(|m| defaults.matching.methods.contains(m) || defaults.train.methods.contains(m))
            .map(|m| m.weights_owner().as_str());
        for m in deep {
            assert!(names.contains(&format!("models/{m}.bpk").as_str()), "{m}");
            assert!(names.contains(&format!("models/{m}.toml").as_str()), "{m}");
        }
        // And nothing else: shipped weights are the default training's.
        for name in &names {
            if let Some(m) = name
                .strip_prefix("models/")
                .and_then(|n| n.strip_suffix(".bpk"))
            {
                let m = crate::label::parse::<Method>("method", m.rsplit('/').next().unwrap());
                assert!(defaults.train.methods.contains(&m.unwrap()), "{name}");
            }
        }
        assert!(names.contains(&"sumo_nets/intersection/intersection.sumocfg"));
        assert!(carried("models/ours.toml").is_some());
        // The same bytes as the checkout's files.
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        for (name, bytes) in ASSETS {
            assert_eq!(std::fs::read(root.join(name)).unwrap(), *bytes, "{name}");
        }
    }

    #[test]
    fn writing_out_makes_a_complete_folder() {
        let dir = tempfile::tempdir().unwrap();
        write_all(dir.path()).unwrap();
        assert!(is_complete(dir.path()));
        assert!(dir.path().join("configs/default.toml").is_file());
        assert!(dir.path().join("models/ours.bpk").is_file());
        std::fs::write(dir.path().join(STAMP), "another build").unwrap();
        assert!(!is_complete(dir.path()));
    }

    /// Regression: a build whose defaults changed (`[seeds]` moved off the
    /// test runs) kept reading the defaults an earlier build had written
    /// into the same folder, whose name covered the models and the
    /// scenario but not the defaults.
    #[test]
    fn stale_defaults_in_the_install_folder_are_never_read() {
        let dir = tempfile::tempdir().unwrap();
        write_all(dir.path()).unwrap();
        let defaults = dir.path().join("configs/default.toml");
        std::fs::write(&defaults, "[seeds]\ntraffic = 1\n").unwrap();
        assert!(!is_complete(dir.path()));
        write_all(dir.path()).unwrap();
        assert_eq!(std::fs::read_to_string(&defaults).unwrap(), DEFAULTS_TOML);
    }
}
