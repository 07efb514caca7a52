//! Downloading frames: PNG, TIFF and EXR of the same pixels, conditional GETs, and 8-bit
//! thumbnails of the requested size.

use super::*;
use stagehand::storage::exr_hdr::decode_exr;
use stagehand::storage::png16::decode_png16;

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
