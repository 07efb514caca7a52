//! Frames over the daemon's API: query a real run's frames by metadata, download them as
//! PNG / TIFF / EXR and compare the pixels, thumbnails, the latest frame per camera, path
//! traversal attempts, and the executor's Prometheus metrics.
//!
//! The dataset is made once per test binary by the CLI engine in-process (quickstart on a
//! small simulated light stage, virtual clock, one camera frame stalled so the run records a
//! dropped frame, a device error and a reconnect), then every test starts its own daemon on
//! that data directory.

use crate::common;

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use serde_json::Value;
use stagehand::client::Body;
use stagehand::daemon::{RunningDaemon, ServeOptions};
use stagehand::executor::{AutoConfirm, RunControl};
use stagehand::session::{self, Wiring};
use stagehand::storage::RunStatus;
use stagehand::storage::exr_hdr::decode_exr;
use stagehand::storage::png16::decode_png16;
use tokio::sync::broadcast;

/// Marker inside files that must never be served.
const SECRET: &str = "TOP-SECRET-daemon-frames-test";

/// A data directory with one real run and one tampered copy of it.
struct Dataset {
    _tmp: tempfile::TempDir,
    data: PathBuf,
    run_id: String,
    run_dir: PathBuf,
    /// A copy of the run whose index rows / files point outside it: (frame id, how).
    evil_id: String,
    evil_frames: Vec<(i64, &'static str)>,
    /// A copy of the run with damaged frame files: (frame id, its path, how).
    damaged_id: String,
    damaged_frames: Vec<(i64, String, &'static str)>,
}

fn dataset() -> &'static Dataset {
    static DATA: OnceLock<Dataset> = OnceLock::new();
    DATA.get_or_init(|| {
        // The daemon's recorder, installed before the executor runs so its metrics land there.
        stagehand::daemon::metrics_handle();
        std::thread::spawn(make_dataset)
            .join()
            .expect("dataset thread")
    })
}

fn make_dataset() -> Dataset {
    let tmp = tempfile::tempdir().expect("temp dir");
    let data = tmp.path().join("data");
    let runs = data.join("runs");
    std::fs::create_dir_all(&runs).expect("runs dir");
    let prepared = session::prepare(
        common::script("quickstart.rhai"),
        &[],
        common::small_rig("lightstage", 32, 24),
    )
    .expect("quickstart prepares");
    let runtime = session::runtime_for(&prepared.rig).expect("runtime");
    let store = session::create_run(&prepared, &runs, 7).expect("create run");
    let run_dir = store.dir().to_path_buf();
    let summary = runtime
        .block_on(async move {
            let (tx, _) = broadcast::channel(1024);
            let wiring = Wiring {
                events: tx,
                control: RunControl::new(),
                operator: Arc::new(AutoConfirm),
                reserve_bytes: 0,
            };
            let rig = session::open_rig(&prepared.rig, 7, None).expect("open rig");
            // One frame cam1 never delivers: a MissingFrame fault, recovery, and the step again.
            rig.world
                .as_ref()
                .expect("simulated rig")
                .stall_camera("cam1", 1);
            session::run(prepared, store, rig, wiring).await
        })
        .expect("quickstart runs");
    assert_eq!(summary.status, RunStatus::Done);
    let run_id = file_name(&run_dir);

    // Tokens now, so the daemons the tests start concurrently all load the same file.
    stagehand::daemon::auth::Tokens::load_or_create(&data).expect("tokens");

    // Secrets outside the run, and a tampered copy of the run pointing at them.
    std::fs::write(tmp.path().join("secret.txt"), SECRET).expect("secret");
    std::fs::write(runs.join("secret.txt"), SECRET).expect("secret in runs");
    let evil_id = "evil-run".to_string();
    let evil = runs.join(&evil_id);
    copy_dir(&run_dir, &evil);
    std::fs::write(evil.join("secret.txt"), SECRET).expect("secret in run");
    let conn = rusqlite::Connection::open(evil.join("index.sqlite")).expect("open copy");
    let ids: Vec<(i64, String)> = conn
        .prepare("SELECT id, path FROM frames WHERE kind = 'raw' ORDER BY id LIMIT 5")
        .and_then(|mut s| {
            s.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?
                .collect::<Result<_, _>>()
        })
        .expect("frame ids");
    let outside = tmp.path().join("secret.txt");
    let mut evil_frames = Vec::new();
    for ((id, path), (how, new_path)) in ids.iter().zip([
        ("absolute path", outside.display().to_string()),
        ("dot-dot path", "../secret.txt".to_string()),
        ("dot-dot inside frames", "frames/../secret.txt".to_string()),
        ("deep dot-dot", "frames/../../../secret.txt".to_string()),
        ("symlink in frames/", String::new()),
    ]) {
        if new_path.is_empty() {
            // Replace the frame file by a symlink pointing outside the run.
            let file = evil.join(path);
            std::fs::remove_file(&file).expect("remove frame");
            std::os::unix::fs::symlink(&outside, &file).expect("plant symlink");
        } else {
            conn.execute(
                "UPDATE frames SET path = ?1 WHERE id = ?2",
                rusqlite::params![new_path, id],
            )
            .expect("tamper");
        }
        evil_frames.push((*id, how));
    }
    drop(conn);
    // A run directory that is a symlink to a run elsewhere is not a run.
    let elsewhere = tmp.path().join("elsewhere");
    copy_dir(&run_dir, &elsewhere);
    std::os::unix::fs::symlink(&elsewhere, runs.join("linked-run")).expect("link run");
    let (damaged_id, damaged_frames) = damage_a_copy(&run_dir, &runs);
    Dataset {
        _tmp: tmp,
        data,
        run_id,
        run_dir,
        evil_id,
        evil_frames,
        damaged_id,
        damaged_frames,
    }
}

/// Copies the run to `damaged-run` and damages frame files there: a raw PNG replaced by
/// garbage, an HDR EXR with one flipped byte, a raw PNG deleted.
fn damage_a_copy(run_dir: &Path, runs: &Path) -> (String, Vec<(i64, String, &'static str)>) {
    let id = "damaged-run".to_string();
    let copy = runs.join(&id);
    copy_dir(run_dir, &copy);
    let conn = common::db(&copy);
    let row = |sql: &str| -> (i64, String) {
        conn.query_row(sql, [], |r| Ok((r.get(0)?, r.get(1)?)))
            .expect("frame row")
    };
    let garbage = row("SELECT id, path FROM frames WHERE kind = 'raw' ORDER BY id LIMIT 1");
    let flipped = row("SELECT id, path FROM frames WHERE kind = 'hdr' ORDER BY id LIMIT 1");
    let missing = row("SELECT id, path FROM frames WHERE kind = 'raw' ORDER BY id DESC LIMIT 1");
    std::fs::write(copy.join(&garbage.1), b"not a PNG at all").expect("garbage");
    let mut bytes = std::fs::read(copy.join(&flipped.1)).expect("hdr file");
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    std::fs::write(copy.join(&flipped.1), bytes).expect("flip a byte");
    std::fs::remove_file(copy.join(&missing.1)).expect("delete");
    let frames = vec![
        (garbage.0, garbage.1, "raw PNG replaced by garbage"),
        (flipped.0, flipped.1, "HDR EXR with a flipped byte"),
        (missing.0, missing.1, "raw PNG deleted"),
    ];
    (id, frames)
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .and_then(|n| n.to_str())
        .expect("utf-8 name")
        .to_string()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read dir") {
        let entry = entry.expect("entry");
        let target = to.join(entry.file_name());
        if entry.file_type().expect("type").is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).expect("copy");
        }
    }
}

