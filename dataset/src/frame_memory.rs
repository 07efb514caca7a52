//! How the process's allocator treats frame buffers. A 1024×768 16-bit RGB frame is 4.7 MB;
//! at the rig's rates some sixty are made and freed a second. Left to glibc's defaults, each
//! freed buffer went back to the kernel and the next was faulted in again, page by page
//! (60,000 page faults a second at 7.5 Hz, a third of a core in the kernel, and the capture
//! loop's worst intervals with them: `cargo bench --bench frame_pipeline`). Kept in the
//! allocator, the next frame reuses them.

/// Largest allocation glibc serves from its heaps rather than a fresh mapping: its maximum on
/// 64-bit (32 MiB), above any frame of the built-in rigs.
const MMAP_THRESHOLD_BYTES: i32 = 32 << 20;

/// Free memory glibc keeps at a heap's top before returning it to the kernel: half the
/// writer's 512 MiB frame budget, so the frames in flight are recycled, not refaulted.
const TRIM_THRESHOLD_BYTES: i32 = 256 << 20;

/// Asks the allocator to keep freed frame buffers for the next frames. Call once, first thing
/// in `main`, before other threads start; nothing happens where the C library is not glibc.
/// Returns whether both settings took.
#[allow(unsafe_code)]
pub fn keep_frame_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: `mallopt` only sets allocator parameters; called before other threads
        // allocate, as its documentation asks.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On this glibc target both settings are accepted (mallopt returns 1), and a frame-sized
    /// buffer freed and made again keeps working memory.
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_accepts_both_settings() {
        assert!(keep_frame_memory());
        let frame = vec![1u16; 1024 * 768 * 3];
        assert_eq!(frame.iter().map(|&v| v as u64).sum::<u64>(), 1024 * 768 * 3);
    }
}
