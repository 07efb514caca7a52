//! Time a simulated device spends computing (the simulator rendering a frame) that the physical
//! device it stands in for would not spend. Timeouts built from physics (exposure + readout +
//! margin) do not count it, so a slow render on a busy machine is never mistaken for a lost
//! frame or a loose cable.

use std::future::Future;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::time::Instant;

/// Shared account of computing time; cheap to clone. A device that never computes (real
/// hardware) keeps the default, which never excuses any time.
#[derive(Clone, Debug, Default)]
pub struct ComputeTime(Arc<Mutex<Spent>>);

#[derive(Debug, Default)]
struct Spent {
    /// Finished computations.
    total: Duration,
    /// Start of the computation in progress.
    since: Option<Instant>,
}

impl ComputeTime {
    fn lock(&self) -> MutexGuard<'_, Spent> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Computing time so far, including the computation in progress.
    pub fn spent(&self) -> Duration {
        let s = self.lock();
        s.total + s.since.map(|t| t.elapsed()).unwrap_or_default()
    }

    /// Runs `f`, counting its duration as computing time.
    pub fn measure<T>(&self, f: impl FnOnce() -> T) -> T {
        self.begin();
        let out = f();
        self.end();
        out
    }

    fn begin(&self) {
        self.lock().since = Some(Instant::now());
    }

    fn end(&self) {
        let mut s = self.lock();
        if let Some(t) = s.since.take() {
            s.total += t.elapsed();
        }
    }

    /// Awaits `fut` for at most `limit` of time not spent computing; `None` when that passes
    /// first. With no computation this is `tokio::time::timeout`.
    pub async fn timeout<F: Future>(&self, limit: Duration, fut: F) -> Option<F::Output> {
        let start = Instant::now();
        let base = self.spent();
        tokio::pin!(fut);
        loop {
            // Computing time is added as it accrues, so while a render runs the deadline keeps
            // moving ahead of the clock.
            let deadline = start + limit + self.spent().saturating_sub(base);
            tokio::select! {
                biased;
                out = &mut fut => return Some(out),
                () = tokio::time::sleep_until(deadline) => {
                    if start + limit + self.spent().saturating_sub(base) <= Instant::now() {
                        return None;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn without_computation_it_is_a_plain_timeout() {
        let ct = ComputeTime::default();
        let never = std::future::pending::<()>();
        let t0 = Instant::now();
        assert_eq!(ct.timeout(Duration::from_secs(3), never).await, None);
        assert_eq!(t0.elapsed(), Duration::from_secs(3));
        let ready = async { 7 };
        assert_eq!(ct.timeout(Duration::from_secs(3), ready).await, Some(7));
    }

    #[tokio::test(start_paused = true)]
    async fn computing_time_does_not_count_against_the_limit() {
        let ct = ComputeTime::default();
        let worker = ct.clone();
        // A "render" that holds the clock for 5 s (paused time advances only by sleeping, so
        // the render is modelled as a sleep inside a counted computation).
        let job = async move {
            tokio::time::sleep(Duration::from_secs(1)).await;
            worker.begin();
            tokio::time::sleep(Duration::from_secs(5)).await;
            worker.end();
            tokio::time::sleep(Duration::from_secs(1)).await;
            "frame"
        };
        let t0 = Instant::now();
        assert_eq!(ct.timeout(Duration::from_secs(3), job).await, Some("frame"));
        assert_eq!(t0.elapsed(), Duration::from_secs(7));
        assert_eq!(ct.spent(), Duration::from_secs(5));
    }

    #[tokio::test(start_paused = true)]
    async fn a_stall_after_computing_still_times_out() {
        let ct = ComputeTime::default();
        let worker = ct.clone();
        let job = async move {
            worker.begin();
            tokio::time::sleep(Duration::from_secs(2)).await;
            worker.end();
            std::future::pending::<()>().await;
        };
        let t0 = Instant::now();
        assert_eq!(ct.timeout(Duration::from_secs(3), job).await, None);
        assert_eq!(t0.elapsed(), Duration::from_secs(5));
    }
}