/// The run's index, read-only, for the expected answers.
fn db(d: &Dataset) -> rusqlite::Connection {
    common::db(&d.run_dir)
}

fn sql_i64(d: &Dataset, sql: &str) -> i64 {
    db(d).query_row(sql, [], |r| r.get(0)).expect("query")
}

async fn daemon(d: &Dataset) -> RunningDaemon {
    common::start_daemon(&d.data, None)
        .await
        .expect("daemon starts")
}

/// A blocking client (call it inside `spawn_blocking`): requests through the daemon's router,
/// raw targets over its socket.
#[derive(Clone)]
struct Api {
    http: common::api::Api,
}

/// Status, headers and body of an answer.
struct Answer {
    status: u16,
    content_type: String,
    disposition: String,
    etag: String,
    body: Vec<u8>,
}

impl Answer {
    fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or(Value::Null)
    }

    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

impl Api {
    fn new(d: &RunningDaemon) -> Self {
        // Reading frames needs only the read-only token.
        Self {
            http: common::api::Api::read_only(d),
        }
    }

    fn get_with(&self, path: &str, if_none_match: Option<&str>) -> Answer {
        let headers: Vec<(&str, &str)> = if_none_match
            .map(|tag| ("If-None-Match", tag))
            .into_iter()
            .collect();
        let r = self.http.raw("GET", path, &headers, Body::Empty);
        Answer {
            status: r.status,
            content_type: r.header("content-type").to_string(),
            disposition: r.header("content-disposition").to_string(),
            etag: r.header("etag").to_string(),
            body: r.body,
        }
    }

    fn get(&self, path: &str) -> Answer {
        self.get_with(path, None)
    }

