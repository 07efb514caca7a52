//! What processing writes into a run: product files under `products/` and one row each in the
//! index's `products` table (schema ≥ 4). A product is written atomically (temp file, fsync,
//! rename, directory fsync) before its row commits, so an interrupted `process` leaves whole
//! products or none; a rerun skips every product whose row says it was made from the same
//! inputs, calibrations and parameters and whose file still has its checksum.

use std::fs::File;
use std::path::{Path, PathBuf};

use rusqlite::{OptionalExtension, params};
use serde::{Deserialize, Serialize};

use crate::atomic::{fsync_dir, write_atomic};
use crate::checksum::sha256_hex;
use crate::error::{Result, StorageError};
use crate::index::{Index, now_unix_s, sql_err};
use crate::layout;

/// The columns [`row_to_product`] reads, in its order.
const COLUMNS: &str = "kind, key, path, inputs, calibrations, software, parameters, sha256, \
    size_bytes, created_unix_s";

/// A product about to be written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NewProduct {
    /// `hdr`, `rectified`, `btf`.
    pub kind: String,
    /// What it is of, unique in the run (e.g. `hdr/s000012/cam3`).
    pub key: String,
    /// File name under `products/<kind>/`; it may hold `/`-separated folders (a Zarr chunk's
    /// `btf.zarr/radiance/c/0/3/0/0/0`), never `..`, `.` or an empty part.
    pub file_name: String,
    /// The frames it was made from (paths relative to the run directory).
    pub inputs: Vec<String>,
    /// The calibrations it used, by id.
    pub calibrations: Vec<String>,
    /// The software that made it, e.g. `stagehand 0.1.0`.
    pub software: String,
    /// Every setting that changes its bytes.
    pub parameters: serde_json::Value,
}

/// A product as indexed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoredProduct {
    /// What it is, and how it was made.
    #[serde(flatten)]
    pub made: NewProduct,
    /// Path relative to the run directory.
    pub path: String,
    /// SHA-256 of the file's bytes, hex.
    pub sha256: String,
    /// File size.
    pub size_bytes: u64,
    /// When its row committed.
    pub created_unix_s: f64,
}

/// A run open for writing products: holds the run's write lock (so no capture or resume
/// writes at the same time) and its index, upgraded to schema 4 if older.
pub struct ProductStore {
    dir: PathBuf,
    index: Index,
    _lock: File,
}

impl ProductStore {
    /// Opens the run at `run_dir` for products; fails with `RunInUse` while a capture holds it.
    pub fn open(run_dir: &Path) -> Result<ProductStore> {
        let lock = crate::run_store::lock_run(run_dir)?;
        let index = Index::open(&run_dir.join(layout::INDEX))?;
        Ok(ProductStore {
            dir: run_dir.to_path_buf(),
            index,
            _lock: lock,
        })
    }

    /// The run directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The product indexed under `key`, if any.
    pub fn product(&self, key: &str) -> Result<Option<StoredProduct>> {
        let path = self.index_path();
        self.index
            .conn()
            .query_row(
                &format!("SELECT {COLUMNS} FROM products WHERE key = ?1"),
                [key],
                row_to_product,
            )
            .optional()
            .map_err(sql_err(&path, "read a product row"))
    }

    /// Every product, in key order.
    pub fn products(&self) -> Result<Vec<StoredProduct>> {
        list(self.index.conn(), &self.index_path())
    }

    /// Whether `new` is already made: its row matches what `new` says it is made from, and its
    /// file is there with the recorded checksum.
    pub fn is_current(&self, new: &NewProduct) -> Result<bool> {
        let Some(stored) = self.product(&new.key)? else {
            return Ok(false);
        };
        if stored.made != *new {
            return Ok(false);
        }
        match std::fs::read(self.dir.join(&stored.path)) {
            Ok(bytes) => Ok(sha256_hex(&bytes) == stored.sha256),
            Err(_) => Ok(false),
        }
    }

