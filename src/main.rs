//! The `stagehand` command line: run, plan (dry run) and resume capture scripts.

#![deny(unsafe_code)]

fn main() {
    std::process::exit(stagehand::cli::main());
}
