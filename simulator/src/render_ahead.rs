//! Rendering ahead on a real-time rig. While the simulated rig settles (a lamp warming up, an
//! axis moving to its target) a worker thread traces what every camera will see once it has
//! settled ([`World::settled_snapshot`]), so a frame of that world reuses the trace, or waits
//! for the rest of it, instead of tracing after its exposure: the rendering overlaps the
//! rig's own waits as a real camera's readout does. The frames are the same, bit for bit (the
//! trace is keyed on the exact world, `render/kept_radiance.rs`); a wrong guess costs CPU
//! only. Only the daemon's rig renders ahead, and only while a run drives it (an operator
//! jogging would make it trace worlds no frame sees); on the virtual clock settling takes no
//! time.

use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, Weak};
use std::time::Duration;

use crate::world::World;

/// How long the worker lets a burst of changes settle (a lamp step switches one relay after
/// another) before it guesses the world.
const BURST: Duration = Duration::from_millis(3);

/// What the worker is asked to do and is doing.
#[derive(Debug, Default)]
struct Wanted {
    /// The rig changed since the worker last looked.
    changed: bool,
    /// The worker is tracing.
    busy: bool,
    /// The world is gone: stop.
    closed: bool,
}

#[derive(Debug, Default)]
struct Shared {
    wanted: Mutex<Wanted>,
    wake: Condvar,
    /// Changes are traced only while on (a run drives the rig), not while an operator jogs.
    on: AtomicBool,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Wanted> {
        self.wanted
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn wait<'a>(&self, guard: MutexGuard<'a, Wanted>) -> MutexGuard<'a, Wanted> {
        self.wake
            .wait(guard)
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// The render-ahead worker of one [`World`]; stops when dropped.
#[derive(Debug)]
pub(crate) struct RenderAhead {
    shared: Arc<Shared>,
}

impl RenderAhead {
    /// Starts the worker for `world` (held weakly: the worker never keeps the world alive).
    pub(crate) fn start(world: Weak<World>) -> std::io::Result<RenderAhead> {
        let shared = Arc::new(Shared::default());
        let theirs = Arc::clone(&shared);
        std::thread::Builder::new()
            .name("render-ahead".into())
            .spawn(move || work(&theirs, &world))?;
        Ok(RenderAhead { shared })
    }

    /// Traces changes from now on (`true`) or ignores them (`false`).
    pub(crate) fn set_on(&self, on: bool) {
        self.shared.on.store(on, Ordering::Relaxed);
        if on {
            self.changed();
        }
    }

    /// The rig changed: guess its settled world again (while on).
    pub(crate) fn changed(&self) {
        if self.shared.on.load(Ordering::Relaxed) {
            self.shared.lock().changed = true;
            self.shared.wake.notify_all();
        }
    }

    /// Blocks until the worker has traced every change so far (for tests).
    pub(crate) fn wait_idle(&self) {
        let mut wanted = self.shared.lock();
        while (wanted.changed || wanted.busy) && !wanted.closed {
            wanted = self.shared.wait(wanted);
        }
    }
}

impl Drop for RenderAhead {
    fn drop(&mut self) {
        self.shared.lock().closed = true;
        self.shared.wake.notify_all();
    }
}

/// The worker: on every change, after a burst settles, trace each camera's view of the
/// settled world, dropping a guess the rig has changed away from.
fn work(shared: &Shared, world: &Weak<World>) {
    loop {
        {
            let mut wanted = shared.lock();
            while !wanted.changed && !wanted.closed {
                wanted = shared.wait(wanted);
            }
            if wanted.closed {
                return;
            }
        }
        std::thread::sleep(BURST);
        let _busy = Busy::start(shared);
        if let Some(world) = world.upgrade()
            && let Some(settled) = world.settled_snapshot()
        {
            for camera in &world.rig().cameras {
                if shared.lock().changed || !shared.on.load(Ordering::Relaxed) {
                    break;
                }
                // A failing or panicking trace fails the frame's own render too, which reports
                // it; the worker lives on to guess the next world.
                let _ = std::panic::catch_unwind(AssertUnwindSafe(|| {
                    world.renderer().render_ahead(&settled, &camera.id)
                }));
            }
        }
    }
}

/// The worker's busy flag, set while it traces and cleared however the trace ends.
struct Busy<'a>(&'a Shared);

impl<'a> Busy<'a> {
    fn start(shared: &'a Shared) -> Busy<'a> {
        let mut wanted = shared.lock();
        wanted.changed = false;
        wanted.busy = true;
        Busy(shared)
    }
}

impl Drop for Busy<'_> {
    fn drop(&mut self) {
        self.0.lock().busy = false;
        self.0.wake.notify_all();
    }
}
