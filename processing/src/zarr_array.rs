//! Zarr v3 arrays (the format Python's `zarr` reads), described and encoded here and written
//! by the caller (as products, atomically and indexed): an array's `zarr.json` holds its shape,
//! chunk grid, data type and attributes, and each chunk is one file `c/i/j/…` of its values,
//! little-endian, uncompressed (the `bytes` codec). Chunks never written read back as the fill
//! value (0). A group's `zarr.json` only says it is a group.
//!
//! Written here rather than with the `zarrs` crate: these lines cover the one layout the
//! products need, where `zarrs` would add 130 crates to every build; the tests read the arrays
//! back by the spec, and Python's `zarr` 3.1 reads them (checked when this was written:
//! shape, chunks, attributes and values).

use serde_json::{Value, json};

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

/// An array's description: shape, chunk shape, element type, dimension names, attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct ZarrArray {
    shape: Vec<u64>,
    chunk: Vec<u64>,
    dtype: ZarrType,
    metadata: Value,
}

/// The `zarr.json` of a group holding `attributes`.
pub fn group_metadata(attributes: Value) -> Vec<u8> {
    let meta = json!({"zarr_format": 3, "node_type": "group", "attributes": attributes});
    serde_json::to_vec_pretty(&meta).unwrap_or_default()
}

impl ZarrArray {
    /// Describes an array of `shape` in chunks of `chunk`, with one name per dimension.
    pub fn new(
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
        let metadata = json!({
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
        Ok(ZarrArray {
            shape: shape.to_vec(),
            chunk: chunk.to_vec(),
            dtype,
            metadata,
        })
    }

    /// The bytes of the array's `zarr.json`.
    pub fn metadata(&self) -> Vec<u8> {
        serde_json::to_vec_pretty(&self.metadata).unwrap_or_default()
    }

    /// Elements per chunk.
    pub fn chunk_len(&self) -> usize {
        self.chunk.iter().product::<u64>() as usize
    }

    /// The path of chunk `index` (chunk coordinates) relative to the array's folder,
    /// `c/i/j/…`; an index outside the chunk grid is an error.
    pub fn chunk_key(&self, index: &[u64]) -> Result<String, ProcessingError> {
        let inside = index.len() == self.shape.len()
            && index
                .iter()
                .zip(self.shape.iter().zip(&self.chunk))
                .all(|(&i, (&s, &c))| i < s.div_ceil(c));
        if !inside {
            return Err(ProcessingError::BadParameter {
                name: "zarr chunk index",
                value: index.len() as f64,
                why: "the chunk index is outside the array's chunk grid",
            });
        }
        let parts: Vec<String> = index.iter().map(u64::to_string).collect();
        Ok(format!("c/{}", parts.join("/")))
    }

    fn check(&self, len: usize, dtype: ZarrType) -> Result<(), ProcessingError> {
        if dtype != self.dtype {
            return Err(ProcessingError::BadParameter {
                name: "zarr data type",
                value: 0.0,
                why: "the values are not of the array's data type",
            });
        }
        if len != self.chunk_len() {
            return Err(ProcessingError::BadParameter {
                name: "zarr chunk",
                value: len as f64,
                why: "the data is not one whole chunk",
            });
        }
        Ok(())
    }

    /// The bytes of one whole chunk of f32 values (C order within the chunk).
    pub fn encode_f32(&self, data: &[f32]) -> Result<Vec<u8>, ProcessingError> {
        self.check(data.len(), ZarrType::Float32)?;
        Ok(data.iter().flat_map(|v| v.to_le_bytes()).collect())
    }

    /// The bytes of one whole chunk of u8 values (C order within the chunk).
    pub fn encode_u8(&self, data: &[u8]) -> Result<Vec<u8>, ProcessingError> {
        self.check(data.len(), ZarrType::Uint8)?;
        Ok(data.to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn describes_the_v3_layout_a_reader_expects() {
        let arr = ZarrArray::new(
            &[2, 3, 4, 4, 3],
            &[1, 1, 4, 4, 3],
            ZarrType::Float32,
            &["view", "light", "y", "x", "rgb"],
            json!({"units": "white diffuser"}),
        )
        .unwrap();
        let meta: Value = serde_json::from_slice(&arr.metadata()).unwrap();
        assert_eq!(meta["zarr_format"], 3);
        assert_eq!(meta["node_type"], "array");
        assert_eq!(meta["shape"], json!([2, 3, 4, 4, 3]));
        assert_eq!(
            meta["chunk_grid"]["configuration"]["chunk_shape"],
            json!([1, 1, 4, 4, 3])
        );
        assert_eq!(meta["attributes"]["units"], "white diffuser");
        assert_eq!(arr.chunk_key(&[1, 2, 0, 0, 0]).unwrap(), "c/1/2/0/0/0");
        let data: Vec<f32> = (0..48).map(|i| i as f32 * 0.5).collect();
        let bytes = arr.encode_f32(&data).unwrap();
        let back: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(back, data);
        assert!(arr.chunk_key(&[2, 0, 0, 0, 0]).is_err());
        assert!(arr.chunk_key(&[0, 0]).is_err());
        assert!(arr.encode_f32(&data[..10]).is_err());
        assert!(arr.encode_u8(&[0; 48]).is_err());
        let group: Value = serde_json::from_slice(&group_metadata(json!({"a": 1}))).unwrap();
        assert_eq!(group["node_type"], "group");
    }
}
