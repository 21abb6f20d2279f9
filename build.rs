//! Embeds an rpath to the libpython that pyo3 links against, so the binary
//! loads the same interpreter it was built for without LD_LIBRARY_PATH.

use std::process::Command;

fn main() {
    println!("cargo:rerun-if-env-changed=PYO3_PYTHON");
    println!("cargo:rerun-if-changed=build.rs");
    let python = std::env::var("PYO3_PYTHON").unwrap_or_else(|_| "python3".to_owned());
    let out = Command::new(&python)
        .args([
            "-c",
            "import sysconfig; print(sysconfig.get_config_var('LIBDIR') or '')",
        ])
        .output();
    match out {
        Ok(o) if o.status.success() => {
            let libdir = String::from_utf8_lossy(&o.stdout).trim().to_owned();
            if !libdir.is_empty() {
                println!("cargo:rustc-link-arg=-Wl,-rpath,{libdir}");
            }
        }
        _ => println!(
            "cargo:warning=could not ask {python} for its LIBDIR; run bridge/setup.sh first"
        ),
    }
}
