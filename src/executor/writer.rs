//! The writer thread: makes each step's frames durable (and merges HDR brackets) off the
//! runtime, in step order, while the executor drives the next step. A step's journal row
//! commits only after its files are fsynced and renamed; after the first failure nothing
//! more is committed, so the dataset stays a clean prefix of the plan plus untouched steps.

use std::sync::{Arc, Mutex};

use tokio::sync::{OwnedSemaphorePermit, Semaphore, broadcast, mpsc, oneshot};

use super::RunError;
use super::capture::StepFrames;
use super::events::Event;
use crate::storage::{
    FramePixels, FrameToWrite, RawCompression, RunStatus, RunStore, StepRecord, StorageError,
    WriteTimes, merge_bracket,
};
use crate::units::human_bytes;

/// What the writer did by the time the run finished.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FinishReport {
    /// Steps durable in the dataset (including earlier sessions of a resumed run).
    pub steps_done: usize,
    /// Files written in this session.
    pub frames_written: usize,
}

enum Msg {
    /// A finished step; the permit holds its share of the in-flight frame budget.
    Step(StepRecord, StepFrames, OwnedSemaphorePermit),
    Finish(
        RunStatus,
        Option<String>,
        oneshot::Sender<Result<FinishReport, StorageError>>,
    ),
}

/// Handle to the writer thread of one run.
pub struct WriterHandle {
    tx: mpsc::Sender<Msg>,
    failed: Arc<Mutex<Option<(usize, String)>>>,
    budget: Arc<Semaphore>,
}

/// Steps queued ahead of the disk before the executor waits.
const QUEUE_STEPS: usize = 4096;
/// Frame data (MiB) queued ahead of the disk before the executor waits: bounds memory while
/// letting cheap steps run far ahead of the writer.
const BUDGET_MIB: u32 = 512;

impl WriterHandle {
    /// Starts the writer thread; it owns `store` until the run finishes. A step is refused
    /// when the file system would keep fewer than `reserve_bytes` free after writing it.
    pub fn spawn(
        store: RunStore,
        events: broadcast::Sender<Event>,
        reserve_bytes: u64,
    ) -> std::io::Result<WriterHandle> {
        let (tx, rx) = mpsc::channel(QUEUE_STEPS);
        let failed = Arc::new(Mutex::new(None));
        let flag = failed.clone();
        let budget = Arc::new(Semaphore::new(BUDGET_MIB as usize));
        let backlog = budget.clone();
        std::thread::Builder::new()
            .name("stagehand-writer".into())
            .spawn(move || writer_loop(store, rx, events, flag, reserve_bytes, backlog))?;
        Ok(WriterHandle { tx, failed, budget })
    }

