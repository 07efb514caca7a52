//! The rig clock: every wait in devices and the executor goes through it.
//!
//! It is built on tokio's clock. In simulation the runtime runs with paused time, so tokio
//! advances the clock to the next timer whenever every task is waiting: a six-hour plan runs in
//! seconds, deterministically, and still reports its rig time. On real hardware the same code
//! waits in real time, on a kernel timer that ends within tenths of a millisecond (see
//! [`sleep_until`]).

use std::time::Duration;
use tokio::io::Interest;
use tokio::io::unix::AsyncFd;
use tokio::runtime::{Handle, RuntimeFlavor};
use tokio::time::Instant;

/// Rig time source; cheap to copy.
#[derive(Debug, Clone, Copy)]
pub struct RigClock {
    start: Instant,
    offset_s: f64,
}

impl RigClock {
    /// A clock reading `offset_s` now (a resumed run continues its rig time).
    pub fn starting_at(offset_s: f64) -> Self {
        Self {
            start: Instant::now(),
            offset_s,
        }
    }

    /// Seconds of rig time.
    pub fn now_s(&self) -> f64 {
        self.offset_s + self.start.elapsed().as_secs_f64()
    }

    /// Waits `seconds` of rig time (negative or NaN waits nothing).
    pub async fn sleep_s(&self, seconds: f64) {
        sleep(duration_s(seconds)).await;
    }

    /// Waits until the clock reads `rig_time_s` (a time already past waits nothing). A
    /// schedule's waits should use this, not [`sleep_s`](Self::sleep_s) of the time left: the
    /// deadline stays the same however long the task took to reach the wait.
    pub async fn sleep_until_s(&self, rig_time_s: f64) {
        sleep_until(self.start + duration_s(rig_time_s - self.offset_s)).await;
    }
}

/// Waits `d` (see [`sleep_until`]).
pub async fn sleep(d: Duration) {
    if d.is_zero() {
        return;
    }
    sleep_until(Instant::now() + d).await;
}

/// Waits until `deadline`. In real time (a multi-threaded runtime) it waits on a kernel timer
/// (`timerfd`) armed for the deadline itself, which ended 0.04–0.20 ms late on the development
/// machine where tokio's own timer, which rounds every deadline up to its next millisecond
/// tick, ended 1.1–1.35 ms late (`cargo bench --bench timer_precision`): that added up to 3 %
/// of a sweep line on the simulated rig and paced a 15 Hz capture at 14.7 Hz. On the virtual
/// clock (paused time, which tokio allows only on a current-thread runtime) it is tokio's
/// sleep, so paused time still jumps to it.
pub async fn sleep_until(deadline: Instant) {
    if deadline <= Instant::now() {
        return;
    }
    let real_time = matches!(
        Handle::try_current().map(|h| h.runtime_flavor()),
        Ok(RuntimeFlavor::MultiThread)
    );
    // Without a kernel timer (no descriptor left, no I/O driver) tokio's timer still waits.
    if real_time && kernel_timer(deadline).await.is_ok() {
        return;
    }
    tokio::time::sleep_until(deadline).await;
}

/// Waits until `deadline` on a one-shot `timerfd` polled by the runtime's I/O driver. The timer
/// is armed at an absolute time on the monotonic clock (tokio's `Instant` in real time), so a
/// thread preempted before it arms the timer does not push the deadline back. Armed with the
/// time left, the 99th percentile of a 15 Hz capture's pacing wait had ended 4.5 ms late while
/// the frame writer kept both cores busy (`frame_pipeline`).
#[allow(unsafe_code)]
async fn kernel_timer(deadline: Instant) -> std::io::Result<()> {
    use rustix::time::{
        ClockId, Itimerspec, TimerfdClockId, TimerfdFlags, TimerfdTimerFlags, Timespec,
        clock_gettime, timerfd_create, timerfd_settime,
    };
    let fd = timerfd_create(
        TimerfdClockId::Monotonic,
        TimerfdFlags::NONBLOCK | TimerfdFlags::CLOEXEC,
    )?;
    // The deadline on the monotonic clock: two readings taken together, nanoseconds apart.
    let left = deadline.saturating_duration_since(Instant::now());
    let at = timespec_after(clock_gettime(ClockId::Monotonic), left);
    let zero = Timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    timerfd_settime(
        &fd,
        TimerfdTimerFlags::ABSTIME,
        &Itimerspec {
            it_interval: zero,
            it_value: at,
        },
    )?;
    // SAFETY: `AsyncFd` owns the `OwnedFd`, whose descriptor stays open and the same until
    // both are dropped together.
    let fd = unsafe { AsyncFd::register_with_interest(fd, Interest::READABLE) }
        .map_err(|e| e.into_parts().1)?;
    loop {
        let mut ready = fd.readable().await?;
        let mut expirations = [0u8; 8];
        match ready.try_io(|fd| Ok(rustix::io::read(fd.get_ref(), &mut expirations)?)) {
            Ok(read) => return read.map(|_| ()),
            // Woken without an expiry: readiness is cleared, wait again.
            Err(_would_block) => continue,
        }
    }
}

