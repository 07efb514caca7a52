//! Portable float maps (PFM, colour `PF`, little-endian): linear float RGB images that both
//! stagehand and Mitsuba read and write without an image library. Rows are stored bottom to
//! top; these functions take and return them top to bottom.

use std::path::Path;

use super::TradeoffError;

/// Why PFM bytes do not decode.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PfmError {
    #[error("truncated PFM header")]
    TruncatedHeader,
    #[error("not a colour PFM (magic `{0}`)")]
    NotColour(String),
    #[error("bad PFM size `{0}`")]
    BadSize(String),
    #[error("bad PFM scale `{0}`")]
    BadScale(String),
    #[error("PFM data too short: {len} bytes for {width}×{height}")]
    TooShort { len: usize, width: u32, height: u32 },
}

/// Encodes a `width` × `height` RGB image (rows top to bottom) as PFM bytes.
pub fn encode(width: u32, height: u32, rgb: &[f32]) -> Result<Vec<u8>, TradeoffError> {
    let row = width as usize * 3;
    if rgb.len() != row * height as usize {
        return Err(TradeoffError::SizeMismatch(
            row * height as usize,
            rgb.len(),
        ));
    }
    let mut out = format!("PF\n{width} {height}\n-1.0\n").into_bytes();
    out.reserve(rgb.len() * 4);
    for y in (0..height as usize).rev() {
        for v in &rgb[y * row..(y + 1) * row] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    Ok(out)
}

/// Writes an RGB image as a PFM file.
pub fn write(path: &Path, width: u32, height: u32, rgb: &[f32]) -> Result<(), TradeoffError> {
    let bytes = encode(width, height, rgb)?;
    std::fs::write(path, bytes).map_err(|e| TradeoffError::io(path, e))
}

/// Decodes PFM bytes (colour, either byte order) into (width, height, rgb top to bottom).
pub fn decode(bytes: &[u8]) -> Result<(u32, u32, Vec<f32>), PfmError> {
    // Header: three whitespace-separated tokens after "PF", then one whitespace byte.
    let mut tokens = Vec::new();
    let mut pos = 0;
    while tokens.len() < 4 {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        if start == pos {
            return Err(PfmError::TruncatedHeader);
        }
        tokens.push(String::from_utf8_lossy(&bytes[start..pos]).to_string());
    }
    pos += 1;
    if tokens[0] != "PF" {
        return Err(PfmError::NotColour(tokens[0].clone()));
    }
    let parse = |t: &str| {
        t.parse::<u32>()
            .map_err(|_| PfmError::BadSize(t.to_string()))
    };
    let (w, h) = (parse(&tokens[1])?, parse(&tokens[2])?);
    let scale: f32 = tokens[3]
        .parse()
        .map_err(|_| PfmError::BadScale(tokens[3].clone()))?;
    let row = w as usize * 3;
    let n = row * h as usize;
    let data = bytes.get(pos..).unwrap_or(&[]);
    if data.len() < n * 4 {
        return Err(PfmError::TooShort {
            len: data.len(),
            width: w,
            height: h,
        });
    }
    let mut rgb = vec![0f32; n];
    for (k, chunk) in data.chunks_exact(4).take(n).enumerate() {
        let b = [chunk[0], chunk[1], chunk[2], chunk[3]];
        let v = if scale < 0.0 {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        };
        // Stored bottom row first.
        let (y, x) = (k / row, k % row);
        rgb[(h as usize - 1 - y) * row + x] = v;
    }
    Ok((w, h, rgb))
}

/// Reads a PFM file.
pub fn read(path: &Path) -> Result<(u32, u32, Vec<f32>), TradeoffError> {
    let bytes = std::fs::read(path).map_err(|e| TradeoffError::io(path, e))?;
    decode(&bytes).map_err(|e| TradeoffError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_row_order() {
        let rgb: Vec<f32> = (0..2 * 3 * 3).map(|v| v as f32 * 0.5).collect();
        let bytes = encode(2, 3, &rgb).expect("size");
        assert!(bytes.starts_with(b"PF\n2 3\n-1.0\n"));
        // The first stored row is the bottom one (values 12..18 × 0.5).
        assert_eq!(&bytes[12..16], &6.0f32.to_le_bytes());
        assert_eq!(decode(&bytes).expect("valid"), (2, 3, rgb));
        assert!(encode(2, 2, &[0.0; 3]).is_err());
        assert!(decode(b"P6\n1 1\n255\n").is_err());
        assert!(decode(b"PF\n4 4\n-1.0\n\0\0").is_err());
    }
}