    /// `method path` with `token`, a text body (PUT) or a JSON body (POST): status and JSON.
    fn send(&self, method: &str, path: &str, token: &str, body: &str) -> (u16, Value) {
        let (method, content_type) = match method {
            "PUT" => ("PUT", "text/plain"),
            _ => ("POST", "application/json"),
        };
        let body = Body::Text {
            content_type: content_type.into(),
            text: body.to_string(),
        };
        let r = self.http.with_token(token).raw(method, path, &[], body);
        (
            r.status,
            serde_json::from_slice(&r.body).unwrap_or(Value::Null),
        )
    }

    /// Sends `GET <raw target>` byte for byte over the daemon's socket (no client-side
    /// normalisation of `..` or `%2F`).
    fn raw_get(&self, target: &str) -> (u16, String) {
        self.http.get_exact(target)
    }
}

/// Runs `f` with a client of a fresh daemon on the dataset, then shuts the daemon down.
async fn with_api<T: Send + 'static>(f: impl FnOnce(&Dataset, Api) -> T + Send + 'static) -> T {
    let d = dataset();
    let daemon = daemon(d).await;
    let api = Api::new(&daemon);
    let out = tokio::task::spawn_blocking(move || f(d, api))
        .await
        .expect("test body");
    daemon.shutdown().await;
    out
}

fn frames_of(a: &Answer) -> Vec<Value> {
    a.json()["frames"].as_array().cloned().unwrap_or_default()
}

