//! What the frames and the index hold on disk: PNG, stored PNG, EXR, old datasets, the fixture's placement.

use super::*;

#[test]
fn png_round_trip_and_identical_bytes_without_wall_time() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let frame = raw_frame(1, "cam5", 1, &["lamp3"]);
    let FramePixels::Raw(pixels) = frame.pixels.clone() else {
        return Err("not raw".into());
    };
    let meta = frame.meta.clone();
    let paths = store.commit_step(&record(1, 9.5), vec![frame.clone()])?;
    let bytes_a = fs::read(&paths[0])?;

    let decoded = decode_png16("t", &bytes_a)?;
    assert_eq!((decoded.width, decoded.height), (meta.width, meta.height));
    assert_eq!(decoded.pixels, pixels, "the DN come back exactly");
    // Stored MSB-aligned (12-bit sensor: shifted by 4, sBIT 12), and the shift is recorded.
    assert_eq!((decoded.significant_bits, decoded.shift), (12, 4));
    let embedded: serde_json::Value =
        serde_json::from_str(decoded.metadata.as_deref().ok_or("no iTXt")?)?;
    assert_eq!(embedded["camera"], "cam5");
    assert_eq!(embedded["exposure_index"], 1);
    assert_eq!(embedded["sample_shift"], 4);
    assert!(embedded.get("wall_time_unix_s").is_none());

    let mut later = frame;
    later.meta.wall_time_unix_s += 3600.0;
    let paths_b = store.commit_step(&record(1, 9.5), vec![later])?;
    let bytes_b = fs::read(&paths_b[0])?;
    assert_eq!(bytes_a, bytes_b);
    let rows = store.frames(Some(1))?;
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].meta.sample_shift, 4);
    assert_eq!(rows[0].sha256, sha256_hex(&bytes_a));
    assert_eq!(
        rows[0].meta.wall_time_unix_s,
        meta.wall_time_unix_s + 3600.0
    );
    Ok(())
}

/// A writer behind the cameras stores some raw frames uncompressed (every other, or all): both
/// kinds are PNG that decode to the same DN and are indexed with their own size and hash, and
/// the commit says where its time went.
#[test]
fn stored_frames_decode_alike_at_every_compression() -> TestResult {
    for (compression, expected) in [
        (RawCompression::Deflate, (0, 4)),
        (RawCompression::HalfStored, (2, 2)),
        (RawCompression::Stored, (4, 0)),
    ] {
        let (stored, deflated, times) = stored_and_deflated(compression)?;
        assert_eq!(
            (stored, deflated),
            expected,
            "{compression:?}: raw frames (stored, deflated)"
        );
        for t in [times.encode_s, times.write_s] {
            assert!(t.is_finite() && t > 0.0, "{compression:?}: {times:?}");
        }
    }
    Ok(())
}

/// Commits step 1's frames (four raw, made 64×48) with `compression`; counts the raw frames
/// stored and deflated after checking each file against its row and its DN.
fn stored_and_deflated(
    compression: RawCompression,
) -> Result<(usize, usize, WriteTimes), Box<dyn std::error::Error>> {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let dir = store.dir().to_path_buf();
    // Frames large enough for deflate to pay: a smooth 64×48 gradient.
    let mut frames = step1_frames();
    for f in &mut frames {
        if let FramePixels::Raw(px) = &mut f.pixels {
            (f.meta.width, f.meta.height) = (64, 48);
            *px = (0..64 * 48 * 3).map(|i| (i / 3 % 64 * 16) as u16).collect();
        }
    }
    let raw: Vec<(String, Option<usize>, Vec<u16>)> = frames
        .iter()
        .filter_map(|f| match &f.pixels {
            FramePixels::Raw(px) => {
                Some((f.meta.camera.clone(), f.meta.exposure_index, px.clone()))
            }
            FramePixels::Hdr(_) => None,
        })
        .collect();
    let (_, times) =
        store.commit_steps_with(vec![(record(1, 9.5), frames)], compression, &|_| {})?;
    let (mut stored, mut deflated) = (0, 0);
    for row in store.frames(Some(1))? {
        let bytes = fs::read(dir.join(&row.path))?;
        assert_eq!(row.sha256, sha256_hex(&bytes));
        assert_eq!(row.size_bytes, bytes.len() as u64);
        if row.meta.kind != FrameKind::Raw {
            continue;
        }
        let (_, _, pixels) = raw
            .iter()
            .find(|(c, e, _)| *c == row.meta.camera && *e == row.meta.exposure_index)
            .ok_or("a row for no frame")?;
        assert_eq!(
            &decode_png16(&row.path, &bytes)?.pixels,
            pixels,
            "{}",
            row.path
        );
        // Stored: every sample's two bytes and more; deflated: far less.
        if bytes.len() > pixels.len() * 2 {
            stored += 1;
        } else {
            deflated += 1;
        }
    }
    Ok((stored, deflated, times))
}

