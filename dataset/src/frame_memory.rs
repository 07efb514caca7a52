//! How the process's allocator treats frame buffers. A 1024×768 16-bit RGB frame is 4.7 MB;
//! at the rig's rates some sixty are made and freed a second. Left to glibc's defaults, each
//! freed buffer went back to the kernel and the next was faulted in again, page by page
//! (60,000 page faults a second at 7.5 Hz, a third of a core in the kernel, and the capture
//! loop's worst intervals with them: `cargo bench --bench frame_pipeline`). Kept in the
//! allocator, the next frame reuses them. One heap (arena) per core rather than glibc's eight
//! per core: buffers freed by one thread (the writer's) are reused by the others instead of
//! each arena keeping its own, so the memory kept is one pool (at 12 Hz for 30 s, four runs
//! each, alternated: peak RSS 177–240 MiB against 273–318 MiB, 4 late captures of 1,440
//! against 5).

/// Largest allocation glibc serves from its heaps rather than a fresh mapping: its maximum on
/// 64-bit (32 MiB), above any frame of the built-in rigs.
const MMAP_THRESHOLD_BYTES: i32 = 32 << 20;

/// Free memory glibc keeps at a heap's top before returning it to the kernel: half the
/// writer's 512 MiB frame budget, so the frames in flight are recycled, not refaulted.
const TRIM_THRESHOLD_BYTES: i32 = 256 << 20;

/// Asks the allocator to keep freed frame buffers for the next frames, in one heap per core.
/// Call once, first thing in `main`, before other threads start; nothing happens where the C
/// library is not glibc. Returns whether every setting took.
#[allow(unsafe_code)]
pub fn keep_frame_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let arenas = i32::try_from(cores).unwrap_or(i32::MAX);
        // SAFETY: `mallopt` only sets allocator parameters; called before other threads
        // allocate, as its documentation asks.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1
                && libc::mallopt(libc::M_ARENA_MAX, arenas) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

/// Gives the memory the allocator kept for frames (see [`keep_frame_memory`]) back to the
/// system once no run is making frames, so an idle daemon holds its live data only (measured
/// in the README's "The daemon's memory"). Returns whether any memory went back;
/// false where the C library is not glibc.
#[allow(unsafe_code)]
pub fn release_frame_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: `malloc_trim` only returns free heap pages to the kernel.
        unsafe { libc::malloc_trim(0) == 1 }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On this glibc target every setting is accepted (mallopt returns 1), and a frame-sized
    /// buffer freed and made again keeps working memory.
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_accepts_every_setting() {
        assert!(keep_frame_memory());
        let frame = vec![1u16; 1024 * 768 * 3];
        assert_eq!(frame.iter().map(|&v| v as u64).sum::<u64>(), 1024 * 768 * 3);
    }

    /// Frame buffers freed and kept by the allocator go back to the system on release.
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn kept_frames_are_released() {
        assert!(keep_frame_memory());
        let frames: Vec<Vec<u16>> = (0..8).map(|k| vec![k as u16; 1024 * 768 * 3]).collect();
        assert_eq!(frames[7][1000], 7);
        drop(frames);
        assert!(release_frame_memory(), "nothing went back");
    }
}