fn ids(frames: &[Value]) -> Vec<i64> {
    frames
        .iter()
        .map(|f| f["frame_id"].as_i64().expect("frame_id"))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_are_queried_by_metadata_and_paged() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let run = &d.run_id;
        let base = format!("/api/runs/{run}/frames");
        let all = api.get(&format!("{base}?limit=1000"));
        assert_eq!(all.status, 200, "{}", all.text());
        let total = sql_i64(d, "SELECT count(*) FROM frames");
        assert_eq!(total, 72 + 8, "quickstart: 72 raw + 8 HDR frames");
        assert_eq!(all.json()["total"], total);
        let frames = frames_of(&all);
        assert_eq!(frames.len() as i64, total);
        // Default page: 100 frames, here all of them.
        assert_eq!(frames_of(&api.get(&base)).len() as i64, total.min(100));

        // Every field agrees with the index.
        let f = &frames[0];
        let id = f["frame_id"].as_i64().expect("id");
        let (path, sha, camera, step, size): (String, String, String, i64, i64) = db(d)
            .query_row(
                "SELECT path, sha256, camera, step, size_bytes FROM frames WHERE id = ?1",
                [id],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?)),
            )
            .expect("row");
        assert_eq!(f["path"], path);
        assert_eq!(f["sha256"], sha);
        assert_eq!(f["camera"], camera);
        assert_eq!(f["step"], step);
        assert_eq!(f["size_bytes"], size);
        assert_eq!(f["run_id"], run.as_str());
        assert_eq!(f["url"], format!("/api/runs/{run}/frames/{id}"));
        assert_eq!(
            f["thumbnail_url"],
            format!("/api/runs/{run}/frames/{id}/thumbnail")
        );
        for key in [
            "kind",
            "label",
            "block",
            "exposure_index",
            "exposure_s",
            "gain",
            "lamps_on",
            "axes_deg",
            "laser_on",
            "rig_time_s",
            "width",
            "height",
        ] {
            assert!(f.get(key).is_some(), "FrameInfo lacks {key}: {f}");
        }
        assert_eq!(f["width"], 32);
        assert_eq!(f["height"], 24);

        // By camera.
        let cam = api.get(&format!("{base}?camera=cam1&limit=1000"));
        let n = sql_i64(d, "SELECT count(*) FROM frames WHERE camera = 'cam1'");
        assert!(n > 0);
        assert_eq!(cam.json()["total"], n);
        assert!(frames_of(&cam).iter().all(|f| f["camera"] == "cam1"));

        // By lamp: every frame had that lamp on; the count matches the frame_lamps view.
        let lamp = frames
            .iter()
            .find_map(|f| {
                f["lamps_on"]
                    .as_array()?
                    .first()?
                    .as_str()
                    .map(String::from)
            })
            .expect("a frame with a lamp on");
        let by_lamp = api.get(&format!("{base}?lamp={lamp}&limit=1000"));
        assert_eq!(by_lamp.status, 200);
        let n: i64 = db(d)
            .query_row(
                "SELECT count(*) FROM frame_lamps WHERE lamp = ?1",
                [&lamp],
                |r| r.get(0),
            )
            .expect("count");
        assert!(n > 0 && n < total);
        assert_eq!(by_lamp.json()["total"], n);
        for f in frames_of(&by_lamp) {
            let lamps = f["lamps_on"].as_array().expect("lamps");
            assert!(lamps.iter().any(|l| l == lamp.as_str()), "{f}");
        }
        // Lamp and camera together.
        let both = api.get(&format!("{base}?lamp={lamp}&camera=cam2"));
        assert!(
            frames_of(&both)
                .iter()
                .all(|f| f["camera"] == "cam2" && f["lamps_on"].to_string().contains(&lamp))
        );
        assert!(both.json()["total"].as_i64().expect("total") > 0);

        // By step, kind, block, label.
        let step = frames[frames.len() / 2]["step"].as_i64().expect("step");
        let by_step = api.get(&format!("{base}?step={step}"));
        let n = sql_i64(
            d,
            &format!("SELECT count(*) FROM frames WHERE step = {step}"),
        );
        assert_eq!(by_step.json()["total"], n);
        assert!(frames_of(&by_step).iter().all(|f| f["step"] == step));
        let hdr = api.get(&format!("{base}?kind=hdr"));
        assert_eq!(hdr.json()["total"], 8);
        assert!(frames_of(&hdr).iter().all(|f| f["kind"] == "hdr"));
        let block = api.get(&format!("{base}?block=hdr&kind=raw"));
        assert_eq!(
            block.json()["total"],
            sql_i64(
                d,
                "SELECT count(*) FROM frames WHERE block = 'hdr' AND kind = 'raw'"
            )
        );
        // The block filter is a prefix of whole block names: `lamps` finds the frames of
        // `lamps/position 0`, `lamps/position 1`…; `lamp` (half a name) finds none.
        let nested = sql_i64(d, "SELECT count(*) FROM frames WHERE block LIKE 'lamps/%'");
        assert!(nested > 0, "quickstart captures inside `lamps/position N`");
        let lamps = api.get(&format!("{base}?block=lamps&limit=1000"));
        assert_eq!(lamps.json()["total"], nested, "{}", lamps.text());
        assert!(
            frames_of(&lamps)
                .iter()
                .all(|f| f["block"].as_str().is_some_and(|b| b.starts_with("lamps/")))
        );
        let one = api.get(&format!("{base}?block={}", url_encode("lamps/position 1")));
        assert_eq!(
            one.json()["total"],
            sql_i64(
                d,
                "SELECT count(*) FROM frames WHERE block = 'lamps/position 1'"
            )
        );
        assert_eq!(api.get(&format!("{base}?block=lamp")).json()["total"], 0);
        let label = f["label"].as_str().expect("label").to_string();
        let by_label = api.get(&format!("{base}?label={}", url_encode(&label)));
        assert_eq!(by_label.status, 200, "{}", by_label.text());
        assert!(
            frames_of(&by_label)
                .iter()
                .all(|f| f["label"] == label.as_str())
        );
        let none = api.get(&format!("{base}?camera=nope"));
        assert_eq!(none.status, 200);
        assert_eq!(none.json()["total"], 0);

        // Pagination: pages of 7 concatenate to the whole list, in order.
        let mut paged = Vec::new();
        let mut offset = 0;
        loop {
            let page = api.get(&format!("{base}?limit=7&offset={offset}"));
            assert_eq!(page.json()["total"], total);
            let p = frames_of(&page);
            if p.is_empty() {
                break;
            }
            assert!(p.len() <= 7);
            paged.extend(ids(&p));
            offset += 7;
        }
        assert_eq!(paged, ids(&frames));
        let steps: Vec<i64> = frames
            .iter()
            .map(|f| f["step"].as_i64().expect("step"))
            .collect();
        assert!(steps.windows(2).all(|w| w[0] <= w[1]), "ordered by step");
        let zero = api.get(&format!("{base}?limit=0"));
        assert_eq!(zero.json()["total"], total);
        assert!(frames_of(&zero).is_empty());

        // Bad queries are 400 with a JSON message.
        for q in [
            "limit=1001",
            "limit=-1",
            "limit=abc",
            "offset=-5",
            "step=x",
            "kind=jpeg",
            "cam=cam1",
        ] {
            let a = api.get(&format!("{base}?{q}"));
            assert_eq!(a.status, 400, "{q}: {}", a.text());
            assert!(a.json()["error"].is_string(), "{q}: {}", a.text());
        }
        // Unknown run: 404; bad run id: 400.
        assert_eq!(api.get("/api/runs/no-such-run/frames").status, 404);
        assert_eq!(api.get("/api/runs/.hidden/frames").status, 400);
    })
    .await;
}

