//! The simulated cameras' test pattern (`sim.frames = "pattern"`): a frame made without
//! rendering, as Micro-Manager's DemoCamera makes one, so that the frame pipeline (trigger
//! accounting, the writer, its encoding, fsync and the index) can be measured at the rig's full
//! rate. A diagonal grating moves with every trigger, so no two frames of a camera are alike,
//! and a few bits of per-pixel noise make it compress about as a sensor's frame does.

/// Bits of noise on every sample: a sensor's read and shot noise at mid-scale.
const NOISE_BITS: u32 = 4;

/// The pattern of the frame for `trigger_id` of the camera whose noise is seeded by `seed`:
/// `width × height` RGB samples, interleaved, each within `bit_depth` bits.
pub fn test_pattern(
    width: u32,
    height: u32,
    bit_depth: u8,
    seed: u64,
    trigger_id: u64,
) -> Vec<u16> {
    let max = (1u32 << bit_depth.clamp(1, 16)) - 1;
    let noise_bits = NOISE_BITS.min(u32::from(bit_depth.clamp(1, 16)));
    let noise_mask = (1u64 << noise_bits) - 1;
    let scale = (max >> noise_bits).max(1);
    // The grating's period (a power of two), as a table of its triangle wave from 0 to
    // `scale`, already shifted above the noise bits (so base | noise stays within `max`);
    // and where the trigger moved it.
    const PERIOD: usize = 256;
    let wave: Vec<u16> = (0..PERIOD)
        .map(|t| {
            let ramp = t.min(PERIOD - t) as u32;
            ((ramp * scale / (PERIOD as u32 / 2)) << noise_bits).min(max) as u16
        })
        .collect();
    let phase = (trigger_id.wrapping_mul(7).wrapping_add(seed) % PERIOD as u64) as usize;
    let mut out = vec![0u16; width as usize * height as usize * 3];
    // xorshift64 must not start at 0.
    let mut state = (trigger_id.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ seed) | 1;
    let per_step = (64 / noise_bits) as usize;
    for (y, row) in out.chunks_exact_mut(width.max(1) as usize * 3).enumerate() {
        // The grating: red and green at the wave, blue at half of it.
        for (x, rgb) in row.chunks_exact_mut(3).enumerate() {
            let base = wave[(x + y + phase) % PERIOD];
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
    out
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
}
