//! A small radix-2 complex FFT in f32 and the 2D transforms built on it, for convolving
//! per-frame texel maps with wide kernels (the subsurface pass). Deterministic: the same
//! input gives bit-identical output at any rayon thread count (rows are independent).

use std::f32::consts::TAU;

use rayon::prelude::*;

/// A complex number (re, im).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct C32 {
    /// Real part.
    pub re: f32,
    /// Imaginary part.
    pub im: f32,
}

impl C32 {
    /// re + i·im.
    #[inline]
    pub const fn new(re: f32, im: f32) -> C32 {
        C32 { re, im }
    }
    #[inline]
    fn add(self, o: C32) -> C32 {
        C32::new(self.re + o.re, self.im + o.im)
    }
    #[inline]
    fn sub(self, o: C32) -> C32 {
        C32::new(self.re - o.re, self.im - o.im)
    }
    #[inline]
    fn mul(self, o: C32) -> C32 {
        C32::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
    /// Complex conjugate.
    #[inline]
    pub fn conj(self) -> C32 {
        C32::new(self.re, -self.im)
    }
}

/// Precomputed twiddles and bit reversal for transforms of length `n` (a power of two).
#[derive(Debug, Clone)]
pub struct Fft {
    n: usize,
    twiddles: Vec<C32>,
    reversed: Vec<u32>,
}

impl Fft {
    /// A plan for length `n`, rounded up to a power of two (at least 1).
    pub fn new(n: usize) -> Fft {
        let n = n.max(1).next_power_of_two();
        let bits = n.trailing_zeros();
        let twiddles = (0..n / 2)
            .map(|k| {
                let a = -TAU * k as f32 / n as f32;
                C32::new(a.cos(), a.sin())
            })
            .collect();
        let reversed = (0..n as u32)
            .map(|i| {
                if bits == 0 {
                    0
                } else {
                    i.reverse_bits() >> (32 - bits)
                }
            })
            .collect();
        Fft {
            n,
            twiddles,
            reversed,
        }
    }

    /// Transform length.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether the length is zero (never: at least 1).
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// In-place forward (e^{−2πi kx/n}) or, with `inverse`, unnormalised inverse transform of
    /// `data` (length n).
    pub fn run(&self, data: &mut [C32], inverse: bool) {
        let n = self.n;
        if data.len() != n {
            return;
        }
        for i in 0..n {
            let j = self.reversed[i] as usize;
            if j > i {
                data.swap(i, j);
            }
        }
        let mut len = 2;
        while len <= n {
            let half = len / 2;
            let stride = n / len;
            for start in (0..n).step_by(len) {
                for k in 0..half {
                    let mut w = self.twiddles[k * stride];
                    if inverse {
                        w = w.conj();
                    }
                    let a = data[start + k];
                    let b = data[start + k + half].mul(w);
                    data[start + k] = a.add(b);
                    data[start + k + half] = a.sub(b);
                }
            }
            len *= 2;
        }
    }

    /// 2D transform of the n × n row-major `data`, rows then columns. The result is stored
    /// transposed (index kx·n + ky); applying the inverse to it restores the original layout,
    /// scaled by n². Element-wise products of two spectra are layout-independent.
    pub fn run_2d(&self, data: &mut Vec<C32>, inverse: bool) {
        let n = self.n;
        if data.len() != n * n {
            return;
        }
        data.par_chunks_mut(n)
            .for_each(|row| self.run(row, inverse));
        transpose(data, n);
        data.par_chunks_mut(n)
            .for_each(|row| self.run(row, inverse));
    }
}

/// Transposes the n × n row-major matrix in `data` (through a scratch copy).
fn transpose(data: &mut Vec<C32>, n: usize) {
    let src = std::mem::take(data);
    let mut dst = vec![C32::default(); n * n];
    dst.par_chunks_mut(n).enumerate().for_each(|(r, row)| {
        for (c, v) in row.iter_mut().enumerate() {
            *v = src[c * n + r];
        }
    });
    *data = dst;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct DFT for comparison.
    fn dft(x: &[C32]) -> Vec<C32> {
        let n = x.len();
        (0..n)
            .map(|k| {
                let mut s = (0.0f64, 0.0f64);
                for (j, v) in x.iter().enumerate() {
                    let a = -std::f64::consts::TAU * (k * j) as f64 / n as f64;
                    let (c, si) = (a.cos(), a.sin());
                    s.0 += v.re as f64 * c - v.im as f64 * si;
                    s.1 += v.re as f64 * si + v.im as f64 * c;
                }
                C32::new(s.0 as f32, s.1 as f32)
            })
            .collect()
    }

    #[test]
    fn matches_the_direct_dft_and_inverts() {
        for n in [1usize, 2, 8, 64] {
            let fft = Fft::new(n);
            let x: Vec<C32> = (0..n)
                .map(|k| C32::new((k as f32 * 0.7).sin(), (k as f32 * 0.3).cos()))
                .collect();
            let mut y = x.clone();
            fft.run(&mut y, false);
            for (a, b) in y.iter().zip(dft(&x)) {
                assert!((a.re - b.re).abs() < 1e-4 && (a.im - b.im).abs() < 1e-4);
            }
            fft.run(&mut y, true);
            for (a, b) in y.iter().zip(&x) {
                assert!((a.re / n as f32 - b.re).abs() < 1e-5);
                assert!((a.im / n as f32 - b.im).abs() < 1e-5);
            }
        }
        let fft = Fft::new(16);
        let x: Vec<C32> = (0..256).map(|k| C32::new((k % 7) as f32, 0.0)).collect();
        let mut y = x.clone();
        fft.run_2d(&mut y, false);
        // DC term is the sum.
        let sum: f32 = x.iter().map(|v| v.re).sum();
        assert!((y[0].re - sum).abs() < 1e-3);
        fft.run_2d(&mut y, true);
        for (a, b) in y.iter().zip(&x) {
            assert!((a.re / 256.0 - b.re).abs() < 1e-4);
        }
        assert_eq!(Fft::new(5).len(), 8);
    }
}
