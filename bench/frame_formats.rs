//! What a raw frame costs to store, per format (issue 16: choose the frame format by
//! measurement): 1024×768 16-bit frames of the simulated cameras' test pattern (a moving
//! grating with 4 bits of sensor-like noise), or a run's own frames (a run directory among
//! the arguments: a laser sweep's frames are mostly dark, at the camera's bit depth), each
//! encoded on one core as the dataset's PNG (`encode_png16`: the fastest deflate and the Up
//! filter, with its sBIT and metadata), the dataset's stored PNG (what a writer behind the
//! cameras writes every other frame as), PNG with the fastest deflate (fdeflate) and each
//! filter, with zlib's level 1, with zlib-rs (zlib-ng's port) at its fast levels and
//! Huffman-only and RLE strategies, stored PNG (no compression), and the raw big-endian samples;
//! then its SHA-256 and one durable write (write, fsync) of each result to the scratch disk.
//! Prints one JSON object per format with the time per frame, the size against raw, and the
//! frames per second that 8 cameras could reach on 2 cores if encoding were all they did.
//!
//! Then the same for HDR frames (f32 RGB OpenEXR, what a bracket merges into): a bracket of
//! three test patterns (5, 20 and 80 ms) merged with hat weights into DN per second, encoded
//! with each lossless OpenEXR compression.
//!
//! Run: `cargo bench --bench frame_formats [-- FRAMES [RUN_DIR] [NAME…]]` (default 24 frames
//! per format; with NAMEs, only the formats whose name contains one of them).

use std::io::Write;
use std::time::Instant;

use sha2::{Digest, Sha256};
use stagehand_dataset::exr_hdr::{Compression, encode_exr_with};
use stagehand_dataset::png16::{Deflate, encode_png16, encode_png16_with};
use stagehand_simulator::sim_devices::test_pattern;

/// Encodes one frame `F` into a file's bytes.
type Encoder<F> = Box<dyn Fn(&F) -> Vec<u8>>;

const WIDTH: u32 = 1024;
const HEIGHT: u32 = 768;

/// A raw frame: the sensor's digital numbers and its bit depth.
struct Raw {
    dn: Vec<u16>,
    bits: u8,
}

impl Raw {
    /// The samples as a PNG stores them: MSB-aligned to 16 bits.
    fn aligned(&self) -> Vec<u8> {
        let shift = 16 - u32::from(self.bits.min(16));
        self.dn
            .iter()
            .flat_map(|v| (v << shift).to_be_bytes())
            .collect()
    }
}

/// The frame's samples as a 16-bit PNG with `compression` and `filter`.
fn png(frame: &Raw, compression: png::DeflateCompression, filter: png::Filter) -> Vec<u8> {
    let data = frame.aligned();
    let mut out = Vec::with_capacity(data.len() + 4096);
    let mut encoder = png::Encoder::new(&mut out, WIDTH, HEIGHT);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Sixteen);
    encoder.set_deflate_compression(compression);
    encoder.set_filter(filter);
    let mut writer = encoder.write_header().expect("header");
    writer.write_image_data(&data).expect("data");
    writer.finish().expect("finish");
    out
}

/// The frame's samples as a 16-bit PNG, Up filter, its image data compressed by zlib-rs
/// with `config`.
fn png_zlib_rs(frame: &Raw, config: zlib_rs::DeflateConfig) -> Vec<u8> {
    let data = frame.aligned();
    let row = WIDTH as usize * 6;
    let mut filtered = Vec::with_capacity(data.len() + HEIGHT as usize);
    for (y, line) in data.chunks_exact(row).enumerate() {
        filtered.push(2u8);
        if y == 0 {
            filtered.extend_from_slice(line);
        } else {
            let above = &data[(y - 1) * row..y * row];
            filtered.extend(line.iter().zip(above).map(|(a, b)| a.wrapping_sub(*b)));
        }
    }
    let mut buf = vec![0u8; zlib_rs::compress_bound(filtered.len())];
    let (z, rc) = zlib_rs::compress_slice(&mut buf, &filtered, config);
    assert_eq!(rc, zlib_rs::ReturnCode::Ok);
    let mut out = Vec::with_capacity(z.len() + 4096);
    let mut encoder = png::Encoder::new(&mut out, WIDTH, HEIGHT);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Sixteen);
    let mut writer = encoder.write_header().expect("header");
    writer.write_chunk(png::chunk::IDAT, z).expect("idat");
    writer.finish().expect("finish");
    out
}

