//! Prometheus metrics of the executor: step timing, steps, frames written and dropped, device
//! errors, reconnects and finished runs. The macros are no-ops until a recorder is installed
//! (the daemon installs one; the CLI does not), so the CLI pays nothing.

use stagehand_devices::{DeviceError, DeviceErrorKind};

/// Describes the executor's metrics (HELP lines); call once after installing a recorder.
pub fn describe_metrics() {
    metrics::describe_histogram!(
        "stagehand_step_seconds",
        metrics::Unit::Seconds,
        "Wall time of each executed step, by step kind"
    );
    metrics::describe_counter!("stagehand_steps_total", "Steps executed, by step kind");
    metrics::describe_counter!(
        "stagehand_frames_written_total",
        "Frame files made durable (raw and HDR)"
    );
    metrics::describe_counter!(
        "stagehand_frames_dropped_total",
        "Frames a camera failed to deliver (missing, timeout) or delivered for the wrong trigger (unexpected); the step is retaken"
    );
    metrics::describe_counter!(
        "stagehand_device_errors_total",
        "Device errors during runs, by device"
    );
    metrics::describe_counter!(
        "stagehand_reconnects_total",
        "Devices re-established after a fault during a run, by device"
    );
    metrics::describe_counter!("stagehand_runs_total", "Runs finished, by final status");
}

/// A step finished after `wall_s` seconds of wall time.
pub(super) fn step_done(kind: &'static str, wall_s: f64) {
    metrics::histogram!("stagehand_step_seconds", "kind" => kind).record(wall_s);
    metrics::counter!("stagehand_steps_total", "kind" => kind).increment(1);
}

/// A device failed during a step (or while recovering).
pub(super) fn device_error(e: &DeviceError) {
    let device = e.device().to_string();
    let dropped = match &e.kind {
        DeviceErrorKind::MissingFrame { .. } => Some("missing"),
        DeviceErrorKind::UnexpectedFrame { .. } => Some("unexpected"),
        // The camera task did not answer the frame request in time (exposure + readout).
        DeviceErrorKind::Timeout { request, .. } if request == "frame" => Some("timeout"),
        // A simulated camera's frame that never came (a stall injected into the simulation).
        DeviceErrorKind::SimulatedFault { request, .. } if request == "frame" => Some("missing"),
        _ => None,
    };
    if let Some(reason) = dropped {
        metrics::counter!("stagehand_frames_dropped_total", "device" => device.clone(), "reason" => reason)
            .increment(1);
    }
    metrics::counter!("stagehand_device_errors_total", "device" => device).increment(1);
}

/// A device was re-established after a fault.
pub(super) fn reconnected(device: &str) {
    metrics::counter!("stagehand_reconnects_total", "device" => device.to_string()).increment(1);
}

/// `n` frame files became durable.
pub(super) fn frames_written(n: usize) {
    metrics::counter!("stagehand_frames_written_total").increment(n as u64);
}

/// A run finished with `status` (`done`, `failed`, `aborted`).
pub(super) fn run_finished(status: &str) {
    metrics::counter!("stagehand_runs_total", "status" => status.to_string()).increment(1);
}
