//! Encoding and durably writing one frame's files, for [`crate::RunStore`]: how a batch's raw
//! frames are compressed, the records of the files written (not yet indexed), and the
//! low-priority pool that encodes, hashes, writes and fsyncs them.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rayon::prelude::*;

use crate::atomic::write_atomic_uncached;
use crate::checksum::sha256_hex;
use crate::error::{Result, StorageError};
use crate::exr_hdr::{HDR_FRAME_COMPRESSION, encode_exr_with};
use crate::exr_planes::encode_exr_planes;
use crate::frame_meta::{
    FrameMeta, FramePixels, FrameToWrite, frame_file_name, ground_truth_file_name,
};
use crate::layout;
use crate::png16::{Deflate, encode_png16_with};
use stagehand_devices::ground_truth::GroundTruthData;

/// How the raw frames of a batch are compressed. Every file is a plain PNG either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawCompression {
    /// Every raw frame with the fastest deflate (about 55 % of the raw size).
    Deflate,
    /// Every other raw frame stored uncompressed: for a writer behind the cameras. Deflate is
    /// most of a frame's CPU, stored frames most of the disk's bytes; half and half spares
    /// both (`cargo bench --bench frame_pipeline`).
    HalfStored,
    /// Every raw frame stored uncompressed: for a writer far behind the cameras whose time
    /// goes to encoding rather than to the disk (a stored frame takes about a third of a
    /// deflated one's CPU and 1.8 times its bytes).
    Stored,
}

impl RawCompression {
    /// The deflate for the `i`-th raw frame of a batch.
    pub(crate) fn for_frame(self, i: usize) -> Deflate {
        match self {
            RawCompression::HalfStored if i % 2 == 1 => Deflate::Stored,
            RawCompression::Stored => Deflate::Stored,
            _ => Deflate::Fastest,
        }
    }
}

/// Where a batch's writing time went, summed over its files (wall time on the writer's
/// threads): the writer compresses less when encoding, not the disk, holds it back.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WriteTimes {
    /// Encoding and hashing the files, seconds.
    pub encode_s: f64,
    /// Writing, fsyncing and renaming them, seconds.
    pub write_s: f64,
}

impl WriteTimes {
    /// True when the disk took longer than the encoding: storing frames uncompressed would
    /// only add to the disk's work.
    pub fn disk_bound(&self) -> bool {
        self.write_s > self.encode_s
    }
}

/// A frame file written to disk (not yet indexed).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WrittenFrame {
    /// Index of the frame in the slice given to `write_frames`.
    pub position: usize,
    /// Absolute path.
    pub path: PathBuf,
    /// Path relative to the run directory.
    pub rel_path: String,
    pub sha256: String,
    pub size_bytes: u64,
    /// The ground-truth images written beside it.
    pub ground_truth: Vec<WrittenGroundTruth>,
    /// Where the frame file's own writing time went (ground truth not counted).
    pub times: WriteTimes,
}

/// A ground-truth image written beside a frame (not yet indexed).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WrittenGroundTruth {
    /// Plane kind (`depth`, `normal`, `radiance`, `material`).
    pub kind: String,
    /// Absolute path.
    pub path: PathBuf,
    /// Path relative to the run directory.
    pub rel_path: String,
    pub sha256: String,
    pub size_bytes: u64,
    /// Channel names in sample order.
    pub channels: Vec<String>,
}

/// One frame of a batch for the writer's pool: its metadata, and the pixels and ground truth
/// it owns, so they are freed as soon as its files are written.
pub(crate) struct FrameJob<'a> {
    /// Index of its step in the batch.
    pub step: usize,
    /// Index of the frame in its step.
    pub position: usize,
    pub meta: &'a FrameMeta,
    pub pixels: FramePixels,
    pub ground_truth: Option<Arc<GroundTruthData>>,
}

impl<'a> FrameJob<'a> {
    /// Takes the pixels and ground truth out of `f` (its pixels left empty) for a job.
    pub(crate) fn take(step: usize, position: usize, f: &'a mut FrameToWrite) -> Self {
        let FrameToWrite {
            meta,
            pixels,
            ground_truth,
        } = f;
        FrameJob {
            step,
            position,
            meta,
            pixels: std::mem::replace(pixels, FramePixels::Raw(Vec::new())),
            ground_truth: ground_truth.take(),
        }
    }
}