fn url_encode(s: &str) -> String {
    s.bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b"-_.~".contains(&b) {
                (b as char).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

/// (frame id, path) of the first frame of `kind`.
fn first_of(d: &Dataset, kind: &str) -> (i64, String) {
    db(d)
        .query_row(
            "SELECT id, path FROM frames WHERE kind = ?1 ORDER BY id LIMIT 1",
            [kind],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .expect("frame")
}

fn read_tiff(bytes: &[u8]) -> ((u32, u32), tiff::decoder::DecodingResult) {
    let mut dec = tiff::decoder::Decoder::new(Cursor::new(bytes)).expect("a TIFF");
    let dims = dec.dimensions().expect("dimensions");
    (dims, dec.read_image().expect("TIFF pixels"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_download_as_png_tiff_and_exr_with_the_same_pixels() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let run = &d.run_id;
        // A raw frame: the PNG as stored, a 16-bit TIFF and a float EXR of the same DN.
        let (id, path) = first_of(d, "raw");
        let on_disk = std::fs::read(d.run_dir.join(&path)).expect("frame file");
        let png = decode_png16(&path, &on_disk).expect("png16");
        let url = format!("/api/runs/{run}/frames/{id}");
        for q in ["", "?format=png"] {
            let a = api.get(&format!("{url}{q}"));
            assert_eq!(a.status, 200, "{}", a.text());
            assert_eq!(a.content_type, "image/png");
            assert!(
                a.disposition.starts_with("attachment; filename=\""),
                "{}",
                a.disposition
            );
            assert!(a.disposition.ends_with(".png\""), "{}", a.disposition);
            assert_eq!(a.body, on_disk, "served as stored");
        }
        let tif = api.get(&format!("{url}?format=tiff"));
        assert_eq!(tif.status, 200, "{}", tif.text());
        assert_eq!(tif.content_type, "image/tiff");
        assert!(tif.disposition.ends_with(".tiff\""));
        let (dims, px) = read_tiff(&tif.body);
        assert_eq!(dims, (png.width, png.height));
        match px {
            tiff::decoder::DecodingResult::U16(v) => assert_eq!(v, png.pixels),
            other => panic!("raw TIFF is not 16-bit: {other:?}"),
        }
        let exr = api.get(&format!("{url}?format=exr"));
        assert_eq!(exr.status, 200, "{}", exr.text());
        assert_eq!(exr.content_type, "image/x-exr");
        let back = decode_exr("raw.exr", &exr.body).expect("exr");
        assert_eq!((back.width, back.height), (png.width, png.height));
        let want: Vec<f32> = png.pixels.iter().map(|&v| f32::from(v)).collect();
        assert_eq!(back.pixels, want);
        assert_eq!(back.metadata, png.metadata, "metadata carried over");

        // Conditional GET: same ETag → 304.
        assert!(!tif.etag.is_empty());
        let again = api.get_with(&format!("{url}?format=tiff"), Some(&tif.etag));
        assert_eq!(again.status, 304);

        // An HDR frame: EXR as stored, 32-bit float TIFF, PNG refused (would clip).
        let (id, path) = first_of(d, "hdr");
        let on_disk = std::fs::read(d.run_dir.join(&path)).expect("hdr file");
        let hdr = decode_exr(&path, &on_disk).expect("exr");
        let url = format!("/api/runs/{run}/frames/{id}");
        let a = api.get(&url);
        assert_eq!(a.status, 200);
        assert_eq!(a.content_type, "image/x-exr");
        assert_eq!(a.body, on_disk);
        let tif = api.get(&format!("{url}?format=tiff"));
        assert_eq!(tif.status, 200, "{}", tif.text());
        let (dims, px) = read_tiff(&tif.body);
        assert_eq!(dims, (hdr.width, hdr.height));
        match px {
            tiff::decoder::DecodingResult::F32(v) => assert_eq!(v, hdr.pixels),
            other => panic!("HDR TIFF is not float: {other:?}"),
        }
        let png = api.get(&format!("{url}?format=png"));
        assert_eq!(png.status, 422, "{}", png.text());
        assert!(
            png.json()["error"]
                .as_str()
                .expect("error")
                .contains("clip")
        );
        assert!(png.json()["hint"].as_str().expect("hint").contains("exr"));

        // Bad format / frame id: 400; unknown frame: 404.
        assert_eq!(api.get(&format!("{url}?format=jpeg")).status, 400);
        assert_eq!(api.get(&format!("{url}?fmt=png")).status, 400);
        assert_eq!(api.get(&format!("/api/runs/{run}/frames/abc")).status, 400);
        assert_eq!(
            api.get(&format!("/api/runs/{run}/frames/999999")).status,
            404
        );
        assert_eq!(api.get(&format!("/api/runs/{run}/frames/-1")).status, 404);
        assert_eq!(api.get("/api/runs/no-such-run/frames/1").status, 404);
    })
    .await;
}

fn png8_size(bytes: &[u8]) -> (u32, u32) {
    let reader = png::Decoder::new(Cursor::new(bytes))
        .read_info()
        .expect("a PNG");
    let info = reader.info();
    assert_eq!(info.bit_depth, png::BitDepth::Eight, "8-bit");
    assert_eq!(info.color_type, png::ColorType::Rgb);
    (info.width, info.height)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn thumbnails_are_8_bit_pngs_of_the_requested_size() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let run = &d.run_id;
        for kind in ["raw", "hdr"] {
            let (id, _) = first_of(d, kind);
            let url = format!("/api/runs/{run}/frames/{id}/thumbnail");
            let a = api.get(&url);
            assert_eq!(a.status, 200, "{kind}: {}", a.text());
            assert_eq!(a.content_type, "image/png");
            // 32×24 frames: the longer side is the requested size.
            assert_eq!(png8_size(&a.body), (256, 192), "{kind} default size");
            for (size, want) in [(16, (16, 12)), (64, (64, 48)), (1024, (1024, 768))] {
                let a = api.get(&format!("{url}?size={size}"));
                assert_eq!(a.status, 200, "{kind} {size}: {}", a.text());
                assert_eq!(png8_size(&a.body), want, "{kind} size {size}");
            }
            let cached = api.get_with(&url, Some(&a.etag));
            assert_eq!(cached.status, 304);
            for bad in ["0", "15", "1025", "big", "-3"] {
                let a = api.get(&format!("{url}?size={bad}"));
                assert_eq!(a.status, 400, "size={bad}: {}", a.text());
            }
        }
        assert_eq!(
            api.get(&format!("/api/runs/{run}/frames/999999/thumbnail"))
                .status,
            404
        );
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn path_traversal_never_serves_a_file() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let run = &d.run_id;
        let (id, _) = first_of(d, "raw");
        for target in [
            "/api/runs/..%2F..%2Fetc/frames".to_string(),
            "/api/runs/..%2Fsecret.txt/frames/1".to_string(),
            format!("/api/runs/..%2Fruns%2F{run}/frames/{id}"),
            "/api/runs/%2Fetc%2Fpasswd/frames".to_string(),
            "/api/runs/..%5C..%5Csecret.txt/frames/1".to_string(),
            "/api/runs/a%00b/frames".to_string(),
            "/api/runs/..%2f..%2f..%2fetc%2fpasswd/frames/1/thumbnail".to_string(),
            format!("/api/runs/{run}%2F..%2F..%2Fsecret.txt/frames/{id}"),
            format!("/api/runs/{run}/frames/..%2F..%2Fsecret.txt"),
            format!("/api/runs/{run}/frames/{id}%2F..%2F..%2Fsecret.txt"),
            format!("/api/runs/{run}/frames/%2Fetc%2Fpasswd"),
            // Unencoded dot segments: no client normalises them on the way.
            format!("/api/runs/../runs/{run}/frames/{id}"),
            format!("/api/runs/{run}/frames/../../secret.txt"),
            format!("/api/runs/{run}/../../secret.txt"),
            "/api/runs/../../secret.txt".to_string(),
            "/api/runs/.%2E/frames".to_string(),
            "/api/cameras/..%2F..%2Fsecret.txt/latest".to_string(),
        ] {
            let (status, text) = api.raw_get(&target);
            assert!(
                status == 400 || status == 404,
                "{target}: status {status}\n{text}"
            );
            assert!(!text.contains(SECRET), "{target} served a secret");
            assert!(!text.contains("root:"), "{target} served /etc/passwd");
        }
        // A run directory that is a symlink is not a run.
        let (status, _) = api.raw_get("/api/runs/linked-run/frames");
        assert_eq!(status, 404);
        // Index rows and files pointing outside the run: 404, never the file.
        let evil = &d.evil_id;
        assert_eq!(
            api.get(&format!("/api/runs/{evil}/frames?limit=1")).status,
            200,
            "the tampered run still lists"
        );
        for (id, how) in &d.evil_frames {
            for suffix in ["", "?format=tiff", "/thumbnail"] {
                let a = api.get(&format!("/api/runs/{evil}/frames/{id}{suffix}"));
                assert_eq!(a.status, 404, "{how}{suffix}: {}", a.text());
                assert!(!a.text().contains(SECRET), "{how}{suffix} served a secret");
            }
        }
    })
    .await;
}

/// A frame file that no longer matches the SHA-256 its index row recorded (or is gone) is never
/// served: every format and the thumbnail answer 500 with a JSON error naming the file, the
/// frame and the step, and saying how to find and repair the damage.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn damaged_frame_files_are_refused_with_a_repair_hint() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let run = &d.damaged_id;
        for (id, path, how) in &d.damaged_frames {
            let step: i64 = common::db(&d.run_dir)
                .query_row("SELECT step FROM frames WHERE id = ?1", [id], |r| r.get(0))
                .expect("step");
            for suffix in ["", "?format=tiff", "?format=exr", "/thumbnail"] {
                let a = api.get(&format!("/api/runs/{run}/frames/{id}{suffix}"));
                assert_eq!(a.status, 500, "{how}{suffix}: {}", a.text());
                assert!(
                    a.content_type.starts_with("application/json"),
                    "{how}{suffix}"
                );
                let error = a.json()["error"].as_str().unwrap_or("").to_string();
                let hint = a.json()["hint"].as_str().unwrap_or("").to_string();
                assert!(error.contains(path.as_str()), "{how}{suffix}: {error}");
                assert!(
                    error.contains(&format!("frame {id}")),
                    "{how}{suffix}: {error}"
                );
                assert!(
                    error.contains(&format!("step {step}")),
                    "{how}{suffix}: {error}"
                );
                assert!(hint.contains("stagehand verify"), "{how}{suffix}: {hint}");
                assert!(
                    hint.contains(&format!("--retake {step}")),
                    "{how}{suffix}: {hint}"
                );
            }
        }
        // The run's verify report names every damaged file and the steps to retake.
        let report = api.get(&format!("/api/runs/{run}/verify"));
        assert_eq!(report.status, 200, "{}", report.text());
        let report = report.json();
        assert_eq!(report["ok"], false, "{report}");
        let problems = report["problems"].as_array().cloned().unwrap_or_default();
        let mut steps = Vec::new();
        for (id, path, how) in &d.damaged_frames {
            let p = problems
                .iter()
                .find(|p| p["path"] == path.as_str())
                .unwrap_or_else(|| panic!("{how}: {path} not in {report}"));
            assert_eq!(p["frame_id"], *id, "{how}");
            steps.push(p["step"].as_u64().expect("step"));
        }
        steps.sort();
        steps.dedup();
        assert_eq!(report["retake_steps"], serde_json::json!(steps));
        let command = report["retake_command"].as_str().unwrap_or("");
        assert!(
            command.starts_with("stagehand resume --retake "),
            "{command}"
        );
        // The intact original verifies clean.
        let clean = api.get(&format!("/api/runs/{}/verify", d.run_id)).json();
        assert_eq!(clean["ok"], true, "{clean}");
        assert_eq!(clean["files_checked"], 80);
        assert_eq!(api.get("/api/runs/no-such-run/verify").status, 404);

        // An intact frame of the same run is still served.
        let intact: i64 = db(d)
            .query_row(
                "SELECT id FROM frames WHERE kind = 'raw' ORDER BY id LIMIT 1 OFFSET 1",
                [],
                |r| r.get(0),
            )
            .expect("a second raw frame");
        assert!(d.damaged_frames.iter().all(|(bad, _, _)| *bad != intact));
        let a = api.get(&format!("/api/runs/{run}/frames/{intact}?format=tiff"));
        assert_eq!(a.status, 200, "{}", a.text());
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn latest_frame_of_each_camera() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        for cam in ["cam1", "cam5"] {
            let a = api.get(&format!("/api/cameras/{cam}/latest"));
            assert_eq!(a.status, 200, "{cam}: {}", a.text());
            let f = a.json();
            assert_eq!(f["camera"], cam);
            let newest: f64 = db(d)
                .query_row(
                    "SELECT max(wall_time_unix_s) FROM frames WHERE camera = ?1",
                    [cam],
                    |r| r.get(0),
                )
                .expect("max");
            assert_eq!(f["wall_time_unix_s"].as_f64(), Some(newest));
            // Its URL works.
            let url = f["thumbnail_url"].as_str().expect("url");
            if f["run_id"] == d.run_id.as_str() {
                assert_eq!(api.get(url).status, 200);
            }
        }
        // An unknown camera is no such camera (naming the rig's), not one without frames.
        let a = api.get("/api/cameras/no-such-camera/latest");
        assert_eq!(a.status, 404);
        let error = a.json()["error"].as_str().unwrap_or_default().to_string();
        assert!(error.contains("no such camera"), "{error}");
        assert!(error.contains("cam1") && error.contains("cam8"), "{error}");
        assert!(!error.contains("no frame yet"), "{error}");
    })
    .await;
}

