//! The transport counters of a GenICam camera's streams (packets resent and missing, frames
//! failed or incomplete, reopens), summed over every stream it opened.

use std::sync::{Arc, Mutex, PoisonError};

use aravis::glib::prelude::*;
use aravis::prelude::*;
use aravis::{GvStream, Stream};

/// Transport counters of one camera, summed over every stream it opened.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamCounters {
    /// Frames the stream completed (aravis `n_completed_buffers`).
    pub completed_frames: u64,
    /// Frames the stream gave up on or delivered incomplete (aravis `n_failures`).
    pub failed_frames: u64,
    /// Frames dropped because no buffer was free (aravis `n_underruns`).
    pub underruns: u64,
    /// Packets the camera sent again when asked (aravis `n_resent_packets`).
    pub resent_packets: u64,
    /// Packets still missing when their frame was given up (aravis `n_missing_packets`).
    pub missing_packets: u64,
    /// Frames this driver reported as missing because they arrived incomplete.
    pub incomplete_frames: u64,
    /// Times the camera was reopened after it was lost.
    pub reopens: u64,
}

impl StreamCounters {
    pub(super) fn plus(self, o: Self) -> Self {
        Self {
            completed_frames: self.completed_frames + o.completed_frames,
            failed_frames: self.failed_frames + o.failed_frames,
            underruns: self.underruns + o.underruns,
            resent_packets: self.resent_packets + o.resent_packets,
            missing_packets: self.missing_packets + o.missing_packets,
            incomplete_frames: self.incomplete_frames + o.incomplete_frames,
            reopens: self.reopens + o.reopens,
        }
    }

    /// The counters aravis keeps for `stream` (the driver's own counts are zero).
    pub(super) fn of(stream: &Stream) -> Self {
        let (completed_frames, failed_frames, underruns) = stream.statistics();
        let (resent_packets, missing_packets) = stream
            .downcast_ref::<GvStream>()
            .map_or((0, 0), |gv| gv.statistics());
        Self {
            completed_frames,
            failed_frames,
            underruns,
            resent_packets,
            missing_packets,
            ..Self::default()
        }
    }
}

/// A live view of one camera's [`StreamCounters`], updated by its worker thread.
#[derive(Debug, Clone, Default)]
pub struct StreamStats(Arc<Mutex<StreamCounters>>);

impl StreamStats {
    /// The counters as of the worker's last grab.
    pub fn snapshot(&self) -> StreamCounters {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    pub(super) fn set(&self, c: StreamCounters) {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner) = c;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counters_add_up() {
        let a = StreamCounters {
            completed_frames: 3,
            resent_packets: 2,
            reopens: 1,
            ..StreamCounters::default()
        };
        let b = StreamCounters {
            completed_frames: 4,
            missing_packets: 5,
            incomplete_frames: 1,
            ..StreamCounters::default()
        };
        let s = a.plus(b);
        assert_eq!(
            (s.completed_frames, s.resent_packets, s.missing_packets),
            (7, 2, 5)
        );
        assert_eq!((s.incomplete_frames, s.reopens), (1, 1));
    }
}