/// A dataset written before MSB alignment and ground truth (index schema 1, PNGs with the DN
/// unshifted and no sBIT) verifies clean, opens, is upgraded to schema 3 with shift 0 in every
/// row, and reads the same DN.
#[test]
fn old_datasets_without_sample_shift_still_read() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let dir = store.dir().to_path_buf();
    // Every frame step 1 of the plan asks for, so the dataset verifies clean.
    let mut frames = step1_frames();
    frames.push(hdr_frame(1, "cam6"));
    store.commit_step(&record(1, 9.5), frames.clone())?;
    drop(store);
    // Turn it into what an older stagehand wrote.
    let conn = rusqlite::Connection::open(dir.join(layout::INDEX))?;
    for f in &frames {
        let FramePixels::Raw(px) = &f.pixels else {
            continue;
        };
        let name = frame_file_name(&f.meta);
        let mut old_meta = f.meta.clone();
        old_meta.sample_shift = 0;
        let json = old_meta.embedded_json()?;
        let bytes = crate::png16::encode_png16_unshifted(&name, 4, 3, px, &json)?;
        fs::write(dir.join("frames").join(&name), &bytes)?;
        conn.execute(
            "UPDATE frames SET sha256 = ?1, size_bytes = ?2 WHERE path = ?3",
            rusqlite::params![
                sha256_hex(&bytes),
                bytes.len() as i64,
                format!("frames/{name}")
            ],
        )?;
    }
    conn.execute_batch(
        "DROP VIEW frame_lamps; ALTER TABLE frames DROP COLUMN sample_shift;
         ALTER TABLE frames DROP COLUMN fixture_pose; DROP TABLE products;
         CREATE VIEW frame_lamps AS
             SELECT frames.*, j.value AS lamp FROM frames, json_each(frames.lamps_on) AS j;
         DROP TABLE ground_truth;
         PRAGMA user_version = 1;",
    )?;
    drop(conn);
    let report = verify::verify_run::<Plan>(&dir)?;
    assert!(report.ok, "{}", report.render());
    assert_eq!(report.files_checked, frames.len());

    let (store, _, _) = RunStore::open::<Plan>(&dir)?;
    let version: i32 = store
        .index()
        .conn()
        .query_row("PRAGMA user_version", [], |r| r.get(0))?;
    assert_eq!(version, index::SCHEMA_VERSION);
    let rows = store.frames(Some(1))?;
    assert_eq!(rows.len(), frames.len());
    for row in &rows {
        assert_eq!(row.meta.sample_shift, 0, "{}", row.path);
        if row.meta.kind != FrameKind::Raw {
            continue;
        }
        let written = frames
            .iter()
            .find(|f| format!("frames/{}", frame_file_name(&f.meta)) == row.path)
            .ok_or("a written frame")?;
        let decoded = decode_png16(&row.path, &fs::read(dir.join(&row.path))?)?;
        assert_eq!(FramePixels::Raw(decoded.pixels), written.pixels);
        assert_eq!(decoded.shift, 0);
    }
    // The lamp view still works on the upgraded index.
    let n: i64 = store.index().conn().query_row(
        "SELECT count(*) FROM frame_lamps WHERE lamp = 'lamp3' AND sample_shift = 0",
        [],
        |r| r.get(0),
    )?;
    assert_eq!(n, frames.len() as i64);
    Ok(())
}

#[test]
fn exr_round_trip() -> TestResult {
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let frame = hdr_frame(2, "cam5");
    let FramePixels::Hdr(pixels) = frame.pixels.clone() else {
        return Err("not hdr".into());
    };
    let paths = store.commit_step(&record(2, 3.0), vec![frame])?;
    assert!(paths[0].ends_with("frames/s000002_cam5_hdr.exr"));
    let decoded = decode_exr("t", &fs::read(&paths[0])?)?;
    assert_eq!(decoded.pixels, pixels);
    let embedded: serde_json::Value =
        serde_json::from_str(decoded.metadata.as_deref().ok_or("no attribute")?)?;
    assert_eq!(embedded["kind"], "hdr");
    Ok(())
}

#[test]
fn a_placed_fixture_is_indexed_and_embedded_and_a_flat_one_is_left_out() -> TestResult {
    use stagehand_devices::fixture_pose::FixturePose;
    let tmp = tempfile::tempdir()?;
    let mut store = RunStore::create(tmp.path(), manifest(), &plan())?;
    let mut frames = step1_frames();
    let pose = FixturePose {
        tilt_deg: 30.0,
        tilt_toward_deg: 90.0,
        ..FixturePose::default()
    };
    frames[0].meta.fixture_pose = pose;
    let flat_json = frames[1].meta.embedded_json()?;
    assert!(!flat_json.contains("fixture_pose"), "{flat_json}");
    assert!(
        frames[0]
            .meta
            .embedded_json()?
            .contains("\"tilt_deg\":30.0")
    );
    store.commit_step(&record(1, 9.5), frames.clone())?;
    let rows = store.frames(Some(1))?;
    let placed: Vec<FixturePose> = rows.iter().map(|r| r.meta.fixture_pose).collect();
    assert_eq!(placed.iter().filter(|p| **p == pose).count(), 1);
    assert_eq!(
        placed.iter().filter(|p| p.is_flat_centred()).count(),
        rows.len() - 1
    );
    let reader = RunReader::open(store.dir())?;
    assert_eq!(reader.schema_version(), index::SCHEMA_VERSION);
    Ok(())
}