/// The value of the first sample line of `name` whose labels contain all of `labels`.
fn sample(text: &str, name: &str, labels: &[&str]) -> Option<f64> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter(|l| {
            l.starts_with(name) && matches!(l.as_bytes().get(name.len()), Some(b'{') | Some(b' '))
        })
        .find(|l| labels.iter().all(|x| l.contains(x)))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn executor_metrics_reach_the_metrics_endpoint() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let a = api.get("/api/metrics");
        assert_eq!(a.status, 200);
        let m = a.text();
        let frames = sql_i64(d, "SELECT count(*) FROM frames") as f64;
        let captures = sql_i64(d, "SELECT count(*) FROM steps WHERE kind = 'capture'") as f64;
        let get = |name: &str, labels: &[&str]| {
            sample(&m, name, labels).unwrap_or_else(|| panic!("{name} {labels:?} missing:\n{m}"))
        };
        // Counters are process-wide: other runs in this binary may add to them.
        assert!(get("stagehand_frames_written_total", &[]) >= frames);
        assert!(get("stagehand_steps_total", &["kind=\"capture\""]) >= captures);
        assert!(get("stagehand_step_seconds_count", &["kind=\"capture\""]) >= captures);
        let sum = get("stagehand_step_seconds_sum", &["kind=\"capture\""]);
        assert!(sum.is_finite() && sum >= 0.0);
        assert!(
            get(
                "stagehand_step_seconds",
                &["kind=\"capture\"", "quantile=\"0.5\""]
            ) >= 0.0
        );
        assert!(get("stagehand_runs_total", &["status=\"done\""]) >= 1.0);
        // The stalled cam1 frame: dropped, a device error, a reconnect.
        assert!(
            get(
                "stagehand_frames_dropped_total",
                &["device=\"cam1\"", "reason=\"missing\""]
            ) >= 1.0
        );
        assert!(get("stagehand_device_errors_total", &["device=\"cam1\""]) >= 1.0);
        assert!(get("stagehand_reconnects_total", &["device=\"cam1\""]) >= 1.0);
        assert!(m.contains("# HELP stagehand_step_seconds"), "described");
    })
    .await;
}

