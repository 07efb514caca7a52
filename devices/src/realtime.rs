//! Real-time scheduling for the threads that drive the rig: `stagehand` asks for
//! [`DEFAULT_PRIORITY`] unless told otherwise (`--realtime-priority N` or `off`).
//!
//! With the frame writer keeping both cores of a small PC busy, the kernel lets a running
//! writer thread finish its time slice before the capture's woken thread runs, so a paced
//! trigger can fire several milliseconds late even though the writer runs at nice 19. A
//! runtime thread at `SCHED_FIFO` runs as soon as it wakes. It needs `CAP_SYS_NICE` or an
//! `RLIMIT_RTPRIO` at least the priority asked for (README, "Installing on a lab PC").
//! Threads started by such a thread (the frame writer's pool, the renderer's) get normal
//! scheduling (`SCHED_RESET_ON_FORK`), so only the runtime's own threads are raised, and work
//! that may take a core for long on a runtime thread (a simulated camera's rendering, a
//! blocking task) runs at normal priority through [`at_normal_priority`] and
//! [`spawn_blocking`]: at `SCHED_FIFO` it would keep the frame writer off that core.

use std::cell::Cell;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

/// Highest `SCHED_FIFO` priority Linux accepts.
pub const MAX_PRIORITY: u8 = 99;

/// The `SCHED_FIFO` priority `stagehand` asks for when no `--realtime-priority` is given: low
/// among real-time priorities (the kernel's own interrupt threads run at 50), above every
/// normal thread.
pub const DEFAULT_PRIORITY: u8 = 10;

static PRIORITY: OnceLock<u8> = OnceLock::new();
/// Whether the priority was asked for (`--realtime-priority N`) rather than the default.
static ASKED: AtomicBool = AtomicBool::new(false);
/// The system's answer at the first refusal to raise a thread (which is logged then).
static REFUSED: OnceLock<String> = OnceLock::new();

thread_local! {
    /// The `SCHED_FIFO` priority this thread was raised to, if it was.
    static RAISED: Cell<Option<u8>> = const { Cell::new(None) };
}

/// Sets the `SCHED_FIFO` priority (1..=[`MAX_PRIORITY`]) that runtime threads started from now
/// on ask for, as asked for by the user (a refusal is a warning); the first call wins. Call it
/// before building the runtime.
pub fn set_priority(priority: u8) {
    if PRIORITY.set(priority.clamp(1, MAX_PRIORITY)).is_ok() {
        ASKED.store(true, Ordering::Relaxed);
    }
}

/// Sets [`DEFAULT_PRIORITY`] for runtime threads started from now on, where the system allows
/// it: a refusal is logged at info level and the threads keep normal scheduling.
fn set_default_priority() {
    let _ = PRIORITY.set(DEFAULT_PRIORITY);
}

/// A `--realtime-priority` value: a `SCHED_FIFO` priority, or `off` for normal scheduling.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Choice {
    Priority(u8),
    Off,
}

/// Parses a `--realtime-priority` value: a priority from 1 to [`MAX_PRIORITY`], or `off`.
pub fn parse_choice(value: &str) -> Result<Choice, String> {
    if value == "off" {
        return Ok(Choice::Off);
    }
    value
        .parse::<u8>()
        .ok()
        .filter(|p| (1..=MAX_PRIORITY).contains(p))
        .map(Choice::Priority)
        .ok_or_else(|| format!("expected a priority from 1 to {MAX_PRIORITY}, or `off`"))
}

/// Sets how runtime threads started from now on are scheduled: as chosen, or at
/// [`DEFAULT_PRIORITY`] where the system allows it when nothing was chosen. Call it before
/// building the runtime.
pub fn choose(choice: Option<Choice>) {
    match choice {
        None => set_default_priority(),
        Some(Choice::Priority(p)) => set_priority(p),
        Some(Choice::Off) => {}
    }
}

/// The priority set with [`set_priority`], if any.
pub fn priority() -> Option<u8> {
    PRIORITY.get().copied()
}

