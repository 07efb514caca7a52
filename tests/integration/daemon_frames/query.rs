//! Listing a run's frames by metadata (camera, lamp, step, kind, block, label) with paging,
//! and the latest frame of each camera.

use super::*;
use dataset::sql_i64;

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
