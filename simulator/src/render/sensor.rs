//! The camera sensor: radiance to electrons, photon shot noise, full well, gain, a gently
//! non-linear response, read noise, black level, saturation and quantisation to the bit depth.

use glam::Vec3A;

use super::rng::{GAUSS_BITS, gaussian, hash3, mix64};

/// Electrons a pixel holds before it clips.
pub const FULL_WELL_E: f64 = 20_000.0;
/// Read noise in DN at 12 bits and gain 1 (scales with gain and bit depth).
pub const READ_NOISE_DN_12BIT: f64 = 3.0;
/// Dark offset as a fraction of full scale.
pub const BLACK_FRACTION: f64 = 0.02;
/// Fraction of full scale reached by white Lambert lit by the reference lamp at normal
/// incidence, exposed for `REFERENCE_EXPOSURE_S` at gain 1.
pub const REFERENCE_FILL: f64 = 0.6;
/// Exposure at which `REFERENCE_FILL` is reached.
pub const REFERENCE_EXPOSURE_S: f64 = 0.02;
/// Curvature of the response y = x·(1 − c + c·x) on the fraction of full scale x: monotone,
/// close to x^1.02 over the useful range.
pub const RESPONSE_CURVATURE: f64 = 0.03;
/// Mean electrons are capped here before shot noise is added: four full wells, so the noisy
/// value (at most 3.7σ = 3.7·√e below the mean, the Gaussian table's extreme) still clips at
/// the full well exactly as without the cap, while e + shot·√e can no longer meet ∞ − ∞ (an
/// infinite mean from an enormous exposure would give NaN and read as 0 DN).
const MAX_MEAN_ELECTRONS: f32 = 4.0 * FULL_WELL_E as f32;
/// Largest gain applied: far beyond any camera (the rigs allow 16), and beyond it the frame
/// is no different — every lit pixel saturates and read noise already spans thousands of full
/// scales — while every product below stays finite in f32.
const MAX_GAIN: f64 = 1.0e6;

/// Largest digital number at `bit_depth`.
pub fn max_dn(bit_depth: u8) -> f64 {
    ((1u64 << bit_depth.min(16)) - 1) as f64
}

/// Black level in DN (2% of full scale, rounded) at `bit_depth`.
pub fn black_level_dn(bit_depth: u8) -> f64 {
    (BLACK_FRACTION * max_dn(bit_depth)).round()
}

/// The sensor's response per channel: the fraction of full scale y a fraction of the full
/// well x gives, before black level and read noise. Monotone with y(0) = 0 and y(1) = 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Response {
    /// y = x(1 − c + c·x) with curvature c per channel: close to linear, as a scientific
    /// camera (c = [`RESPONSE_CURVATURE`] on every channel by default).
    Gentle([f32; 3]),
    /// y = x^(1/γ) per channel: the strongly non-linear response of an 8-bit consumer camera
    /// (the seed's rig), which HDR assembly must invert.
    Gamma([f32; 3]),
}

impl Default for Response {
    fn default() -> Self {
        Response::Gentle([RESPONSE_CURVATURE as f32; 3])
    }
}

impl Response {
    /// y for fraction of full well `x` in [0, 1] on channel `c`.
    #[inline]
    pub fn apply(&self, c: usize, x: f32) -> f32 {
        match self {
            Response::Gentle(k) => x * (1.0 - k[c] + k[c] * x),
            Response::Gamma(g) => x.max(0.0).powf(1.0 / g[c]),
        }
    }

    /// [`Self::apply`] on the three channels at once: the same arithmetic lane by lane, so
    /// the same values bit for bit.
    #[inline]
    fn apply_rgb(&self, x: Vec3A) -> Vec3A {
        match self {
            Response::Gentle(k) => {
                let k = Vec3A::from_array(*k);
                x * ((Vec3A::ONE - k) + k * x)
            }
            Response::Gamma(_) => {
                Vec3A::new(self.apply(0, x.x), self.apply(1, x.y), self.apply(2, x.z))
            }
        }
    }

    /// x for fraction of full scale `y` in [0, 1] on channel `c` (the inverse of [`apply`]).
    ///
    /// [`apply`]: Response::apply
    pub fn invert(&self, c: usize, y: f64) -> f64 {
        let y = y.clamp(0.0, 1.0);
        match self {
            Response::Gentle(k) => {
                let k = f64::from(k[c]);
                if k.abs() < 1e-12 {
                    y
                } else {
                    (-(1.0 - k) + ((1.0 - k).powi(2) + 4.0 * k * y).sqrt()) / (2.0 * k)
                }
            }
            Response::Gamma(g) => y.powf(f64::from(g[c])),
        }
    }

