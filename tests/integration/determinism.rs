//! Same seed → byte-identical frames; another seed → other noise.

use crate::common;

use common::*;

fn frames_of(seed: u64) -> Vec<String> {
    let tmp = tempfile::tempdir().unwrap();
    let out = run_sequence(
        "quickstart.rhai",
        small_rig("lightstage", 40, 30),
        &[],
        tmp.path(),
        seed,
    );
    out.result.expect("run");
    disk_checksums(&out.dir)
        .into_iter()
        .map(|(name, sha)| format!("{name} {sha}"))
        .collect()
}

#[test]
fn same_seed_gives_byte_identical_frames() {
    let _turn = crate::grbl_peer::alongside();
    let a = frames_of(11);
    let b = frames_of(11);
    assert!(!a.is_empty());
    assert_eq!(a, b);
}

#[test]
fn different_seed_gives_different_noise() {
    let _turn = crate::grbl_peer::alongside();
    let a = frames_of(11);
    let b = frames_of(12);
    assert_eq!(a.len(), b.len());
    let same = a.iter().zip(&b).filter(|(x, y)| x == y).count();
    assert!(
        same < a.len() / 10,
        "{same} of {} frames identical across seeds",
        a.len()
    );
}