/// Up to `n` frames of the run directory `dir`'s `frames/` (a real capture's raw frames: a
/// laser sweep's are mostly dark, at the camera's bit depth), each 1024×768.
fn frames_of_run(dir: &std::path::Path, n: usize) -> Vec<Raw> {
    let mut paths: Vec<_> = std::fs::read_dir(dir.join("frames"))
        .expect("a run directory with frames/")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .collect();
    paths.sort();
    paths
        .iter()
        .take(n)
        .map(|p| {
            let bytes = std::fs::read(p).expect("read frame");
            let d = stagehand_dataset::png16::decode_png16("bench", &bytes).expect("decode");
            assert_eq!((d.width, d.height), (WIDTH, HEIGHT), "{}", p.display());
            Raw {
                dn: d.pixels,
                bits: d.significant_bits,
            }
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let frames: usize = args.iter().find_map(|a| a.parse().ok()).unwrap_or(24);
    // A run directory among the arguments: its frames instead of the test pattern.
    let run = args
        .iter()
        .map(std::path::Path::new)
        .find(|p| p.join("frames").is_dir());
    // Any other argument selects formats by a part of their name.
    let only: Vec<&str> = args
        .iter()
        .filter(|a| a.parse::<usize>().is_err() && Some(std::path::Path::new(a)) != run)
        .map(String::as_str)
        .collect();
    let patterns: Vec<Raw> = match run {
        Some(dir) => frames_of_run(dir, frames),
        None => (0..frames as u64)
            .map(|t| Raw {
                dn: test_pattern(WIDTH, HEIGHT, 16, 7, 1000 * (t + 1)),
                bits: 16,
            })
            .collect(),
    };
    let raw_bytes = (WIDTH * HEIGHT * 3 * 2) as f64;
    let fdeflate = png::DeflateCompression::FdeflateUltraFast;
    let zlib1 = png::DeflateCompression::Level(1);
    let stored = png::DeflateCompression::NoCompression;
    let mut formats: Vec<(&str, Encoder<Raw>)> = vec![
        (
            "png16 as the dataset stores it",
            Box::new(|f| encode_png16("bench", WIDTH, HEIGHT, &f.dn, f.bits, "{}").expect("png16")),
        ),
        (
            "png16 stored, as the dataset stores every other frame when behind",
            Box::new(|f| {
                encode_png16_with("bench", WIDTH, HEIGHT, &f.dn, f.bits, "{}", Deflate::Stored)
                    .expect("png16")
            }),
        ),
        ("raw big-endian samples", Box::new(Raw::aligned)),
    ];
    // The png crate's fastest deflate is fdeflate; its levels are zlib's (flate2).
    let variants = [
        ("png fastest deflate, Up filter", fdeflate, png::Filter::Up),
        (
            "png fastest deflate, no filter",
            fdeflate,
            png::Filter::NoFilter,
        ),
        (
            "png fastest deflate, Sub filter",
            fdeflate,
            png::Filter::Sub,
        ),
        (
            "png fastest deflate, adaptive",
            fdeflate,
            png::Filter::Adaptive,
        ),
        ("png zlib level 1, no filter", zlib1, png::Filter::NoFilter),
        ("png zlib level 1, Up filter", zlib1, png::Filter::Up),
        ("png stored (no compression)", stored, png::Filter::NoFilter),
    ];
    for (name, level, strategy) in [
        (
            "png zlib-rs Huffman only, Up filter",
            1,
            zlib_rs::Strategy::HuffmanOnly,
        ),
        ("png zlib-rs RLE, Up filter", 1, zlib_rs::Strategy::Rle),
        (
            "png zlib-rs level 1, Up filter",
            1,
            zlib_rs::Strategy::Default,
        ),
        (
            "png zlib-rs level 2, Up filter",
            2,
            zlib_rs::Strategy::Default,
        ),
    ] {
        let config = zlib_rs::DeflateConfig {
            level,
            strategy,
            ..Default::default()
        };
        formats.push((name, Box::new(move |f| png_zlib_rs(f, config))));
    }
    formats.extend(variants.into_iter().map(|(name, compression, filter)| {
        let encode: Encoder<Raw> = Box::new(move |f| png(f, compression, filter));
        (name, encode)
    }));
    measure(&formats, &patterns, raw_bytes, &only);
    let brackets: Vec<Vec<f32>> = (0..frames as u64).map(bracket).collect();
    let exr = |compression: Compression| -> Encoder<Vec<f32>> {
        Box::new(move |p| {
            encode_exr_with("bench", WIDTH, HEIGHT, p, "{}", compression).expect("exr")
        })
    };
    let hdr_formats: Vec<(&str, Encoder<Vec<f32>>)> = vec![
        (
            "exr f32 ZIP16 (the dataset's HDR frames until 2026-12-04)",
            exr(Compression::ZIP16),
        ),
        ("exr f32 ZIP1", exr(Compression::ZIP1)),
        ("exr f32 PIZ", exr(Compression::PIZ)),
        ("exr f32 RLE", exr(Compression::RLE)),
        ("exr f32 uncompressed", exr(Compression::Uncompressed)),
    ];
    measure(&hdr_formats, &brackets, raw_bytes * 2.0, &only);
}

/// A bracket of three test patterns (5, 20, 80 ms; the pattern stands for 20 ms) merged into
/// DN per second with hat weights, as `merge_bracket` weighs them.
fn bracket(t: u64) -> Vec<f32> {
    let exposures = [0.005f32, 0.02, 0.08];
    let frames: Vec<Vec<u16>> = exposures
        .iter()
        .enumerate()
        .map(|(k, &e)| {
            let p = test_pattern(WIDTH, HEIGHT, 16, 7 + k as u64, 1000 * (t + 1));
            p.iter()
                .map(|&v| (f32::from(v) * e / 0.02).min(65535.0) as u16)
                .collect()
        })
        .collect();
    (0..frames[0].len())
        .map(|i| {
            let (mut sum, mut weight) = (0.0f32, 0.0f32);
            for (f, &e) in frames.iter().zip(&exposures) {
                let v = f32::from(f[i]);
                let w = v.min(65535.0 - v).max(1.0);
                sum += w * v / e;
                weight += w;
            }
            sum / weight
        })
        .collect()
}

/// Encodes, hashes and durably writes every frame in each of `formats`, printing one JSON
/// object per format (`raw_bytes`: the frame's uncompressed size).
fn measure<F>(formats: &[(&str, Encoder<F>)], frames_in: &[F], raw_bytes: f64, only: &[&str]) {
    let formats: Vec<_> = formats
        .iter()
        .filter(|(name, _)| only.is_empty() || only.iter().any(|o| name.contains(o)))
        .collect();
    let frames = frames_in.len();
    let scratch = tempfile::tempdir().expect("scratch");
    // Every encoder once first, so that none pays for the process's first allocations.
    for (_, encode) in &formats {
        std::hint::black_box(encode(&frames_in[0]));
    }
    for (name, encode) in &formats {
        let started = Instant::now();
        let encoded: Vec<Vec<u8>> = frames_in.iter().map(encode).collect();
        let encode_s = started.elapsed().as_secs_f64() / frames as f64;
        let started = Instant::now();
        for e in &encoded {
            std::hint::black_box(Sha256::digest(e));
        }
        let sha_s = started.elapsed().as_secs_f64() / frames as f64;
        let started = Instant::now();
        for (k, e) in encoded.iter().enumerate() {
            let path = scratch.path().join(format!("{k}.frame"));
            let mut file = std::fs::File::create(&path).expect("create");
            file.write_all(e).expect("write");
            file.sync_all().expect("fsync");
            drop(file);
            std::fs::remove_file(&path).expect("remove");
        }
        let write_s = started.elapsed().as_secs_f64() / frames as f64;
        let size = encoded.iter().map(Vec::len).sum::<usize>() as f64 / frames as f64;
        let cpu_s = encode_s + sha_s;
        println!(
            "{}",
            serde_json::json!({
                "bench": "frame_formats",
                "format": name,
                "frames": frames,
                "encode_ms": encode_s * 1e3,
                "sha256_ms": sha_s * 1e3,
                "write_fsync_ms": write_s * 1e3,
                "size_vs_raw": size / raw_bytes,
                "cpu_frames_per_s_per_core": 1.0 / cpu_s,
                "captures_per_s_8_cameras_2_cores": 2.0 / cpu_s / 8.0,
                "disk_mb_per_s_one_writer": size / 1e6 / write_s,
            })
        );
    }
}