    /// A one-line description for frame notes.
    pub fn describe(&self) -> String {
        match self {
            // One curvature for all channels: the wording frames always carried.
            Response::Gentle(k) if k[0] == k[1] && k[1] == k[2] => {
                format!("y = x(1 - {c} + {c}x) of full scale", c = k[0])
            }
            Response::Gentle(k) => format!(
                "y = x(1 - c + cx) of full scale, c = [{}, {}, {}]",
                k[0], k[1], k[2]
            ),
            Response::Gamma(g) => {
                format!(
                    "y = x^(1/g) of full scale, g = [{}, {}, {}]",
                    g[0], g[1], g[2]
                )
            }
        }
    }
}

/// The digital numbers of a pixel without light, per channel and read-noise draw (see
/// [`Sensor::dark_levels`]).
#[derive(Debug, Clone)]
pub struct DarkLevels(Box<[u16; 3 << GAUSS_BITS]>);

/// Conversion from scene radiance to digital numbers for one exposure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sensor {
    max_dn: f32,
    black: f32,
    electrons_per_radiance: f32,
    /// Fraction of full scale per electron (gain included).
    fraction_per_electron: f32,
    read_sigma_dn: f32,
    /// The noise seed, pre-mixed once per frame.
    key: u64,
    /// Response per channel.
    response: Response,
    /// The response at no light per channel: what every dark pixel reads before read noise.
    dark: [f32; 3],
}

impl Sensor {
    /// A sensor of `bit_depth` exposed for `exposure_s` (≤ 0 or NaN collects nothing) at
    /// `gain` (< 0 or NaN counts as 0, above `MAX_GAIN` as `MAX_GAIN`), with noise drawn from
    /// `seed`. Any finite exposure and gain, however large, give finite arithmetic: huge values
    /// saturate, never wrap to 0.
    pub fn new(bit_depth: u8, exposure_s: f64, gain: f64, seed: u64) -> Sensor {
        let max = max_dn(bit_depth);
        // White Lambert under the reference lamp has radiance 1/π.
        let per_radiance_second =
            std::f64::consts::PI * REFERENCE_FILL * FULL_WELL_E / REFERENCE_EXPOSURE_S;
        // NaN-safe: `max` returns the non-NaN operand; `as f32` turns overflow into ∞, which
        // `min` brings back to the largest finite f32 (so 0 · factor stays 0, never NaN).
        let exposure_s = exposure_s.max(0.0);
        let gain = if gain.is_nan() {
            0.0
        } else {
            gain.clamp(0.0, MAX_GAIN)
        };
        let finite = |v: f64| (v as f32).min(f32::MAX);
        Sensor {
            max_dn: max as f32,
            black: black_level_dn(bit_depth) as f32,
            electrons_per_radiance: finite(per_radiance_second * exposure_s),
            fraction_per_electron: finite(gain / FULL_WELL_E),
            read_sigma_dn: (READ_NOISE_DN_12BIT * gain * max / 4095.0) as f32,
            key: hash3(seed, 0x5e45_0e00, 0, 0),
            response: Response::default(),
            dark: [0.0; 3],
        }
        .with_response(Response::default())
    }

    /// The same sensor with `response` instead of the default gentle curve.
    pub fn with_response(self, response: Response) -> Sensor {
        let dark = [0, 1, 2].map(|c| response.apply(c, 0.0));
        Sensor {
            response,
            dark,
            ..self
        }
    }

    /// Black level in DN.
    pub fn black_dn(&self) -> f64 {
        self.black as f64
    }