/// A run started over the API on a small simulated rig (real time): its frames are listed and
/// served, it becomes each camera's latest frame, and the metrics count its steps, frames and
/// run exactly once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_daemon_run_is_listed_served_and_counted() {
    let _turn = crate::grbl_peer::alongside();
    // The shared dataset first, so its (in-process) run is not counted below.
    let _ = dataset();
    let tmp = tempfile::tempdir().expect("temp dir");
    let rig = common::small_rig_file(tmp.path(), "lightstage", 32, 24);
    let daemon = stagehand::daemon::start(ServeOptions {
        rig: Some(rig.display().to_string()),
        listen: "127.0.0.1:0".parse().expect("address"),
        data: tmp.path().join("data"),
        scripts: None,
        seed: 1,
        emulation: None,
    })
    .await
    .expect("daemon starts");
    let api = Api::new(&daemon);
    let operator = daemon.state.tokens.operator.clone();
    tokio::task::spawn_blocking(move || {
        let metric = |m: &str, name: &str, labels: &[&str]| sample(m, name, labels).unwrap_or(0.0);
        let before = api.get("/api/metrics").text();
        let script = "home();\nonly_lamp(\"lamp1\");\ncapture(0.01);\nlamps_off();\n";
        let (status, dry) = api.send("PUT", "/api/scripts/tiny.rhai", &operator, script);
        assert_eq!(status, 200, "{dry}");
        let (status, started) =
            api.send("POST", "/api/runs", &operator, r#"{"script": "tiny.rhai"}"#);
        assert_eq!(status, 201, "{started}");
        let run = started["run_id"].as_str().expect("run_id").to_string();
        let deadline = std::time::Instant::now() + Duration::from_secs(60);
        loop {
            let runs = api.get("/api/runs").json();
            let status = runs
                .as_array()
                .and_then(|a| a.iter().find(|r| r["run_id"] == run.as_str()))
                .map(|r| r["status"].as_str().unwrap_or("").to_string())
                .unwrap_or_default();
            if status != "running" && !status.is_empty() {
                assert_eq!(status, "done", "{runs}");
                break;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "run did not finish: {runs}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        let cameras = 8;
        let list = api.get(&format!("/api/runs/{run}/frames"));
        assert_eq!(list.json()["total"], cameras, "{}", list.text());
        let frames = frames_of(&list);
        assert!(
            frames
                .iter()
                .all(|f| f["lamps_on"] == serde_json::json!(["lamp1"]))
        );
        let latest = api.get("/api/cameras/cam1/latest").json();
        assert_eq!(latest["run_id"], run.as_str());
        let thumb = api.get(latest["thumbnail_url"].as_str().expect("url"));
        assert_eq!(thumb.status, 200);
        assert_eq!(png8_size(&thumb.body), (256, 192));

        let after = api.get("/api/metrics").text();
        let delta = |name: &str, labels: &[&str]| {
            metric(&after, name, labels) - metric(&before, name, labels)
        };
        assert_eq!(
            delta("stagehand_frames_written_total", &[]),
            f64::from(cameras)
        );
        assert_eq!(delta("stagehand_runs_total", &["status=\"done\""]), 1.0);
        assert_eq!(delta("stagehand_steps_total", &["kind=\"capture\""]), 1.0);
        assert_eq!(delta("stagehand_steps_total", &["kind=\"home\""]), 1.0);
        assert_eq!(
            delta("stagehand_step_seconds_count", &["kind=\"capture\""]),
            1.0
        );
        assert!(delta("stagehand_step_seconds_sum", &["kind=\"capture\""]) > 0.0);
    })
    .await
    .expect("test body");
    daemon.shutdown().await;
}
