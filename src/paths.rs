//! Where coid keeps what it installs for itself, so that one binary works
//! from any folder: the user's data folder, this build's files in it (the
//! shipped weights and the default scenario, carried inside the binary
//! and written out on first use by `io::assets`), and SUMO's Python
//! environment. Pure path arithmetic on the environment; nothing here
//! touches the disk.
//!
//! - data folder: `$COID_HOME`, else `$XDG_DATA_HOME/coid-sim`, else
//!   `$HOME/.local/share/coid-sim`;
//! - this build's files: `<data>/install-<version>-<assets id>/`, named by
//!   a hash of their contents, so a binary never reads another build's;
//! - SUMO's Python environment: `$COID_VENV`, else `<data>/venv` (the
//!   checkout's `./coid` sets `COID_VENV` to its own `.venv`).

use std::path::PathBuf;

/// The hash of the files this binary carries (set by `build.rs`).
pub const ASSETS_ID: &str = env!("COID_ASSETS_ID");

/// The interpreter the binary was linked against, and its `major.minor`:
/// SUMO's environment is made from it (set by `build.rs`).
#[cfg(feature = "embed")]
pub const BUILD_PYTHON: &str = env!("COID_BUILD_PYTHON");
#[cfg(feature = "embed")]
pub const BUILD_PYTHON_VERSION: &str = env!("COID_BUILD_PYTHON_VERSION");
/// Its `sys.base_prefix`: where the linked libpython's standard library
/// lives (the embedded interpreter is told, so that it never takes
/// another Python's library found on `PATH`).
#[cfg(feature = "embed")]
pub const BUILD_PYTHON_HOME: &str = env!("COID_BUILD_PYTHON_HOME");

/// Why no data folder could be named.
#[derive(Debug, thiserror::Error)]
#[error("cannot find a folder for coid's data: set COID_HOME (or HOME)")]
pub struct NoDataFolder;

/// The user's data folder for coid.
pub fn data_dir() -> Result<PathBuf, NoDataFolder> {
    let set = |name: &str| {
        std::env::var_os(name)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    if let Some(home) = set("COID_HOME") {
        return Ok(home);
    }
    if let Some(xdg) = set("XDG_DATA_HOME") {
        return Ok(xdg.join("coid-sim"));
    }
    set("HOME")
        .map(|h| h.join(".local").join("share").join("coid-sim"))
        .ok_or(NoDataFolder)
}

/// The folder that holds this build's files (`configs/`, `models/`,
/// `sumo_nets/intersection/`), named by version and contents.
pub fn install_dir() -> Result<PathBuf, NoDataFolder> {
    Ok(data_dir()?.join(format!("install-{}-{ASSETS_ID}", env!("CARGO_PKG_VERSION"))))
}

/// SUMO's Python environment: `$COID_VENV`, else `<data>/venv`.
#[cfg(feature = "embed")]
pub fn venv_dir() -> Result<PathBuf, NoDataFolder> {
    match std::env::var_os("COID_VENV").filter(|v| !v.is_empty()) {
        Some(v) => Ok(PathBuf::from(v)),
        None => Ok(data_dir()?.join("venv")),
    }
}