/// Whether the system refused to raise a thread (logged once, by [`raise_this_thread`]).
pub fn refused() -> bool {
    REFUSED.get().is_some()
}

/// One line on how the rig's threads are scheduled, for a startup banner: real-time, normal
/// because no priority was set (`--realtime-priority off`), or normal because the system
/// refused, with what to grant.
pub fn describe() -> String {
    match (priority(), REFUSED.get()) {
        (None, _) => "normal (--realtime-priority off)".to_string(),
        (Some(p), None) => format!("real-time for the rig's threads (SCHED_FIFO {p})"),
        (Some(p), Some(e)) => format!(
            "normal: SCHED_FIFO {p} refused ({e}); paced triggers may come late while frames \
             are written at full rate. {}",
            what_to_grant(p)
        ),
    }
}

/// What lets a process raise its threads to `priority`.
fn what_to_grant(priority: u8) -> String {
    format!(
        "Give the process CAP_SYS_NICE or an RLIMIT_RTPRIO of at least {priority} \
         (systemd: LimitRTPRIO={priority} and RestrictRealtime=false)"
    )
}

/// For a runtime's `on_thread_start`: puts the calling thread at the `SCHED_FIFO` priority set
/// with [`set_priority`] (nothing when none was set). When the system refuses, the thread keeps
/// its scheduling and the first refusal is logged with what to do.
pub fn raise_this_thread() {
    let Some(priority) = priority() else { return };
    match set_fifo(priority) {
        Ok(()) => RAISED.set(Some(priority)),
        Err(e) if REFUSED.set(e.to_string()).is_ok() => {
            if ASKED.load(Ordering::Relaxed) {
                tracing::warn!(
                    "--realtime-priority {priority}: the runtime's threads keep normal \
                     scheduling: {e}. {}",
                    what_to_grant(priority)
                );
            } else {
                tracing::info!(
                    "the runtime's threads keep normal scheduling (SCHED_FIFO {priority} \
                     refused: {e}); paced triggers may come late under load. {}, or pass \
                     --realtime-priority off",
                    what_to_grant(priority)
                );
            }
        }
        Err(_) => {}
    }
}

/// Runs `f` at normal scheduling on a raised thread (as is on any other), then raises the
/// thread again: for work that may hold a core for long, such as rendering a frame.
pub fn at_normal_priority<T>(f: impl FnOnce() -> T) -> T {
    let Some(priority) = RAISED.get() else {
        return f();
    };
    /// Raises the thread again when `f` returns or unwinds.
    struct Restore(u8);
    impl Drop for Restore {
        fn drop(&mut self) {
            if set_fifo(self.0).is_err() {
                RAISED.set(None);
            }
        }
    }
    if set_normal().is_err() {
        return f();
    }
    let _restore = Restore(priority);
    f()
}

/// `tokio::task::spawn_blocking` with `f` at normal scheduling ([`at_normal_priority`]): the
/// runtime's blocking threads are raised like its workers. The one sanctioned caller of
/// tokio's (`clippy.toml` refuses it elsewhere).
#[allow(clippy::disallowed_methods)]
pub fn spawn_blocking<F, R>(f: F) -> tokio::task::JoinHandle<R>
where
    F: FnOnce() -> R + Send + 'static,
    R: Send + 'static,
{
    tokio::task::spawn_blocking(move || at_normal_priority(f))
}

/// Puts the calling thread at `SCHED_FIFO` `priority`.
#[cfg(target_os = "linux")]
fn set_fifo(priority: u8) -> std::io::Result<()> {
    set_policy(libc::SCHED_FIFO, i32::from(priority))
}

/// Puts the calling thread back at `SCHED_OTHER` (its nice value unchanged).
#[cfg(target_os = "linux")]
fn set_normal() -> std::io::Result<()> {
    set_policy(libc::SCHED_OTHER, 0)
}

