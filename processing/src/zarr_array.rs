//! A writer of Zarr v3 arrays (the format Python's `zarr` reads): a `zarr.json` with the
//! shape, chunk grid, data type and attributes, and one file per chunk under `c/…` holding its
//! values little-endian with no compression (the `bytes` codec). Chunks never written read back
//! as the fill value. Every file is written atomically, so an interrupted write leaves whole
//! chunks only, and rewriting a chunk (a resumed `process`) replaces it.
//!
//! Written here rather than with the `zarrs` crate: these ~100 lines cover the one layout the
//! products need, where `zarrs` would add 130 crates to every build; the tests read the arrays
//! back by the spec, and Python's `zarr` 3.1 reads them (checked when this was written:
//! shape, chunks, attributes and values).

use std::path::{Path, PathBuf};

use serde_json::{Value, json};
use stagehand_dataset::atomic::{fsync_dir, write_atomic};

use crate::error::ProcessingError;

/// Element types the writer stores.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ZarrType {
    /// IEEE 754 single precision.
    Float32,
    /// Unsigned byte.
    Uint8,
}

impl ZarrType {
    fn name(self) -> &'static str {
        match self {
            ZarrType::Float32 => "float32",
            ZarrType::Uint8 => "uint8",
        }
    }

    fn fill(self) -> Value {
        match self {
            ZarrType::Float32 => json!(0.0),
            ZarrType::Uint8 => json!(0),
        }
    }
}

/// An array being written.
#[derive(Debug, Clone, PartialEq)]
pub struct ZarrArray {
    dir: PathBuf,
    shape: Vec<u64>,
    chunk: Vec<u64>,
    dtype: ZarrType,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> ProcessingError {
    ProcessingError::Dataset {
        run: path.display().to_string(),
        message: format!("cannot write the Zarr array: {e}"),
    }
}

impl ZarrArray {
    /// Creates (or reopens, keeping its chunks) the array at `dir` with `shape`, `chunk` shape,
    /// element type, dimension names and attributes.
    pub fn create(
        dir: &Path,
        shape: &[u64],
        chunk: &[u64],
        dtype: ZarrType,
        dimension_names: &[&str],
        attributes: Value,
    ) -> Result<ZarrArray, ProcessingError> {
        let ok = shape.len() == chunk.len()
            && shape.len() == dimension_names.len()
            && chunk.iter().all(|&c| c > 0);
        if !ok {
            return Err(ProcessingError::BadParameter {
                name: "zarr chunk shape",
                value: chunk.len() as f64,
                why: "shape, chunk shape and dimension names need one entry per dimension, chunks ≥ 1",
            });
        }
        std::fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
        let meta = json!({
            "zarr_format": 3,
            "node_type": "array",
            "shape": shape,
            "data_type": dtype.name(),
            "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": chunk}},
            "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
            "fill_value": dtype.fill(),
            "codecs": [{"name": "bytes", "configuration": {"endian": "little"}}],
            "attributes": attributes,
            "dimension_names": dimension_names,
        });
        let bytes = serde_json::to_vec_pretty(&meta).map_err(|e| io_err(dir, e))?;
        write_atomic(dir, "zarr.json", &bytes).map_err(|e| io_err(dir, e))?;
        fsync_dir(dir).map_err(|e| io_err(dir, e))?;
        Ok(ZarrArray {
            dir: dir.to_path_buf(),
            shape: shape.to_vec(),
            chunk: chunk.to_vec(),
            dtype,
        })
    }

    /// Elements per chunk.
    pub fn chunk_len(&self) -> usize {
        self.chunk.iter().product::<u64>() as usize
    }

    /// The file of chunk `index` (chunk coordinates).
    pub fn chunk_path(&self, index: &[u64]) -> PathBuf {
        let mut p = self.dir.join("c");
        for i in index {
            p.push(i.to_string());
        }
        p
    }

    fn check_index(&self, index: &[u64], len: usize) -> Result<(), ProcessingError> {
        let inside = index.len() == self.shape.len()
            && index
                .iter()
                .zip(self.shape.iter().zip(&self.chunk))
                .all(|(&i, (&s, &c))| i < s.div_ceil(c));
        if !inside || len != self.chunk_len() {
            return Err(ProcessingError::BadParameter {
                name: "zarr chunk",
                value: len as f64,
                why: "the chunk index is outside the grid or the data is not one whole chunk",
            });
        }
        Ok(())
    }

    fn write_bytes(&self, index: &[u64], bytes: &[u8]) -> Result<(), ProcessingError> {
        let path = self.chunk_path(index);
        let parent = path.parent().unwrap_or(&self.dir);
        std::fs::create_dir_all(parent).map_err(|e| io_err(parent, e))?;
        let name = index.last().map_or_else(|| "0".to_string(), u64::to_string);
        write_atomic(parent, &name, bytes).map_err(|e| io_err(parent, e))?;
        fsync_dir(parent).map_err(|e| io_err(parent, e))
    }

    /// Writes one whole chunk of f32 values (C order within the chunk).
    pub fn write_f32(&self, index: &[u64], data: &[f32]) -> Result<(), ProcessingError> {
        self.check_index(index, data.len())?;
        if self.dtype != ZarrType::Float32 {
            return Err(ProcessingError::BadParameter {
                name: "zarr data type",
                value: 0.0,
                why: "this array does not hold float32",
            });
        }
        let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.write_bytes(index, &bytes)
    }

    /// Writes one whole chunk of bytes (C order within the chunk).
    pub fn write_u8(&self, index: &[u64], data: &[u8]) -> Result<(), ProcessingError> {
        self.check_index(index, data.len())?;
        if self.dtype != ZarrType::Uint8 {
            return Err(ProcessingError::BadParameter {
                name: "zarr data type",
                value: 0.0,
                why: "this array does not hold uint8",
            });
        }
        self.write_bytes(index, data)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_the_v3_layout_a_reader_expects() {
        let dir = tempfile::tempdir().unwrap();
        let arr = ZarrArray::create(
            &dir.path().join("btf.zarr"),
            &[2, 3, 4, 4, 3],
            &[1, 1, 4, 4, 3],
            ZarrType::Float32,
            &["view", "light", "y", "x", "rgb"],
            json!({"units": "white diffuser"}),
        )
        .unwrap();
        let data: Vec<f32> = (0..48).map(|i| i as f32 * 0.5).collect();
        arr.write_f32(&[1, 2, 0, 0, 0], &data).unwrap();
        let meta: Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("btf.zarr/zarr.json")).unwrap())
                .unwrap();
        assert_eq!(meta["zarr_format"], 3);
        assert_eq!(meta["shape"], json!([2, 3, 4, 4, 3]));
        assert_eq!(
            meta["chunk_grid"]["configuration"]["chunk_shape"],
            json!([1, 1, 4, 4, 3])
        );
        let bytes = std::fs::read(dir.path().join("btf.zarr/c/1/2/0/0/0")).unwrap();
        let back: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(back, data);
        assert!(arr.write_f32(&[2, 0, 0, 0, 0], &data).is_err());
        assert!(arr.write_f32(&[0, 0, 0, 0, 0], &data[..10]).is_err());
        assert!(arr.write_u8(&[0, 0, 0, 0, 0], &[0; 48]).is_err());
    }
}
