//! SUMO's Python: the project's environment with the pinned libsumo and
//! eclipse-sumo (made on first use), SUMO's tools in it, this program as a
//! child process runs it, and the interpreter prepared to import libsumo.

use std::ffi::CString;
use std::path::{Path, PathBuf};

use pyo3::prelude::*;
use pyo3::types::PyModule;

use super::{BridgeError, SHIM, describe};
#[cfg(feature = "embed")]
use crate::paths;

/// Runs SUMO's netconvert (from SUMO's environment: [`sumo_tool`]) in
/// `dir` with `args` (paths in them relative to `dir`). Its console
/// output is kept only for the error.
pub fn netconvert(dir: &Path, args: &[String]) -> Result<(), BridgeError> {
    let exe = sumo_tool("netconvert")?;
    let fail = |message: String| BridgeError::Tool {
        tool: "netconvert",
        dir: dir.to_owned(),
        message,
    };
    let out = std::process::Command::new(&exe)
        .args(args)
        .current_dir(dir)
        .env_remove("PYTHONHOME")
        .output()
        .map_err(|e| fail(e.to_string()))?;
    if out.status.success() {
        return Ok(());
    }
    let text = String::from_utf8_lossy(&out.stderr);
    Err(fail(text.lines().last().unwrap_or("no output").to_owned()))
}

/// One of SUMO's programs: the binary's SUMO environment's (its `bin/`).
#[cfg(feature = "embed")]
fn sumo_tool(name: &str) -> Result<PathBuf, BridgeError> {
    let venv = environment()?;
    let exe = venv.join("bin").join(name);
    if !exe.is_file() {
        return Err(BridgeError::NoEnvironment(venv));
    }
    Ok(exe)
}

/// One of SUMO's programs: the eclipse-sumo package's of the interpreter
/// that loaded coid (`<sumo.SUMO_HOME>/bin/`).
#[cfg(not(feature = "embed"))]
fn sumo_tool(name: &str) -> Result<PathBuf, BridgeError> {
    let home: String = Python::attach(|py| {
        py.import("sumo")
            .and_then(|m| m.getattr("SUMO_HOME"))
            .and_then(|h| h.str())
            .map(|h| h.to_string())
            .map_err(|e| BridgeError::Setup(no_sumo(&describe(py, &e))))
    })?;
    let exe = Path::new(&home).join("bin").join(name);
    if !exe.is_file() {
        return Err(BridgeError::Setup(format!(
            "SUMO's {name} is not in {}",
            exe.parent().unwrap_or(Path::new(&home)).display()
        )));
    }
    Ok(exe)
}

/// Why SUMO could not be imported into the interpreter that loaded coid.
#[cfg(not(feature = "embed"))]
fn no_sumo(why: &str) -> String {
    format!(
        "this Python has no SUMO ({why}): install the pinned packages with `pip install {}`",
        REQUIREMENTS
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .collect::<Vec<_>>()
            .join(" ")
    )
}

/// How to start another coid process (a batch's workers, training's
/// children): the program and the arguments before the command. The
/// binary starts itself.
#[cfg(feature = "embed")]
pub fn this_program() -> std::io::Result<(PathBuf, Vec<std::ffi::OsString>)> {
    Ok((std::env::current_exe()?, Vec::new()))
}

/// How to start another coid process: inside the Python package, the
/// interpreter that loaded it, as `python -m coid_sim`.
#[cfg(not(feature = "embed"))]
pub fn this_program() -> std::io::Result<(PathBuf, Vec<std::ffi::OsString>)> {
    let exe: Option<String> = Python::attach(|py| {
        py.import("sys")
            .and_then(|m| m.getattr("executable"))
            .and_then(|e| e.extract())
            .ok()
    });
    let exe = exe.filter(|e: &String| !e.is_empty()).ok_or_else(|| {
        std::io::Error::other("this Python does not name its executable (sys.executable)")
    })?;
    Ok((PathBuf::from(exe), vec!["-m".into(), "coid_sim".into()]))
}

