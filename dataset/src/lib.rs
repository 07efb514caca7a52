//! Crash-safe run datasets: one directory per run with its manifest, plan, script, rig file,
//! frames (16-bit PNG raw, OpenEXR HDR) and a SQLite index that doubles as the step journal.
//!
//! The engine writes a run through [`RunStore`]; the daemon, `stagehand verify` and any
//! processing read it through [`RunReader`], which checks the index schema version first.
//! This crate is the one place that knows the index schema; it does not depend on the engine
//! (the engine's plan type implements [`RunPlan`]).
//!
//! A step is done when its frames are durable: [`RunStore::commit_step`]
//! writes and fsyncs every frame file before the one transaction that indexes the frames and
//! marks the step done. See [`run_store`] for the full contract and [`layout`] for the files.
//!
//! | file | concept |
//! |---|---|
//! | [`layout`] | run directory naming and the paths inside a run |
//! | [`manifest`] | the run manifest |
//! | [`frame_meta`] | per-frame metadata and frame file names |
//! | [`frame_write`] | encoding and durably writing one frame's files, the writer pool |
//! | [`atomic`] | temp → fsync → rename → fsync dir |
//! | [`checksum`] | SHA-256 of frame files |
//! | [`png16`] | 16-bit RGB PNG with iTXt metadata |
//! | `png_rgb16` | a 16-bit RGB PNG's bytes in one pass: convert, filter and deflate row by row |
//! | [`exr_file`] | the OpenEXR conventions both EXR kinds share (ZIP16 unless told, metadata attribute) |
//! | [`exr_hdr`] | OpenEXR f32 RGB: uncompressed as captured, ZIP for products |
//! | [`exr_planes`] | OpenEXR f32 named channels (ground truth), ZIP |
//! | [`hdr_merge`] | Debevec-style bracket merge |
//! | [`index`] | SQLite schema, its versions and migrations, the writer's statements |
//! | [`query`] | typed queries on the index, shared by writer and reader |
//! | [`reader`] | a run opened read-only, schema version checked |
//! | [`run_store`] | the writer of a run |
//! | [`plan`] | what the dataset needs of a capture plan ([`RunPlan`]) |
//! | [`verify`] | checks a run: files against the index, the index against the plan |
//! | [`error`] | typed errors |
//!
//! Reading the raw frames of one camera, as digital numbers:
//! ```no_run
//! use stagehand_dataset::png16::decode_png16;
//! use stagehand_dataset::{FrameKind, FrameQuery, RunReader};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let run = RunReader::open("runs/quickstart-20261201-101500-1a2b3c4d".as_ref())?;
//! let query = FrameQuery {
//!     camera: Some("cam1".into()),
//!     kind: Some(FrameKind::Raw),
//!     ..FrameQuery::default()
//! };
//! for frame in run.frames(&query)?.frames {
//!     let bytes = std::fs::read(run.dir().join(&frame.path))?;
//!     let png = decode_png16(&frame.path, &bytes)?; // the sBIT shift undone
//!     println!("step {} {:?}: {} samples", frame.meta.step, frame.meta.lamps_on, png.pixels.len());
//! }
//! # Ok(())
//! # }
//! ```
//!
//! The on-disk format, versioned, with a Python example that reads a run without stagehand:
#![doc = include_str!("../FORMAT.md")]
#![warn(missing_docs)]
#![deny(unsafe_code)]

pub mod atomic;
pub mod checksum;
pub mod error;
pub mod exr_file;
pub mod exr_hdr;
pub mod exr_planes;
pub mod frame_memory;
pub mod frame_meta;
pub mod frame_write;
pub mod hdr_merge;
pub mod index;
pub mod layout;
pub mod manifest;
pub mod plan;
pub mod png16;
mod png_rgb16;
pub mod products;
pub mod query;
pub mod reader;
pub mod run_store;
pub mod verify;

#[cfg(test)]
mod tests;

pub use error::StorageError;
pub use frame_memory::{keep_frame_memory, release_frame_memory};
pub use frame_meta::{
    FrameKind, FrameMeta, FramePixels, FrameToWrite, frame_file_name, ground_truth_file_name,
};
pub use frame_write::{RawCompression, WriteTimes};
pub use hdr_merge::{HdrImage, merge_bracket};
pub use index::{RunStatus, StepRecord, StoredFrame, StoredGroundTruth};
pub use manifest::{Manifest, SimManifest};
pub use plan::{PlannedCapture, PlannedStep, RunPlan, plan_hash};
pub use query::{
    FramePage, FrameQuery, JournalStep, JournalSummary, RecordedFile, RecordedKind, RunRow,
};
pub use reader::{RunReader, read_manifest};
pub use run_store::RunStore;
