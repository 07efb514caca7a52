//! stagehand: control software for an appearance-capture light stage and its laser scanners.
//!
//! Data flows one way: a Rhai script ([`script`]) emits a [`plan::Plan`]; [`validate`] and
//! [`estimate`] check and cost it before anything moves; the [`executor`] runs it against the
//! devices of a [`rig`] and hands frames to [`storage`], which makes them durable before the
//! step's journal row commits.

#![deny(unsafe_code)]

pub mod cli;
pub mod client;
pub mod daemon;
pub mod dry_run;
pub mod estimate;
pub mod evaluate;
pub mod executor;
pub mod plan;
pub mod rig;
pub mod script;
pub mod session;
pub mod storage;
#[cfg(test)]
mod test_support;
pub mod units;
pub mod validate;
