//! The `coid` binary: parses the command line, runs the command (see
//! `cli`), and maps any error to one line on stderr (the cause chain joined
//! by ": ") and exit code 1. Usage errors are clap's (exit code 2).

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = coid_sim::cli::Cli::parse();
    match coid_sim::cli::execute(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let chain: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            eprintln!("error: {}", chain.join(": "));
            ExitCode::FAILURE
        }
    }
}
