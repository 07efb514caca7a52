//! The `stagehand` command line: run, plan (dry run) and resume capture scripts.

fn main() {
    std::process::exit(stagehand::cli::main());
}