/// `sched_setscheduler` on the calling thread, with `SCHED_RESET_ON_FORK`.
#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
fn set_policy(policy: i32, priority: i32) -> std::io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: a plain system call on the calling thread (pid 0), reading `param` only.
    let rc = unsafe { libc::sched_setscheduler(0, policy | libc::SCHED_RESET_ON_FORK, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn set_normal() -> std::io::Result<()> {
    Ok(())
}

#[cfg(not(target_os = "linux"))]
fn set_fifo(_priority: u8) -> std::io::Result<()> {
    Err(std::io::Error::other(
        "real-time priority is only set on Linux",
    ))
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[allow(unsafe_code)]
    fn policy() -> i32 {
        // SAFETY: a plain system call about the calling thread.
        unsafe { libc::sched_getscheduler(0) }
    }

    /// A raised thread runs at `SCHED_FIFO` (where the system allows it) and the threads it
    /// starts do not: the frame writer must never outrank the capture loop.
    #[test]
    #[allow(unsafe_code)]
    fn a_raised_thread_starts_threads_at_normal_scheduling() {
        let raised = std::thread::spawn(|| {
            if let Err(e) = set_fifo(1) {
                // Without CAP_SYS_NICE the thread stays as it was; root (CI) has it.
                // SAFETY: a plain system call.
                assert_ne!(
                    unsafe { libc::geteuid() },
                    0,
                    "root may raise a thread: {e}"
                );
                return None;
            }
            let own = policy() & !libc::SCHED_RESET_ON_FORK;
            let child = std::thread::spawn(policy).join().unwrap();
            Some((own, child))
        })
        .join()
        .unwrap();
        if let Some((own, child)) = raised {
            assert_eq!(own, libc::SCHED_FIFO);
            assert_eq!(child, libc::SCHED_OTHER);
        }
    }

    /// Work run at normal priority on a raised thread runs at `SCHED_OTHER`, and the thread is
    /// raised again afterwards, also when the work panics.
    #[test]
    fn work_at_normal_priority_runs_normal_and_the_thread_is_raised_again() {
        let seen = std::thread::spawn(|| {
            if set_fifo(1).is_err() {
                return None; // not permitted here (see above)
            }
            RAISED.set(Some(1));
            let inside = at_normal_priority(policy) & !libc::SCHED_RESET_ON_FORK;
            let after = policy() & !libc::SCHED_RESET_ON_FORK;
            let unwound = std::panic::catch_unwind(|| at_normal_priority(|| panic!("render")));
            let after_panic = policy() & !libc::SCHED_RESET_ON_FORK;
            Some((inside, after, unwound.is_err(), after_panic))
        })
        .join()
        .unwrap();
        if let Some(seen) = seen {
            assert_eq!(
                seen,
                (libc::SCHED_OTHER, libc::SCHED_FIFO, true, libc::SCHED_FIFO)
            );
        }
        // On a thread that was never raised the work runs as it is.
        assert_eq!(at_normal_priority(policy), libc::SCHED_OTHER);
    }

    /// A runtime built as the daemon builds it runs its tasks at `SCHED_FIFO` and its blocking
    /// work ([`spawn_blocking`]) at `SCHED_OTHER`.
    #[test]
    fn a_raised_runtime_runs_tasks_real_time_and_blocking_work_normal() {
        if !std::thread::spawn(|| set_fifo(1).is_ok()).join().unwrap() {
            return; // not permitted here (see above)
        }
        set_priority(1);
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .on_thread_start(raise_this_thread)
            .build()
            .unwrap();
        let (task, blocking) = runtime.block_on(async {
            let task = tokio::spawn(async { policy() }).await.unwrap();
            let blocking = spawn_blocking(policy).await.unwrap();
            (task, blocking)
        });
        assert_eq!(task & !libc::SCHED_RESET_ON_FORK, libc::SCHED_FIFO);
        assert_eq!(blocking & !libc::SCHED_RESET_ON_FORK, libc::SCHED_OTHER);
    }
}
