//! The `coid` binary: parses the command line, runs the command (see
//! `cli`), and maps any error to one line on stderr (the cause chain joined
//! by ": ", causes already quoted left out) and exit code 1. Usage errors
//! are clap's (exit code 2).

use std::process::ExitCode;

use clap::Parser;

/// mimalloc: the matchers allocate many short-lived tensor buffers; glibc
/// returns the large ones to the system and faults them in again.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> ExitCode {
    let cli = coid_sim::cli::Cli::parse();
    match coid_sim::cli::execute(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // A cause that an outer message already quotes is not repeated.
            let mut line = String::new();
            for cause in e.chain().map(|c| c.to_string()) {
                if !line.contains(&cause) {
                    if !line.is_empty() {
                        line.push_str(": ");
                    }
                    line.push_str(&cause);
                }
            }
            eprintln!("error: {line}");
            ExitCode::FAILURE
        }
    }
}
