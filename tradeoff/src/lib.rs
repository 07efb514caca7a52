//! What accuracy costs in time: `stagehand-tradeoff`, also run as `stagehand sim tradeoff`.
//! A crate of its own (on the simulator's renderer) so that plotting and its bundled font stay
//! out of the simulator library and the daemon.
//!
//! For one scene on the built-in light stage under a fixed lighting state ([`setup`]), render a
//! converged reference, then sweep each accuracy knob one at a time from the standard preset
//! plus the three presets ([`sweep`]), timing every setting (best of N, wall clock) and
//! measuring its error against the reference ([`metrics`]). The Pareto front and the cheapest
//! setting that meets an error target come from [`pareto`]; [`report`] writes the CSV and
//! Markdown table and [`plot`] the RMSE-vs-time plots. [`mitsuba`] exports the same scene for
//! Mitsuba 3, [`peer`] reads its timings back and [`equal_error`] compares the two renderers
//! at equal error. [`pfm`] reads and writes the float images they exchange.

#![deny(unsafe_code)]

pub mod cli;
pub mod equal_error;
pub mod error;
pub mod metrics;
pub mod mitsuba;
pub mod pareto;
pub mod peer;
pub mod pfm;
pub mod plot;
pub mod report;
pub mod setup;
pub mod sweep;

pub use error::TradeoffError;
pub use pareto::{Cost, Target};
pub use setup::{Setup, SetupOptions};
pub use sweep::{Point, Setting, SweepConfig, Tradeoff};

#[cfg(test)]
mod tests;
