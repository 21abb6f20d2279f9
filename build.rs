//! 1. Embeds an rpath to the libpython that pyo3 links against, so the
//!    binary loads the same interpreter it was built for without
//!    LD_LIBRARY_PATH, and records that interpreter (`COID_BUILD_PYTHON`,
//!    `COID_BUILD_PYTHON_VERSION`): SUMO's Python environment is made from
//!    it on first use.
//! 2. Lists the files the binary carries (the shipped weights and the
//!    default scenario) as `include_bytes!`
//!    entries in `$OUT_DIR/assets.rs`, and names their contents
//!    (`COID_ASSETS_ID`, a hash), so that an installed `coid` works from
//!    any folder and never reads a stale copy.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Folders (relative to the package) whose files the binary carries (and
/// `models/seed-<N>/`, the other training seeds' weights).
const ASSET_DIRS: &[&str] = &["models", "sumo_nets/intersection"];
/// Single files it carries.
const ASSET_FILES: &[&str] = &[];
/// Files compiled in elsewhere (`include_str!`) and written out with the
/// assets: part of the folder's name, not of `ASSETS`.
const NAMED_FILES: &[&str] = &["configs/default.toml"];

fn main() {
    println!("cargo:rerun-if-env-changed=PYO3_PYTHON");
    println!("cargo:rerun-if-changed=build.rs");
    python();
    assets();
}

fn python() {
    let python = std::env::var("PYO3_PYTHON").unwrap_or_else(|_| "python3".to_owned());
    let probe = "import os, sys, sysconfig\n\
                 print(sysconfig.get_config_var('LIBDIR') or '')\n\
                 print(os.path.realpath(getattr(sys, '_base_executable', sys.executable)))\n\
                 print('%d.%d' % sys.version_info[:2])\n\
                 print(sys.base_prefix)";
    let out = Command::new(&python).args(["-c", probe]).output();
    match out {
        Ok(o) if o.status.success() => {
            let text = String::from_utf8_lossy(&o.stdout).into_owned();
            let mut lines = text.lines();
            let libdir = lines.next().unwrap_or("").trim();
            if !libdir.is_empty() {
                println!("cargo:rustc-link-arg=-Wl,-rpath,{libdir}");
            }
            let exe = lines.next().unwrap_or("python3").trim();
            let version = lines.next().unwrap_or("").trim();
            let home = lines.next().unwrap_or("").trim();
            println!("cargo:rustc-env=COID_BUILD_PYTHON={exe}");
            println!("cargo:rustc-env=COID_BUILD_PYTHON_VERSION={version}");
            println!("cargo:rustc-env=COID_BUILD_PYTHON_HOME={home}");
        }
        _ => {
            println!(
                "cargo:warning=could not ask {python} for its LIBDIR; run bridge/setup.sh first"
            );
            println!("cargo:rustc-env=COID_BUILD_PYTHON=python3");
            println!("cargo:rustc-env=COID_BUILD_PYTHON_VERSION=");
            println!("cargo:rustc-env=COID_BUILD_PYTHON_HOME=");
        }
    }
}

/// `ASSET_DIRS`, and the other training seeds' models folders inside
/// `models` (`models/seed-<N>`), in order.
fn asset_dirs(root: &Path) -> Vec<String> {
    let mut dirs: Vec<String> = ASSET_DIRS.iter().map(|d| (*d).to_owned()).collect();
    let mut seeds: Vec<String> = std::fs::read_dir(root.join("models"))
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .filter(|e| e.path().is_dir())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|name| name.starts_with("seed-"))
                .map(|name| format!("models/{name}"))
                .collect()
        })
        .unwrap_or_default();
    seeds.sort();
    dirs.extend(seeds);
    dirs
}

fn assets() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let mut files: Vec<String> = ASSET_FILES.iter().map(|f| (*f).to_owned()).collect();
    for dir in asset_dirs(&root) {
        println!("cargo:rerun-if-changed={dir}");
        let mut names: Vec<String> = std::fs::read_dir(root.join(&dir))
            .unwrap_or_else(|e| panic!("cannot list {dir}: {e}"))
            .filter_map(|e| e.ok())
            .filter(|e| e.path().is_file())
            .map(|e| format!("{dir}/{}", e.file_name().to_string_lossy()))
            .collect();
        names.sort();
        files.extend(names);
    }
    // FNV-1a over every name and content: a name for this set of assets.
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    let mut feed = |bytes: &[u8]| {
        for b in bytes {
            hash ^= u64::from(*b);
            hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    let mut code =
        String::from("/// Files the binary carries: (path in the installation, bytes).\n");
    code.push_str("pub static ASSETS: &[(&str, &[u8])] = &[\n");
    for f in &files {
        println!("cargo:rerun-if-changed={f}");
        let path = root.join(f);
        let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("cannot read {f}: {e}"));
        feed(f.as_bytes());
        feed(&(bytes.len() as u64).to_le_bytes());
        feed(&bytes);
        code.push_str(&format!(
            "    ({f:?}, include_bytes!({:?})),\n",
            Path::new(&path).display().to_string()
        ));
    }
    code.push_str("];\n");
    for f in NAMED_FILES {
        println!("cargo:rerun-if-changed={f}");
        let bytes = std::fs::read(root.join(f)).unwrap_or_else(|e| panic!("cannot read {f}: {e}"));
        feed(f.as_bytes());
        feed(&(bytes.len() as u64).to_le_bytes());
        feed(&bytes);
    }
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets it")).join("assets.rs");
    std::fs::write(&out, code).expect("write assets.rs");
    println!("cargo:rustc-env=COID_ASSETS_ID={hash:016x}");
}
