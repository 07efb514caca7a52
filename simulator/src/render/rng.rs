//! Counter-based hashing RNG: every random number is a pure function of its key, so pixels can
//! be rendered in any order on any number of threads and still come out bit-identical.

/// SplitMix64 finaliser: a bijective 64-bit mix with good avalanche.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A 64-bit hash of up to three counters under a seed.
#[inline]
pub fn hash3(seed: u64, a: u64, b: u64, c: u64) -> u64 {
    let h = mix64(seed ^ 0x9e37_79b9_7f4a_7c15);
    let h = mix64(h ^ a.wrapping_mul(0xd6e8_feb8_6659_fd93));
    let h = mix64(h ^ b.wrapping_mul(0xa076_1d64_78bd_642f));
    mix64(h ^ c.wrapping_mul(0xe703_7ed1_a0b4_28db))
}

/// Uniform in [0, 1) from the top 24 bits of a hash (exact in f32).
#[inline]
pub fn unit_f32(h: u64) -> f32 {
    (h >> 40) as f32 * (1.0 / 16_777_216.0)
}

/// Entries in the Gaussian table (12 bits of a hash pick one).
pub const GAUSS_BITS: u32 = 12;

/// A standard normal deviate from the low 12 bits of `bits`: the inverse normal CDF at the
/// 4096 equiprobable strata, rescaled to unit variance (tails cut at ±3.5σ, plenty for
/// sensor noise). A table lookup is far cheaper than Box–Muller.
#[inline]
pub fn gaussian(bits: u64) -> f64 {
    gaussian_table()[(bits & ((1 << GAUSS_BITS) - 1)) as usize] as f64
}

fn gaussian_table() -> &'static [f32; 1 << GAUSS_BITS] {
    static TABLE: std::sync::OnceLock<[f32; 1 << GAUSS_BITS]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let n = 1usize << GAUSS_BITS;
        let raw: Vec<f64> = (0..n)
            .map(|k| inverse_normal_cdf((k as f64 + 0.5) / n as f64))
            .collect();
        let var = raw.iter().map(|v| v * v).sum::<f64>() / n as f64;
        let scale = 1.0 / var.sqrt();
        let mut table = [0.0f32; 1 << GAUSS_BITS];
        for (t, r) in table.iter_mut().zip(&raw) {
            *t = (r * scale) as f32;
        }
        table
    })
}

/// Acklam's rational approximation of the standard normal quantile (relative error < 1.2e-9).
fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    const LOW: f64 = 0.02425;
    if p < LOW {
        tail((-2.0 * p.ln()).sqrt())
    } else if p <= 1.0 - LOW {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_has_unit_variance_and_zero_mean() {
        let n = 200_000u64;
        let (mut s1, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let g = gaussian(hash3(7, i, 0, 0) >> 20);
            s1 += g;
            s2 += g * g;
        }
        let mean = s1 / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.02, "variance {var}");
    }

    #[test]
    fn quantiles_are_right() {
        assert!(inverse_normal_cdf(0.5).abs() < 1e-9);
        assert!((inverse_normal_cdf(0.975) - 1.959_963_985).abs() < 1e-6);
        assert!((inverse_normal_cdf(0.001) + 3.090_232_306).abs() < 1e-6);
    }

    #[test]
    fn hashes_differ_by_each_counter() {
        let base = hash3(1, 2, 3, 4);
        assert_ne!(base, hash3(0, 2, 3, 4));
        assert_ne!(base, hash3(1, 3, 3, 4));
        assert_ne!(base, hash3(1, 2, 4, 4));
        assert_ne!(base, hash3(1, 2, 3, 5));
    }
}
