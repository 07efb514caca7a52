//! File checksums: hex SHA-256, as stored in `frames.sha256`.

use std::io::Read;
use std::path::Path;

use sha2::{Digest, Sha256};

/// Lower-case hex SHA-256 of `bytes` (64 characters, as `sha256sum` prints it).
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

/// Bytes read (and hashed) at a time by [`read_hashed`]: small enough to stay in cache
/// between the read and the hash.
const CHUNK: usize = 256 << 10;

/// Reads the file at `path` and its hex SHA-256 in one pass, hashing each chunk as it is read
/// (so a large frame is hashed while it is in cache, not re-read from memory afterwards).
/// `size_hint` (the recorded size) sizes the buffer. Readers keep the bytes to decode them.
pub fn read_hashed(path: &Path, size_hint: u64) -> std::io::Result<(Vec<u8>, String)> {
    let mut file = std::fs::File::open(path)?;
    let mut bytes = Vec::with_capacity(usize::try_from(size_hint).unwrap_or(0));
    let mut hasher = Sha256::new();
    loop {
        let start = bytes.len();
        let n = (&mut file).take(CHUNK as u64).read_to_end(&mut bytes)?;
        if n == 0 {
            break;
        }
        hasher.update(&bytes[start..]);
    }
    Ok((bytes, hex(&hasher.finalize())))
}

/// Lower-case hex of a digest.
fn hex(digest: &[u8]) -> String {
    let mut hex = String::with_capacity(64);
    for b in digest.iter() {
        hex.push(char::from(HEX[usize::from(b >> 4)]));
        hex.push(char::from(HEX[usize::from(b & 0x0f)]));
    }
    hex
}

const HEX: &[u8; 16] = b"0123456789abcdef";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_digest() {
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn chunked_reads_hash_like_the_whole() -> std::io::Result<()> {
        let tmp = tempfile::tempdir()?;
        let path = tmp.path().join("f");
        // More than two chunks, not a multiple of the chunk size.
        let data: Vec<u8> = (0..(2 * CHUNK + 12_345))
            .map(|i| (i * 7 % 251) as u8)
            .collect();
        std::fs::write(&path, &data)?;
        for hint in [0, 10, data.len() as u64] {
            let (bytes, hash) = read_hashed(&path, hint)?;
            assert_eq!(bytes, data);
            assert_eq!(hash, sha256_hex(&data));
        }
        Ok(())
    }
}