/// Prepares a process that coid runs as its main program (the binary,
/// `python -m coid_sim`), while it has one thread: the signals
/// ([`crate::interrupt::watch`]); and for the binary, the embedded
/// interpreter's home (`PYTHONHOME`, unless the user set it) is the
/// Python the binary was linked against, so that its standard library is
/// never taken from another Python on `PATH` (a system `python3` of the
/// same version has extension modules built in that this libpython looks
/// for as files).
pub fn prepare_process() {
    #[cfg(feature = "embed")]
    {
        let home = Path::new(paths::BUILD_PYTHON_HOME);
        if std::env::var_os("PYTHONHOME").is_none() && home.join("lib").is_dir() {
            // SAFETY: called first thing in `main`, before any thread is
            // started.
            unsafe { std::env::set_var("PYTHONHOME", home) };
        }
    }
    crate::interrupt::watch();
}

/// The pinned SUMO packages (what `bridge/setup.sh` installs too).
const REQUIREMENTS: &str = include_str!("../../bridge/requirements.txt");
/// Inside the environment: the requirements it was made with, written
/// last (the same stamp `bridge/setup.sh` writes).
#[cfg(feature = "embed")]
const STAMP: &str = ".coid-requirements";

#[cfg(feature = "embed")]
/// SUMO's Python environment, made on first use when it is missing or
/// incomplete: `python -m venv` with the interpreter the binary was
/// linked against (`COID_PYTHON` overrides it), then pip with the pinned
/// requirements. One process makes it while others wait (a lock file
/// beside it).
pub fn environment() -> Result<PathBuf, BridgeError> {
    let venv = paths::venv_dir().map_err(|e| BridgeError::Setup(e.to_string()))?;
    if is_complete(&venv) {
        return Ok(venv);
    }
    let parent = venv.parent().map(Path::to_owned).unwrap_or_default();
    let setup = |what: &str, e: &dyn std::fmt::Display| {
        BridgeError::Setup(format!("{what} {}: {e}", venv.display()))
    };
    std::fs::create_dir_all(&parent).map_err(|e| setup("cannot make the folder of", &e))?;
    let lock = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(parent.join(".venv.lock"))
        .map_err(|e| setup("cannot lock", &e))?;
    lock.lock().map_err(|e| setup("cannot lock", &e))?;
    if is_complete(&venv) {
        return Ok(venv);
    }
    eprintln!(
        "coid: setting up SUMO's Python environment in {} (libsumo and eclipse-sumo from PyPI, ~250 MB, once)",
        venv.display()
    );
    if venv.exists() {
        std::fs::remove_dir_all(&venv).map_err(|e| setup("cannot replace", &e))?;
    }
    let python = std::env::var_os("COID_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            let built = PathBuf::from(paths::BUILD_PYTHON);
            if built.is_file() {
                built
            } else {
                PathBuf::from("python3")
            }
        });
    run_setup(&python, &["-m", "venv"], &venv)?;
    let req = venv.join("requirements.txt");
    std::fs::write(&req, REQUIREMENTS).map_err(|e| setup("cannot write into", &e))?;
    let py = venv.join("bin").join("python");
    let pip = [
        "-m",
        "pip",
        "install",
        "--disable-pip-version-check",
        "--quiet",
        "-r",
    ];
    run_setup(&py, &pip, &req)?;
    check_version(&py)?;
    std::fs::write(venv.join(STAMP), REQUIREMENTS).map_err(|e| setup("cannot write into", &e))?;
    Ok(venv)
}

#[cfg(feature = "embed")]
fn is_complete(venv: &Path) -> bool {
    venv.join("bin").join("python").is_file()
        && std::fs::read_to_string(venv.join(STAMP)).is_ok_and(|s| s == REQUIREMENTS)
}

