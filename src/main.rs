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

/// mimalloc's `mi_option_purge_delay` (its `mimalloc.h`: the option
/// before `mi_option_use_numa_nodes`, which the sys crate names).
const PURGE_DELAY: libmimalloc_sys::mi_option_t = libmimalloc_sys::mi_option_use_numa_nodes - 1;

fn main() -> ExitCode {
    // Memory freed by one training or inference step is kept for the
    // next instead of being returned to the system after 10 ms and faulted
    // in (and zeroed by the kernel) again: 15-25 % of a training's CPU
    // time. Peak memory is unchanged; outputs are too.
    // SAFETY: sets a process-wide allocator option before any thread runs.
    unsafe { libmimalloc_sys::mi_option_set(PURGE_DELAY, -1) };
    coid_sim::cli::prepare_main_process();
    let cli = coid_sim::cli::Cli::parse();
    match coid_sim::cli::execute(cli) {
        Ok(_) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", coid_sim::cli::one_line(&e));
            ExitCode::FAILURE
        }
    }
}
