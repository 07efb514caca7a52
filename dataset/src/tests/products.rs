//! Processing products written beside a closed run.

use super::*;

/// A run created and closed (its lock released), in a temp dir kept alive by the first value.
fn closed_run() -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let store = RunStore::create(&tmp.path().join("out"), manifest(), &plan()).unwrap();
    let dir = store.dir().to_path_buf();
    drop(store);
    (tmp, dir)
}

fn product_named(file_name: &str) -> NewProduct {
    NewProduct {
        kind: "btf".into(),
        key: format!("btf/{file_name}"),
        file_name: file_name.into(),
        inputs: vec!["frames/a.png".into()],
        calibrations: vec!["geometry-1".into()],
        software: "test".into(),
        parameters: serde_json::json!({"size": 4}),
    }
}

#[test]
fn a_product_in_folders_is_written_indexed_and_current() {
    let (_tmp, dir) = closed_run();
    let mut store = ProductStore::open(&dir).unwrap();
    let chunk = product_named("btf.zarr/radiance/c/0/1/0/0/0");
    let stored = store.write(chunk.clone(), &[1, 2, 3]).unwrap();
    assert_eq!(stored.path, "products/btf/btf.zarr/radiance/c/0/1/0/0/0");
    assert_eq!(std::fs::read(dir.join(&stored.path)).unwrap(), [1, 2, 3]);
    assert!(store.is_current(&chunk).unwrap());
    let listed = store.products().unwrap();
    assert_eq!(listed.len(), 1);
    assert_eq!(listed[0].made, chunk, "the file name keeps its folders");
    // Changed bytes on disk: no longer current.
    std::fs::write(dir.join(&stored.path), [9]).unwrap();
    assert!(!store.is_current(&chunk).unwrap());
}

#[test]
fn a_file_name_that_leaves_its_folder_is_refused() {
    let (_tmp, dir) = closed_run();
    let mut store = ProductStore::open(&dir).unwrap();
    for bad in ["../escape", "a//b", "./a", "a/", ""] {
        let err = store.write(product_named(bad), &[0]).unwrap_err();
        assert!(err.to_string().contains("relative path"), "{bad}: {err}");
    }
    let mut wrong_kind = product_named("ok");
    wrong_kind.kind = "../x".into();
    assert!(store.write(wrong_kind, &[0]).is_err());
    assert!(store.products().unwrap().is_empty());
}
