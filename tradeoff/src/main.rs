//! `stagehand-tradeoff`: the accuracy-vs-time sweep as its own program (`stagehand sim
//! tradeoff` runs it). Exit codes: 0 done, 1 failed, 2 bad input.

#![deny(unsafe_code)]

use clap::Parser;
use stagehand_tradeoff::cli::{TradeoffArgs, run};

fn main() {
    std::process::exit(run(&TradeoffArgs::parse()));
}