    /// Writes `bytes` as product `new` (atomically, replacing an older version of the same
    /// key) and indexes it.
    pub fn write(&mut self, new: NewProduct, bytes: &[u8]) -> Result<StoredProduct> {
        let kind_dir = self.dir.join(layout::PRODUCTS_DIR).join(&new.kind);
        let parts: Vec<&str> = new.file_name.split('/').collect();
        let bad = |p: &&str| p.is_empty() || *p == "." || *p == "..";
        let (Some((name, folders)), false) = (parts.split_last(), parts.iter().any(bad)) else {
            return Err(StorageError::InvalidProduct {
                key: new.key.clone(),
                reason: format!(
                    "its file `{}` must be a relative path without empty, `.` or `..` parts",
                    new.file_name
                ),
            });
        };
        if new.kind.is_empty() || new.kind.contains('/') || new.kind.starts_with('.') {
            return Err(StorageError::InvalidProduct {
                key: new.key.clone(),
                reason: format!("its kind `{}` must be one folder name", new.kind),
            });
        }
        let file_dir = folders.iter().fold(kind_dir, |d, f| d.join(f));
        std::fs::create_dir_all(&file_dir)
            .map_err(|e| StorageError::io("create product directory", &file_dir, e))?;
        write_atomic(&file_dir, name, bytes)?;
        fsync_dir(&file_dir)?;
        let stored = StoredProduct {
            path: format!("{}/{}/{}", layout::PRODUCTS_DIR, new.kind, new.file_name),
            sha256: sha256_hex(bytes),
            size_bytes: bytes.len() as u64,
            created_unix_s: now_unix_s(),
            made: new,
        };
        let inputs = to_json(&self.index_path(), &stored.made.inputs)?;
        let calibrations = to_json(&self.index_path(), &stored.made.calibrations)?;
        let parameters = to_json(&self.index_path(), &stored.made.parameters)?;
        let path = self.index_path();
        self.index
            .conn()
            .execute(
                "INSERT OR REPLACE INTO products (kind, key, path, inputs, calibrations, software,
                     parameters, sha256, size_bytes, created_unix_s)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                params![
                    stored.made.kind,
                    stored.made.key,
                    stored.path,
                    inputs,
                    calibrations,
                    stored.made.software,
                    parameters,
                    stored.sha256,
                    i64::try_from(stored.size_bytes).unwrap_or(i64::MAX),
                    stored.created_unix_s,
                ],
            )
            .map_err(sql_err(&path, "insert a product row"))?;
        Ok(stored)
    }

    fn index_path(&self) -> PathBuf {
        self.dir.join(layout::INDEX)
    }
}

/// Every product row of the index at `index` (schema ≥ 4), in key order.
pub(crate) fn list(conn: &rusqlite::Connection, index: &Path) -> Result<Vec<StoredProduct>> {
    let mut stmt = conn
        .prepare(&format!("SELECT {COLUMNS} FROM products ORDER BY key"))
        .map_err(sql_err(index, "list products"))?;
    let rows = stmt
        .query_map([], row_to_product)
        .map_err(sql_err(index, "list products"))?;
    rows.collect::<rusqlite::Result<_>>()
        .map_err(sql_err(index, "list products"))
}

/// A product row's JSON column as text.
fn to_json<T: Serialize>(index: &Path, value: &T) -> Result<String> {
    serde_json::to_string(value).map_err(|source| StorageError::Json {
        op: "encode",
        path: index.join("products"),
        source,
    })
}

fn row_to_product(r: &rusqlite::Row<'_>) -> rusqlite::Result<StoredProduct> {
    let json = |column: usize| -> rusqlite::Result<serde_json::Value> {
        let text: String = r.get(column)?;
        serde_json::from_str(&text).map_err(|e| {
            rusqlite::Error::FromSqlConversionFailure(
                column,
                rusqlite::types::Type::Text,
                Box::new(e),
            )
        })
    };
    let strings = |column: usize| -> rusqlite::Result<Vec<String>> {
        serde_json::from_value(json(column)?).map_err(|e| {
            rusqlite::Error::FromSqlConversionFailure(
                column,
                rusqlite::types::Type::Text,
                Box::new(e),
            )
        })
    };
    let path: String = r.get(2)?;
    let kind: String = r.get(0)?;
    let prefix = format!("{}/{kind}/", layout::PRODUCTS_DIR);
    let file_name = path.strip_prefix(&prefix).unwrap_or(&path).to_string();
    let size: i64 = r.get(8)?;
    Ok(StoredProduct {
        made: NewProduct {
            kind,
            key: r.get(1)?,
            file_name,
            inputs: strings(3)?,
            calibrations: strings(4)?,
            software: r.get(5)?,
            parameters: json(6)?,
        },
        path,
        sha256: r.get(7)?,
        size_bytes: u64::try_from(size).unwrap_or(0),
        created_unix_s: r.get(9)?,
    })
}