    fn failure(&self) -> Option<(usize, String)> {
        self.failed
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Fails if an earlier step could not be written.
    pub fn check(&self) -> Result<(), RunError> {
        match self.failure() {
            Some((step, message)) => Err(RunError::Storage { step, message }),
            None => Ok(()),
        }
    }

    /// Queues a finished step; waits only while the writer is more than the frame budget
    /// (or `QUEUE_STEPS` steps) behind.
    pub async fn submit(&self, record: StepRecord, frames: StepFrames) -> Result<(), RunError> {
        let step = record.step;
        let mib = step_bytes(&frames)
            .div_ceil(1 << 20)
            .min(BUDGET_MIB as usize) as u32;
        let stopped = || RunError::Storage {
            step,
            message: "the writer thread has stopped".into(),
        };
        let permit = self
            .budget
            .clone()
            .acquire_many_owned(mib)
            .await
            .map_err(|_| stopped())?;
        self.tx
            .send(Msg::Step(record, frames, permit))
            .await
            .map_err(|_| RunError::Storage {
                step,
                message: "the writer thread has stopped".into(),
            })?;
        self.check()
    }

    /// Waits until every queued step is durable, records the run's final status and stops
    /// the writer.
    pub async fn finish(
        &self,
        status: RunStatus,
        message: Option<String>,
    ) -> Result<FinishReport, RunError> {
        let (tx, rx) = oneshot::channel();
        let lost = || {
            RunError::Other(
                "the writer thread stopped before the run finished; run `stagehand resume`".into(),
            )
        };
        self.tx
            .send(Msg::Finish(status, message, tx))
            .await
            .map_err(|_| lost())?;
        let report = rx
            .await
            .map_err(|_| lost())?
            .map_err(|e| RunError::Other(e.to_string()))?;
        self.check()?;
        Ok(report)
    }
}

/// Memory a step's frames hold until they are on disk: the raw pixels, the float HDR merges
/// still to make, and the ground truth planes (counted once per image, however many frames
/// share it).
fn step_bytes(frames: &StepFrames) -> usize {
    let raw: usize = frames
        .frames
        .iter()
        .map(|(_, f)| f.pixels.len() * std::mem::size_of::<u16>())
        .sum();
    let hdr: usize = frames
        .hdr
        .iter()
        .filter_map(|(_, idx, _)| idx.first())
        .filter_map(|&i| frames.frames.get(i))
        .map(|(_, f)| f.pixels.len() * std::mem::size_of::<f32>())
        .sum();
    let mut seen = std::collections::BTreeSet::new();
    let truth: usize = frames
        .frames
        .iter()
        .filter_map(|(_, f)| f.ground_truth.as_ref())
        .filter(|g| seen.insert(Arc::as_ptr(g)))
        .flat_map(|g| g.planes.iter())
        .map(|p| p.samples.len() * std::mem::size_of::<f32>())
        .sum();
    raw + hdr + truth
}

fn writer_loop(
    mut store: RunStore,
    mut rx: mpsc::Receiver<Msg>,
    events: broadcast::Sender<Event>,
    failed: Arc<Mutex<Option<(usize, String)>>>,
    reserve_bytes: u64,
    budget: Arc<Semaphore>,
) {
    let mut frames_written = 0usize;
    let mut compression = RawCompression::Deflate;
    // Where the last batch's writing time went: every frame is stored only while encoding,
    // not the disk, holds the writer back.
    let mut last_times = WriteTimes::default();
    let mut first_failure: Option<(usize, String)> = None;
    let mut pending: Option<Msg> = None;
    loop {
        let Some(msg) = pending.take().or_else(|| rx.blocking_recv()) else {
            return;
        };
        match msg {
            Msg::Step(record, frames, permit) => {
                // Take every step already queued (up to the next Finish) as one batch.
                let mut batch = vec![(record, frames, permit)];
                while batch.len() < MAX_BATCH {
                    match rx.try_recv() {
                        Ok(Msg::Step(r, f, p)) => batch.push((r, f, p)),
                        Ok(other) => {
                            pending = Some(other);
                            break;
                        }
                        Err(_) => break,
                    }
                }
                if first_failure.is_some() {
                    continue;
                }
                let steps: Vec<usize> = batch.iter().map(|(r, _, _)| r.step).collect();
                let chosen = compression_for(&budget, last_times.disk_bound());
                if chosen != compression {
                    tracing::info!(
                        step = steps[0],
                        encode_s = last_times.encode_s,
                        write_s = last_times.write_s,
                        "raw frames {}",
                        match chosen {
                            RawCompression::HalfStored =>
                                "half stored uncompressed: the writer is behind the cameras",
                            RawCompression::Stored =>
                                "all stored uncompressed: the writer is far behind the cameras",
                            RawCompression::Deflate =>
                                "all compressed again: the writer has caught up",
                        }
                    );
                    compression = chosen;
                }
                match write_batch(&mut store, batch, reserve_bytes, compression) {
                    Ok((files, times)) => {
                        last_times = times;
                        frames_written += files.iter().sum::<usize>();
                        super::telemetry::frames_written(files.iter().sum());
                        for (step, n) in steps.into_iter().zip(files) {
                            let _ = events.send(Event::StepDurable { step, files: n });
                        }
                    }
                    Err((step, message)) => {
                        tracing::error!("step {step}: {message}");
                        first_failure = Some((step, message.clone()));
                        *failed.lock().unwrap_or_else(|p| p.into_inner()) = Some((step, message));
                    }
                }
            }
            Msg::Finish(status, message, reply) => {
                let (status, message) = match &first_failure {
                    Some((step, m)) => (RunStatus::Failed, Some(format!("step {step}: {m}"))),
                    None => (status, message),
                };
                let result = store
                    .set_status(status, message.as_deref())
                    .and_then(|()| store.done_steps())
                    .map(|done| FinishReport {
                        steps_done: done.len(),
                        frames_written,
                    });
                // Release the run (and its lock) before reporting, so a resume can follow at once.
                drop(store);
                let _ = reply.send(result);
                return;
            }
        }
    }
}

/// Most steps journaled in one transaction.
const MAX_BATCH: usize = 512;

/// Frame data (MiB) in flight, this batch's included, above which half the raw frames are
/// stored uncompressed: deflate takes about half the CPU of a frame's way to disk, and a
/// writer that keeps compressing while behind the cameras would make the next capture late.
const STORE_ABOVE_MIB: usize = BUDGET_MIB as usize / 8;

/// Frame data (MiB) in flight above which every raw frame is stored uncompressed, unless the
/// disk is what holds the writer back: half stored did not let it catch up, and once the
/// budget is full the next capture waits.
const STORE_ALL_ABOVE_MIB: usize = BUDGET_MIB as usize / 4;

/// The compression for the next batch: the fastest deflate unless the writer is behind; the
/// further behind, the more frames stored, but never all of them while `disk_bound` (the last
/// batch spent longer writing than encoding).
fn compression_for(budget: &Semaphore, disk_bound: bool) -> RawCompression {
    let in_flight = (BUDGET_MIB as usize).saturating_sub(budget.available_permits());
    if in_flight > STORE_ALL_ABOVE_MIB && !disk_bound {
        RawCompression::Stored
    } else if in_flight > STORE_ABOVE_MIB {
        RawCompression::HalfStored
    } else {
        RawCompression::Deflate
    }
}

/// Writes a batch of steps (frames first, then one journal transaction); returns the number
/// of files per step and where the frames' writing time went, or the first step that failed
/// and why.
fn write_batch(
    store: &mut RunStore,
    batch: Vec<(StepRecord, StepFrames, OwnedSemaphorePermit)>,
    reserve_bytes: u64,
    compression: RawCompression,
) -> Result<(Vec<usize>, WriteTimes), (usize, String)> {
    let first = batch.first().map(|(r, _, _)| r.step).unwrap_or(0);
    let mut prepared = Vec::with_capacity(batch.len());
    let mut needed = 0u64;
    // A step's permit is held until its frames are written and their pixels freed, so the
    // budget bounds memory truly in flight, while the cameras go on as soon as a step is out.
    let mut permits = Vec::with_capacity(batch.len());
    for (record, frames, permit) in batch {
        permits.push(Mutex::new(Some(permit)));
        let step = record.step;
        let out = prepare_step(frames).map_err(|e| (step, e.to_string()))?;
        needed += out
            .iter()
            .map(|f| {
                f.pixels.len() as u64
                    * if matches!(f.pixels, FramePixels::Raw(_)) {
                        2
                    } else {
                        4
                    }
            })
            .sum::<u64>();
        prepared.push((record, out));
    }
    if needed > 0 {
        let free = store
            .available_bytes()
            .map_err(|e| (first, e.to_string()))?;
        if free < needed.saturating_add(reserve_bytes) {
            return Err((
                first,
                format!(
                    "disk nearly full at {}: {} free, the step needs up to {} plus a reserve of {}; free some space, then `stagehand resume` the run",
                    store.dir().display(),
                    human_bytes(free),
                    human_bytes(needed),
                    human_bytes(reserve_bytes)
                ),
            ));
        }
    }
    let counts = prepared.iter().map(|(_, f)| f.len()).collect();
    let (_, times) = store
        .commit_steps_with(prepared, compression, &|i| {
            if let Some(permit) = permits.get(i) {
                drop(permit.lock().unwrap_or_else(|p| p.into_inner()).take());
            }
        })
        .map_err(|e| (first, e.to_string()))?;
    Ok((counts, times))
}

/// Turns a step's captured frames into the files to write, merging HDR brackets. Ground truth
/// attached to the frames goes beside the first exposure of each camera's bracket.
fn prepare_step(frames: StepFrames) -> Result<Vec<FrameToWrite>, StorageError> {
    let mut merged = Vec::with_capacity(frames.hdr.len());
    for (meta, idx, black) in &frames.hdr {
        let bracket: Vec<&stagehand_devices::Frame> = idx
            .iter()
            .filter_map(|&i| frames.frames.get(i).map(|(_, f)| f))
            .collect();
        let hdr = merge_bracket(&bracket, *black)?;
        let mut meta = meta.clone();
        meta.saturated_samples = hdr.saturated_samples;
        merged.push(FrameToWrite {
            meta,
            pixels: FramePixels::Hdr(hdr.pixels),
            ground_truth: None,
        });
    }
    let mut out: Vec<FrameToWrite> = frames
        .frames
        .into_iter()
        .map(|(meta, frame)| {
            // Ground truth does not depend on the exposure: write it once per capture and
            // camera, beside the bracket's first exposure.
            let ground_truth = frame
                .ground_truth
                .filter(|_| meta.exposure_index == Some(0));
            FrameToWrite {
                meta,
                pixels: FramePixels::Raw(frame.pixels),
                ground_truth,
            }
        })
        .collect();
    out.extend(merged);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_frames_are_stored_more_the_further_the_writer_is_behind() {
        let budget = Semaphore::new(BUDGET_MIB as usize);
        let level = |disk_bound| compression_for(&budget, disk_bound);
        assert_eq!(level(false), RawCompression::Deflate);
        assert_eq!(level(true), RawCompression::Deflate);
        budget.forget_permits(STORE_ABOVE_MIB);
        assert_eq!(level(false), RawCompression::Deflate, "at the first mark");
        budget.forget_permits(1);
        assert_eq!(level(false), RawCompression::HalfStored);
        budget.forget_permits(STORE_ALL_ABOVE_MIB - STORE_ABOVE_MIB - 1);
        assert_eq!(
            level(false),
            RawCompression::HalfStored,
            "at the second mark"
        );
        budget.forget_permits(1);
        assert_eq!(level(false), RawCompression::Stored);
        assert_eq!(
            level(true),
            RawCompression::HalfStored,
            "a writer held back by the disk never stores every frame"
        );
        budget.forget_permits(budget.available_permits());
        assert_eq!(level(false), RawCompression::Stored, "budget full");
        assert_eq!(level(true), RawCompression::HalfStored, "budget full");
        budget.add_permits(BUDGET_MIB as usize);
        assert_eq!(level(false), RawCompression::Deflate, "caught up");
    }
}