#[cfg(feature = "embed")]
/// Runs `program args path` for the environment's set-up; its output is
/// kept for the error.
fn run_setup(program: &Path, args: &[&str], path: &Path) -> Result<(), BridgeError> {
    let out = std::process::Command::new(program)
        .args(args)
        .arg(path)
        .env_remove("PYTHONHOME")
        .output()
        .map_err(|e| BridgeError::Setup(format!("cannot run {}: {e}", program.display())))?;
    if out.status.success() {
        return Ok(());
    }
    let text = String::from_utf8_lossy(&out.stderr);
    Err(BridgeError::Setup(format!(
        "{} {} failed: {}",
        program.display(),
        args.join(" "),
        text.lines().last().unwrap_or("no output")
    )))
}

#[cfg(feature = "embed")]
/// The environment's Python must be the one the binary links against.
fn check_version(python: &Path) -> Result<(), BridgeError> {
    if paths::BUILD_PYTHON_VERSION.is_empty() {
        return Ok(());
    }
    let out = std::process::Command::new(python)
        .args(["-c", "import sys; print('%d.%d' % sys.version_info[:2])"])
        .env_remove("PYTHONHOME")
        .output()
        .map_err(|e| BridgeError::Setup(format!("cannot run {}: {e}", python.display())))?;
    let version = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    if version == paths::BUILD_PYTHON_VERSION {
        return Ok(());
    }
    Err(BridgeError::Setup(format!(
        "the environment's Python is {version}, but coid was built for Python {} (set COID_PYTHON to a python{0})",
        paths::BUILD_PYTHON_VERSION
    )))
}

#[cfg(feature = "embed")]
fn site_packages(venv: &Path) -> Option<PathBuf> {
    let lib = venv.join("lib");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&lib)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path().join("site-packages"))
        .filter(|p| p.join("libsumo").is_dir())
        .collect();
    dirs.sort();
    dirs.pop()
}

/// Makes the embedded interpreter see the project's environment: its
/// site-packages, its python as `sys.executable`, and `SUMO_HOME` (in
/// Python's and the process environment). Idempotent.
#[cfg(feature = "embed")]
pub(super) fn prepare_python(py: Python<'_>) -> Result<Bound<'_, PyModule>, BridgeError> {
    let venv = environment()?;
    let site = site_packages(&venv).ok_or_else(|| BridgeError::NoEnvironment(venv.clone()))?;
    let setup = format!(
        "import os, site, sys\n\
         site.addsitedir({site:?})\n\
         sys.executable = {exe:?}\n\
         import sumo\n\
         os.environ.setdefault('SUMO_HOME', sumo.SUMO_HOME)\n",
        site = site.to_string_lossy(),
        exe = venv.join("bin").join("python").to_string_lossy(),
    );
    let setup = CString::new(setup).map_err(|e| BridgeError::Setup(e.to_string()))?;
    py.run(&setup, None, None)
        .map_err(|e| BridgeError::Setup(describe(py, &e)))?;
    load_shim(py)
}

/// Makes `SUMO_HOME` the eclipse-sumo package's of the interpreter that
/// loaded coid (unless the user set it). Idempotent.
#[cfg(not(feature = "embed"))]
pub(super) fn prepare_python(py: Python<'_>) -> Result<Bound<'_, PyModule>, BridgeError> {
    py.run(
        c"import os, sumo, libsumo\nos.environ.setdefault('SUMO_HOME', sumo.SUMO_HOME)\n",
        None,
        None,
    )
    .map_err(|e| BridgeError::Setup(no_sumo(&describe(py, &e))))?;
    load_shim(py)
}

/// The shim (`bridge/coid_bridge.py`) as a module; the signal handlers of
/// a coid main process again, in case an imported module took them.
fn load_shim(py: Python<'_>) -> Result<Bound<'_, PyModule>, BridgeError> {
    let code = CString::new(SHIM).map_err(|e| BridgeError::Setup(e.to_string()))?;
    let shim = PyModule::from_code(py, &code, c"coid_bridge.py", c"coid_bridge")
        .map_err(|e| BridgeError::Setup(describe(py, &e)))?;
    crate::interrupt::install_handlers();
    Ok(shim)
}