    /// The 64 bits pixel `pixel`'s shot noise is drawn from and the 64 its read noise is
    /// drawn from (12 a channel), the second a hash of the first. Changing either changes
    /// every frame's noise (and whether the calibration tests keep their marginal camera).
    #[inline]
    fn noise_bits(&self, pixel: u64) -> (u64, u64) {
        let shot = mix64(self.key ^ pixel.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        (shot, mix64(shot ^ 0x27d4_eb2f_1656_67c5))
    }

    /// The digital numbers of pixel `pixel` for RGB `radiance`. The noise is a pure function
    /// of (seed, pixel, channel): two 64-bit hashes per pixel, 12 bits per Gaussian draw.
    #[inline]
    pub fn digitise_rgb(&self, radiance: [f32; 3], pixel: u64) -> [u16; 3] {
        let (shot_bits, read_bits) = self.noise_bits(pixel);
        let mut out = [0u16; 3];
        if radiance == [0.0; 3] {
            // No light (most of a laser frame): no shot noise and the response at zero,
            // exactly what the general path computes for it.
            for (c, o) in out.iter_mut().enumerate() {
                let read = gaussian(read_bits >> (GAUSS_BITS * c as u32)) as f32;
                *o = self.dn(self.dark[c], read);
            }
            return out;
        }
        let draws = |bits: u64| {
            let draw = |c: u32| gaussian(bits >> (GAUSS_BITS * c)) as f32;
            Vec3A::new(draw(0), draw(1), draw(2))
        };
        self.digitise_lit(
            Vec3A::from_array(radiance),
            draws(shot_bits),
            draws(read_bits),
        )
    }

    /// Every digital number a pixel without light can read, per channel and read-noise draw,
    /// for [`Self::digitise_rgb_with`]: built once per frame (12,288 values).
    pub fn dark_levels(&self) -> DarkLevels {
        let draws = 1usize << GAUSS_BITS;
        let mut dn = Box::new([0u16; 3 << GAUSS_BITS]);
        for (c, levels) in dn.chunks_exact_mut(draws).enumerate() {
            for (k, level) in levels.iter_mut().enumerate() {
                *level = self.dn(self.dark[c], gaussian(k as u64) as f32);
            }
        }
        DarkLevels(dn)
    }

    /// [`Self::digitise_rgb`], with a dark pixel (most of a laser frame) read from `dark`, this
    /// sensor's [`Self::dark_levels`]: the same numbers, without the arithmetic.
    #[inline]
    pub fn digitise_rgb_with(&self, dark: &DarkLevels, radiance: [f32; 3], pixel: u64) -> [u16; 3] {
        if radiance != [0.0; 3] {
            return self.digitise_rgb(radiance, pixel);
        }
        let (_, read_bits) = self.noise_bits(pixel);
        let draws = 1usize << GAUSS_BITS;
        let draw = |c: usize| (read_bits >> (GAUSS_BITS as usize * c)) as usize & (draws - 1);
        [
            dark.0[draw(0)],
            dark.0[draws + draw(1)],
            dark.0[2 * draws + draw(2)],
        ]
    }

    /// The digital number for `radiance` at channel `channel` (0..3) of pixel `pixel`: the
    /// value `digitise_rgb` produces for that channel.
    pub fn digitise(&self, radiance: f32, pixel: u64, channel: u64) -> u16 {
        let mut rgb = [0.0; 3];
        rgb[(channel % 3) as usize] = radiance;
        self.digitise_rgb(rgb, pixel)[(channel % 3) as usize]
    }

    /// The three channels from their mean radiance and two standard normal deviates each
    /// (shot and read noise), computed on all three lanes at once.
    #[inline]
    fn digitise_lit(&self, radiance: Vec3A, shot: Vec3A, read: Vec3A) -> [u16; 3] {
        // NaN electrons become 0 (`max` takes its second operand then); ∞ becomes the cap.
        let e = (radiance * self.electrons_per_radiance)
            .max(Vec3A::ZERO)
            .min(Vec3A::splat(MAX_MEAN_ELECTRONS));
        let e = (e + shot * e.sqrt())
            .max(Vec3A::ZERO)
            .min(Vec3A::splat(FULL_WELL_E as f32));
        // Gain can take x past 1; the response then extrapolates and the DN clips below.
        let x = e * self.fraction_per_electron;
        let y = Vec3A::select(
            x.cmple(Vec3A::ONE),
            self.response.apply_rgb(x),
            Vec3A::ONE + (x - Vec3A::ONE),
        );
        let dn = y * self.max_dn + Vec3A::splat(self.black) + read * self.read_sigma_dn;
        // Round half up without a libm call: the clamped value is non-negative.
        let dn = dn.max(Vec3A::ZERO).min(Vec3A::splat(self.max_dn)) + Vec3A::splat(0.5);
        [dn.x as u16, dn.y as u16, dn.z as u16]
    }

    /// Channel `c` from its mean radiance and two standard normal deviates, one channel at
    /// a time: the arithmetic [`Self::digitise_lit`] must reproduce (tests).
    #[cfg(test)]
    fn digitise_with(&self, c: usize, radiance: f32, shot: f32, read: f32) -> u16 {
        // `max` maps NaN to 0 (`clamp` would keep it); ∞ becomes the cap.
        let e = (radiance * self.electrons_per_radiance).max(0.0);
        let e = e.min(MAX_MEAN_ELECTRONS);
        let e = (e + shot * e.sqrt()).clamp(0.0, FULL_WELL_E as f32);
        let x = e * self.fraction_per_electron;
        let y = if x <= 1.0 {
            self.response.apply(c, x)
        } else {
            1.0 + (x - 1.0)
        };
        self.dn(y, read)
    }

    /// The digital number for response `y` (fraction of full scale) and a standard normal
    /// read-noise deviate.
    #[inline]
    fn dn(&self, y: f32, read: f32) -> u16 {
        let dn = y * self.max_dn + self.black + read * self.read_sigma_dn;
        // Round half up without a libm call: the clamped value is non-negative.
        (dn.clamp(0.0, self.max_dn) + 0.5) as u16
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sensors of several bit depths, exposures, gains and responses, up to the extremes.
    fn sensors() -> [Sensor; 5] {
        [
            Sensor::new(12, 0.02, 1.0, 1),
            Sensor::new(16, 0.01, 4.0, 9),
            Sensor::new(8, 0.03, 0.5, 3).with_response(Response::Gamma([2.2, 2.0, 1.8])),
            Sensor::new(12, 10.0, 16.0, 5).with_response(Response::Gentle([0.0, 0.03, 0.5])),
            Sensor::new(10, 1.0e30, 1.0e6, 7),
        ]
    }

    /// The dark levels give every pixel, lit or not, the numbers the arithmetic gives, at
    /// several bit depths, gains and responses.
    #[test]
    fn dark_levels_read_as_the_arithmetic_does() {
        for s in sensors() {
            let dark = s.dark_levels();
            for p in 0..20_000u64 {
                for rgb in [[0.0; 3], [0.1, 0.0, 0.0], [0.3, 0.2, 0.1]] {
                    assert_eq!(s.digitise_rgb_with(&dark, rgb, p), s.digitise_rgb(rgb, p));
                }
            }
        }
    }

    /// The three lanes at once give what one channel at a time gives, bit for bit: dark,
    /// dim, saturating, past full well at high gain, negative, NaN and infinite radiance,
    /// every response, bit depth and gain, over every noise draw.
    #[test]
    fn the_lanes_digitise_as_one_channel_at_a_time() {
        let radiances = [
            0.0,
            -0.0,
            1.0e-9,
            1.0e-3,
            0.05,
            std::f32::consts::FRAC_1_PI,
            0.9,
            3.0,
            1.0e6,
            -0.2,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        for s in sensors() {
            for (i, &r0) in radiances.iter().enumerate() {
                let rgb = [
                    r0,
                    radiances[(i + 3) % radiances.len()],
                    radiances[(i + 7) % radiances.len()],
                ];
                for k in 0..(1u64 << GAUSS_BITS) {
                    let (shot_bits, read_bits) = (
                        k | k << 12 | k << 24,
                        (k ^ 0xabc) | k << 12 | (k ^ 0x555) << 24,
                    );
                    let draw =
                        |bits: u64, c: usize| gaussian(bits >> (GAUSS_BITS * c as u32)) as f32;
                    let lanes = s.digitise_lit(
                        Vec3A::from_array(rgb),
                        Vec3A::new(draw(shot_bits, 0), draw(shot_bits, 1), draw(shot_bits, 2)),
                        Vec3A::new(draw(read_bits, 0), draw(read_bits, 1), draw(read_bits, 2)),
                    );
                    let one_by_one = [0, 1, 2].map(|c| {
                        s.digitise_with(c, rgb[c], draw(shot_bits, c), draw(read_bits, c))
                    });
                    assert_eq!(lanes, one_by_one, "{s:?}, radiance {rgb:?}, draw {k}");
                }
            }
        }
    }

    /// Shot and read noise, the second drawn from a hash of the first, are uncorrelated on
    /// every channel.
    #[test]
    fn shot_and_read_noise_are_uncorrelated() {
        let s = Sensor::new(12, 0.02, 1.0, 11);
        let n = 100_000u64;
        for c in 0..3u32 {
            let shift = GAUSS_BITS * c;
            let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
            for p in 0..n {
                let (shot, read) = s.noise_bits(p);
                let (x, y) = (gaussian(shot >> shift), gaussian(read >> shift));
                sxy += x * y;
                sxx += x * x;
                syy += y * y;
            }
            let r = sxy / (sxx * syy).sqrt();
            assert!(r.abs() < 0.01, "channel {c}: correlation {r}");
        }
    }

    #[test]
    fn reference_lamp_on_white_fills_sixty_percent() {
        let s = Sensor::new(12, 0.02, 1.0, 1);
        let n = 4000u64;
        let mean = (0..n)
            .map(|p| s.digitise(std::f32::consts::FRAC_1_PI, p, 0) as f64)
            .sum::<f64>()
            / n as f64;
        let fill = (mean - s.black_dn()) / 4095.0;
        assert!((fill - 0.6).abs() < 0.02, "fill {fill}");
    }

    #[test]
    fn saturates_at_the_bit_depth_maximum() {
        for bits in [8u8, 12, 16] {
            let s = Sensor::new(bits, 10.0, 4.0, 3);
            let v = (0..100).map(|p| s.digitise(1.0, p, 1)).collect::<Vec<_>>();
            assert!(
                v.iter().all(|&d| d as f64 == max_dn(bits)),
                "{bits} bits: {v:?}"
            );
        }
    }

    /// An exposure too large for f32 used to make the mean electrons infinite and a gain too
    /// large made the response and read noise infinite; ∞ − ∞ then turned about half the
    /// saturated pixels into 0 DN.
    #[test]
    fn enormous_exposure_or_gain_saturates_instead_of_reading_zero() {
        for (exposure, gain) in [(f64::MAX, 1.0), (1.0, 1e300), (1e40, 1e40)] {
            let s = Sensor::new(12, exposure, gain, 3);
            for p in 0..1000 {
                assert_eq!(
                    s.digitise(0.01, p, 0),
                    4095,
                    "{exposure:e} {gain:e} pixel {p}"
                );
            }
        }
        let dark = Sensor::new(12, 0.0, 1e300, 3);
        assert!((0..1000).all(|p| dark.digitise(f32::INFINITY, p, 1) <= 4095));
    }

    #[test]
    fn no_exposure_gives_black_level_plus_read_noise() {
        let s = Sensor::new(12, 0.0, 1.0, 9);
        let v: Vec<f64> = (0..5000).map(|p| s.digitise(100.0, p, 2) as f64).collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / v.len() as f64;
        assert!((mean - 82.0).abs() < 0.2, "mean {mean}");
        assert!((var.sqrt() - 3.0).abs() < 0.3, "read noise {}", var.sqrt());
    }

    #[test]
    fn responses_invert_and_are_monotone_per_channel() {
        for r in [
            Response::default(),
            Response::Gentle([0.0, 0.05, 0.1]),
            Response::Gamma([2.2, 2.0, 2.4]),
        ] {
            for c in 0..3 {
                let mut last = -1.0f32;
                for k in 0..=1000 {
                    let x = k as f32 / 1000.0;
                    let y = r.apply(c, x);
                    assert!(y > last || (k == 0 && y == 0.0), "{r:?} channel {c} at {x}");
                    last = y;
                    let back = r.invert(c, f64::from(y));
                    assert!(
                        (back - f64::from(x)).abs() < 1e-4,
                        "{r:?} {c}: {x} -> {back}"
                    );
                }
                assert!((r.apply(c, 1.0) - 1.0).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn a_gamma_sensor_reads_mid_grey_far_above_a_linear_one() {
        let linear = Sensor::new(8, 0.02, 1.0, 5);
        let gamma = linear.with_response(Response::Gamma([2.2; 3]));
        let radiance = 0.18 * std::f32::consts::FRAC_1_PI;
        let mean = |s: &Sensor| {
            (0..2000)
                .map(|p| f64::from(s.digitise(radiance, p, 1)))
                .sum::<f64>()
                / 2000.0
        };
        assert!(
            mean(&gamma) > 1.8 * mean(&linear),
            "{} vs {}",
            mean(&gamma),
            mean(&linear)
        );
    }

    #[test]
    fn response_is_monotone() {
        let s = Sensor::new(12, 0.02, 1.0, 0);
        let mut last = 0.0;
        for k in 0..=1000 {
            let x = k as f64 / 1000.0 * 1.2;
            let y = x * (1.0 - RESPONSE_CURVATURE + RESPONSE_CURVATURE * x);
            assert!(y >= last);
            last = y;
        }
        assert_eq!(s.black_dn(), 82.0);
    }
}