/// Encodes one frame (its ground truth beside it) and writes it durably into `frames_dir`;
/// its pixels are freed once encoded, its ground truth once written.
pub(crate) fn write_frame(
    frames_dir: &Path,
    job: FrameJob<'_>,
    deflate: Deflate,
) -> Result<WrittenFrame> {
    let FrameJob {
        position,
        meta,
        pixels,
        ground_truth,
        ..
    } = job;
    let started = std::time::Instant::now();
    let name = frame_file_name(meta);
    let json = meta.embedded_json().map_err(|source| StorageError::Json {
        op: "encode",
        path: frames_dir.join(&name),
        source,
    })?;
    let bytes = match &pixels {
        FramePixels::Raw(px) => encode_png16_with(
            &name,
            meta.width,
            meta.height,
            px,
            meta.bit_depth,
            &json,
            deflate,
        )?,
        FramePixels::Hdr(px) => {
            let (w, h) = (meta.width, meta.height);
            encode_exr_with(&name, w, h, px, &json, HDR_FRAME_COMPRESSION)?
        }
    };
    drop(pixels);
    let sha256 = sha256_hex(&bytes);
    let encoded = std::time::Instant::now();
    let path = write_atomic_uncached(frames_dir, &name, &bytes)?;
    let times = WriteTimes {
        encode_s: (encoded - started).as_secs_f64(),
        write_s: encoded.elapsed().as_secs_f64(),
    };
    let ground_truth = match ground_truth {
        Some(truth) => write_ground_truth(frames_dir, meta, &truth, &json)?,
        None => Vec::new(),
    };
    Ok(WrittenFrame {
        position,
        path,
        rel_path: format!("{}/{name}", layout::FRAMES_DIR),
        sha256,
        size_bytes: bytes.len() as u64,
        ground_truth,
        times,
    })
}

/// Nice 19 for the calling thread (on Linux a nice value is per thread); best effort. The
/// pool's threads together must weigh little against the capture loop's: at nice 10 its 8
/// threads weighed 880 against a nice-0 thread's 1024, nearly half the CPU when both ran.
#[allow(unsafe_code)]
fn lower_this_threads_priority() {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain system calls on the calling thread's id, no memory shared.
        let rc = unsafe { libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19) };
        if rc != 0 {
            tracing::debug!(
                "frame writer thread keeps its priority: {}",
                std::io::Error::last_os_error()
            );
        }
    }
}

/// The pool that encodes and writes frames: four threads per core (at least 8), so
/// the cores stay busy encoding while some threads wait on fsync, each at a lower scheduling
/// priority (nice 19), so encoding never delays the capture loop (the writer's memory budget
/// absorbs the lag). Falls back to rayon's global pool (`None`) if its threads cannot start.
pub(crate) fn writer_pool() -> Option<&'static rayon::ThreadPool> {
    static POOL: std::sync::OnceLock<Option<rayon::ThreadPool>> = std::sync::OnceLock::new();
    POOL.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        rayon::ThreadPoolBuilder::new()
            .num_threads((4 * cores).max(8))
            .thread_name(|i| format!("stagehand-frames-{i}"))
            .start_handler(|_| lower_this_threads_priority())
            .build()
            .inspect_err(|e| tracing::warn!("frames written on the shared pool: {e}"))
            .ok()
    })
    .as_ref()
}

/// Writes the ground-truth planes of a frame beside it in `frames_dir` (temp → fsync →
/// rename; the caller fsyncs the directory). Each file embeds the frame's metadata
/// (`frame_json`), the plane's kind and channels and the ground truth's notes.
fn write_ground_truth(
    frames_dir: &Path,
    meta: &FrameMeta,
    truth: &GroundTruthData,
    frame_json: &str,
) -> Result<Vec<WrittenGroundTruth>> {
    let name = frame_file_name(meta);
    truth.check().map_err(|reason| StorageError::InvalidFrame {
        name: name.clone(),
        reason: reason.to_string(),
    })?;
    if (truth.width, truth.height) != (meta.width, meta.height) {
        return Err(StorageError::InvalidFrame {
            name,
            reason: format!(
                "ground truth is {}x{}, the frame {}x{}",
                truth.width, truth.height, meta.width, meta.height
            ),
        });
    }
    let frame: serde_json::Value =
        serde_json::from_str(frame_json).map_err(|source| StorageError::Json {
            op: "encode",
            path: frames_dir.join(&name),
            source,
        })?;
    truth
        .planes
        .par_iter()
        .map(|plane| -> Result<WrittenGroundTruth> {
            let name = ground_truth_file_name(meta, &plane.kind);
            let json = serde_json::json!({
                "frame": frame,
                "ground_truth": plane.kind,
                "channels": plane.channels,
                "notes": truth.notes,
            })
            .to_string();
            let bytes = encode_exr_planes(
                &name,
                truth.width,
                truth.height,
                &plane.channels,
                &plane.samples,
                &json,
            )?;
            let sha256 = sha256_hex(&bytes);
            let path = write_atomic_uncached(frames_dir, &name, &bytes)?;
            Ok(WrittenGroundTruth {
                kind: plane.kind.clone(),
                path,
                rel_path: format!("{}/{name}", layout::FRAMES_DIR),
                sha256,
                size_bytes: bytes.len() as u64,
                channels: plane.channels.clone(),
            })
        })
        .collect()
}
