//! What a raw frame costs to store, per format (issue 16: choose the frame format by
//! measurement): one 1024×768 16-bit frame of the simulated cameras' test pattern (a moving
//! grating with 4 bits of sensor-like noise) encoded on one core as the dataset's PNG
//! (`encode_png16`: the fastest deflate and the Up filter, with its sBIT and metadata), the
//! dataset's stored PNG (what a writer behind the cameras writes every other frame as), PNG
//! with fast deflate and the adaptive filter (the dataset's format before), with fast deflate
//! and no filter, with the fastest deflate and the Up filter, stored PNG (no compression), and
//! the raw big-endian samples; then its SHA-256 and one durable write (write, fsync) of each result to the scratch
//! disk. Prints one JSON object per format with the time per frame, the size against raw, and
//! the frames per second that 8 cameras could reach on 2 cores if encoding were all they did.
//!
//! Then the same for HDR frames (f32 RGB OpenEXR, what a bracket merges into): a bracket of
//! three test patterns (5, 20 and 80 ms) merged with hat weights into DN per second, encoded
//! with each lossless OpenEXR compression.
//!
//! Run: `cargo bench --bench frame_formats [-- FRAMES]` (default 24 frames per format).

use std::io::Write;
use std::time::Instant;

use sha2::{Digest, Sha256};
use stagehand_dataset::exr_hdr::{Compression, encode_exr_with};
use stagehand_dataset::png16::{Deflate, encode_png16, encode_png16_with};
use stagehand_simulator::sim_devices::test_pattern;

/// Encodes one frame of samples `P` into a file's bytes.
type Encoder<P> = Box<dyn Fn(&[P]) -> Vec<u8>>;

const WIDTH: u32 = 1024;
const HEIGHT: u32 = 768;

/// The frame's samples as a 16-bit PNG with `compression` and `filter`.
fn png(pixels: &[u16], compression: png::Compression, filter: png::Filter) -> Vec<u8> {
    let data: Vec<u8> = pixels.iter().flat_map(|v| v.to_be_bytes()).collect();
    let mut out = Vec::with_capacity(data.len() + 4096);
    let mut encoder = png::Encoder::new(&mut out, WIDTH, HEIGHT);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Sixteen);
    encoder.set_compression(compression);
    encoder.set_filter(filter);
    let mut writer = encoder.write_header().expect("header");
    writer.write_image_data(&data).expect("data");
    writer.finish().expect("finish");
    out
}

fn main() {
    let frames: usize = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(24);
    let patterns: Vec<Vec<u16>> = (0..frames as u64)
        .map(|t| test_pattern(WIDTH, HEIGHT, 16, 7, 1000 * (t + 1)))
        .collect();
    let raw_bytes = (WIDTH * HEIGHT * 3 * 2) as f64;
    let formats: Vec<(&str, Encoder<u16>)> = vec![
        (
            "png16 as the dataset stores it",
            Box::new(|p| encode_png16("bench", WIDTH, HEIGHT, p, 16, "{}").expect("png16")),
        ),
        (
            "png16 stored, as the dataset stores every other frame when behind",
            Box::new(|p| {
                encode_png16_with("bench", WIDTH, HEIGHT, p, 16, "{}", Deflate::Stored)
                    .expect("png16")
            }),
        ),
        (
            "png fast deflate, adaptive filter (stored until 2026-12)",
            Box::new(|p| png(p, png::Compression::Fast, png::Filter::Adaptive)),
        ),
        (
            "png fast deflate, no filter",
            Box::new(|p| png(p, png::Compression::Fast, png::Filter::NoFilter)),
        ),
        (
            "png fastest deflate, Up filter",
            Box::new(|p| png(p, png::Compression::Fastest, png::Filter::Up)),
        ),
        (
            "png stored (no compression)",
            Box::new(|p| png(p, png::Compression::NoCompression, png::Filter::NoFilter)),
        ),
        (
            "raw big-endian samples",
            Box::new(|p| p.iter().flat_map(|v| v.to_be_bytes()).collect()),
        ),
    ];
    measure(&formats, &patterns, raw_bytes);
    let brackets: Vec<Vec<f32>> = (0..frames as u64).map(bracket).collect();
    let exr = |compression: Compression| -> Encoder<f32> {
        Box::new(move |p| {
            encode_exr_with("bench", WIDTH, HEIGHT, p, "{}", compression).expect("exr")
        })
    };
    let hdr_formats: Vec<(&str, Encoder<f32>)> = vec![
        (
            "exr f32 ZIP16 (the dataset's HDR frames until 2026-12-04)",
            exr(Compression::ZIP16),
        ),
        ("exr f32 ZIP1", exr(Compression::ZIP1)),
        ("exr f32 PIZ", exr(Compression::PIZ)),
        ("exr f32 RLE", exr(Compression::RLE)),
        ("exr f32 uncompressed", exr(Compression::Uncompressed)),
    ];
    measure(&hdr_formats, &brackets, raw_bytes * 2.0);
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
fn measure<P>(formats: &[(&str, Encoder<P>)], frames_in: &[Vec<P>], raw_bytes: f64) {
    let frames = frames_in.len();
    let scratch = tempfile::tempdir().expect("scratch");
    // Every encoder once first, so that none pays for the process's first allocations.
    for (_, encode) in formats {
        std::hint::black_box(encode(&frames_in[0]));
    }
    for (name, encode) in formats {
        let started = Instant::now();
        let encoded: Vec<Vec<u8>> = frames_in.iter().map(|p| encode(p)).collect();
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