/// `t` plus `d`, carrying nanoseconds into seconds (saturating, never panicking).
fn timespec_after(t: rustix::time::Timespec, d: Duration) -> rustix::time::Timespec {
    let nanos = i128::from(t.tv_nsec) + i128::from(d.subsec_nanos());
    rustix::time::Timespec {
        tv_sec: t
            .tv_sec
            .saturating_add(i64::try_from(d.as_secs()).unwrap_or(i64::MAX))
            .saturating_add(i64::from(nanos >= 1_000_000_000)),
        tv_nsec: (nanos % 1_000_000_000) as _,
    }
}

impl Default for RigClock {
    fn default() -> Self {
        Self::starting_at(0.0)
    }
}

/// Converts seconds to a `Duration`, saturating absurd values instead of panicking.
pub fn duration_s(seconds: f64) -> Duration {
    if !seconds.is_finite() || seconds <= 0.0 {
        Duration::ZERO
    } else {
        Duration::from_secs_f64(seconds.min(1.0e9))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_real_time_sleep_never_wakes_early() {
        // The kernel timer itself works here (the fallback would hide it).
        let t0 = std::time::Instant::now();
        kernel_timer(Instant::now() + Duration::from_micros(300))
            .await
            .unwrap();
        assert!(t0.elapsed() >= Duration::from_micros(300));
        // A deadline already past returns at once.
        kernel_timer(Instant::now()).await.unwrap();
        for micros in [1, 50, 900, 2_000, 20_000] {
            let d = Duration::from_micros(micros);
            let t0 = std::time::Instant::now();
            sleep(d).await;
            assert!(t0.elapsed() >= d, "{micros} µs");
        }
        // A cancelled sleep is simply dropped (its descriptor closes with it).
        let cancelled =
            tokio::time::timeout(Duration::from_millis(1), sleep(Duration::from_secs(60)));
        assert!(cancelled.await.is_err());
        let clock = RigClock::default();
        let t0 = clock.now_s();
        clock.sleep_s(0.003).await;
        assert!(clock.now_s() - t0 >= 0.003);
        clock.sleep_s(f64::NAN).await;
        clock.sleep_s(-1.0).await;
        let t0 = clock.now_s();
        clock.sleep_until_s(t0 + 0.002).await;
        assert!(clock.now_s() >= t0 + 0.002);
        clock.sleep_until_s(t0).await;
        clock.sleep_until_s(f64::NAN).await;
    }

    #[test]
    fn a_deadline_carries_nanoseconds_into_seconds() {
        let t = rustix::time::Timespec {
            tv_sec: 7,
            tv_nsec: 999_999_999,
        };
        let at = timespec_after(t, Duration::new(2, 2));
        assert_eq!((at.tv_sec, at.tv_nsec), (10, 1));
        let at = timespec_after(t, Duration::from_nanos(0));
        assert_eq!((at.tv_sec, at.tv_nsec), (7, 999_999_999));
        let far = timespec_after(t, Duration::MAX);
        assert_eq!(far.tv_sec, i64::MAX);
        assert!(far.tv_nsec < 1_000_000_000);
    }

    #[tokio::test(start_paused = true)]
    async fn on_the_virtual_clock_a_sleep_jumps_to_its_deadline() {
        let clock = RigClock::starting_at(5.0);
        let wall = std::time::Instant::now();
        clock.sleep_s(3600.0).await;
        assert_eq!(clock.now_s(), 3605.0);
        sleep(Duration::from_secs(7200)).await;
        assert_eq!(clock.now_s(), 10805.0);
        clock.sleep_until_s(10900.0).await;
        assert_eq!(clock.now_s(), 10900.0);
        // An hour and more of rig time, without waiting for it.
        assert!(wall.elapsed() < Duration::from_secs(60));
    }
}
