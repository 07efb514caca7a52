//! The simulated cameras' test pattern (`sim.frames = "pattern"`): a frame made without
//! rendering, as Micro-Manager's DemoCamera makes one, so that the frame pipeline (trigger
//! accounting, the writer, its encoding, fsync and the index) can be measured at the rig's full
//! rate. A diagonal grating with a few bits of per-pixel noise (so it compresses about as a
//! sensor's frame does) moves with every trigger, so no two frames in a row are alike.
//!
//! The grating and its noise are drawn once per camera on a plate taller than the frame; a
//! trigger's frame is cut from it at a row and column offset of its own. Cutting is a copy, as
//! a camera's frame reaches the host by DMA, so the pattern costs the pipeline under measure
//! little CPU: drawing every frame afresh took 13 % of the process's CPU at 15 Hz.

/// Bits of noise on every sample: a sensor's read and shot noise at mid-scale.
const NOISE_BITS: u32 = 4;
/// The grating's period in pixels along a row or a column (a power of two, so a frame as wide
/// as a multiple of it wraps around without a seam).
const PERIOD: usize = 256;

/// One camera's test pattern: the plate its frames are cut from.
pub struct TestPattern {
    width: usize,
    height: usize,
    /// `height + PERIOD` rows of interleaved RGB samples.
    plate: Vec<u16>,
    seed: u64,
}

impl TestPattern {
    /// The pattern of a `width × height` camera of `bit_depth` bits whose noise is seeded by
    /// `seed`.
    pub fn new(width: u32, height: u32, bit_depth: u8, seed: u64) -> Self {
        let (width, height) = (width as usize, height as usize);
        let bits = u32::from(bit_depth.clamp(1, 16));
        let max = (1u32 << bits) - 1;
        let noise_bits = NOISE_BITS.min(bits);
        let noise_mask = (1u64 << noise_bits) - 1;
        let scale = (max >> noise_bits).max(1);
        // The grating's triangle wave from 0 to `scale`, already shifted above the noise bits
        // (so base | noise stays within `max`).
        let wave: Vec<u16> = (0..PERIOD)
            .map(|t| {
                let ramp = t.min(PERIOD - t) as u32;
                ((ramp * scale / (PERIOD as u32 / 2)) << noise_bits).min(max) as u16
            })
            .collect();
        let mut plate = vec![0u16; width * (height + PERIOD) * 3];
        // xorshift64 must not start at 0.
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let per_step = (64 / noise_bits) as usize;
        for (y, row) in plate.chunks_exact_mut(width.max(1) * 3).enumerate() {
            // The grating: red and green at the wave, blue at half of it.
            for (x, rgb) in row.chunks_exact_mut(3).enumerate() {
                let base = wave[(x + y) % PERIOD];
                rgb.copy_from_slice(&[base, base, base >> 1]);
            }
            // The noise in the low bits: one xorshift64 step gives `per_step` samples of it.
            for chunk in row.chunks_mut(per_step) {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let mut bits = state;
                for v in chunk {
                    *v |= (bits & noise_mask) as u16;
                    bits >>= noise_bits;
                }
            }
        }
        Self {
            width,
            height,
            plate,
            seed,
        }
    }

    /// The frame for `trigger_id`: `width × height` RGB samples, interleaved, each within the
    /// bit depth; rows from the plate's row offset of the trigger, each turned by its column
    /// offset.
    pub fn frame(&self, trigger_id: u64) -> Vec<u16> {
        let stride = self.width * 3;
        let mut out = Vec::with_capacity(stride * self.height);
        if stride == 0 {
            return out;
        }
        let mix = trigger_id.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ self.seed;
        let row0 = (trigger_id.wrapping_mul(7).wrapping_add(self.seed) % PERIOD as u64) as usize;
        let turn = ((mix >> 32) % self.width as u64) as usize * 3;
        for row in self.plate[row0 * stride..]
            .chunks_exact(stride)
            .take(self.height)
        {
            out.extend_from_slice(&row[turn..]);
            out.extend_from_slice(&row[..turn]);
        }
        out
    }
}

/// The frame for `trigger_id` of the camera whose noise is seeded by `seed` (see
/// [`TestPattern`], which keeps the plate for a camera's many frames).
pub fn test_pattern(
    width: u32,
    height: u32,
    bit_depth: u8,
    seed: u64,
    trigger_id: u64,
) -> Vec<u16> {
    TestPattern::new(width, height, bit_depth, seed).frame(trigger_id)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pattern_fits_the_bit_depth_and_changes_with_every_trigger_and_camera() {
        for bit_depth in [8u8, 12, 16] {
            let a = test_pattern(64, 48, bit_depth, 0, 1001);
            assert_eq!(a.len(), 64 * 48 * 3);
            let max = (1u32 << bit_depth) - 1;
            assert!(a.iter().all(|v| u32::from(*v) <= max), "{bit_depth} bits");
            // Most of the range is used.
            let top = a.iter().copied().max().unwrap_or(0);
            assert!(u32::from(top) > max / 2, "{bit_depth}: top {top}");
            assert_eq!(a, test_pattern(64, 48, bit_depth, 0, 1001), "deterministic");
            assert_ne!(a, test_pattern(64, 48, bit_depth, 0, 2001));
            assert_ne!(a, test_pattern(64, 48, bit_depth, 1, 1001));
        }
        assert!(test_pattern(0, 0, 12, 0, 1).is_empty());
        let one_bit = test_pattern(4, 4, 1, 0, 1);
        assert!(one_bit.iter().all(|v| *v <= 1));
    }

    #[test]
    fn a_cameras_frames_in_a_row_all_differ_and_a_wide_frame_has_no_seam() {
        let pattern = TestPattern::new(512, 8, 16, 5);
        // A capture's trigger ids step by 1000: a run's consecutive frames.
        let frames: Vec<Vec<u16>> = (1..=64).map(|s| pattern.frame(s * 1000)).collect();
        for (i, a) in frames.iter().enumerate() {
            for b in &frames[i + 1..] {
                assert_ne!(a, b);
            }
        }
        // A row turned by its column offset continues the grating across the wrap: the wave
        // (noise masked off) of neighbouring pixels differs by one step of the ramp at most
        // (4,095 / 128 levels), everywhere.
        let wave = |v: u16| i32::from(v >> NOISE_BITS);
        for f in &frames {
            for row in f.chunks_exact(512 * 3) {
                for x in 1..512 {
                    let (l, r) = (wave(row[3 * x - 3]), wave(row[3 * x]));
                    assert!((l - r).abs() <= 32, "seam at {x}: {l} {r}");
                }
            }
        }
    }
}
