//! Dataset loaders, PFM I/O and evaluation metrics, on tiny fake folders (and on the shared
//! datasets when `../shared/data` exists, or must: tests/common/shared_data.rs). No GPU needed.

use crate::common;

use std::path::{Path, PathBuf};

use glam::DVec3;
use sweepdepth::datasets::{load_dataset, DatasetError, GroundTruth, Layout};
use sweepdepth::eval::{depth_metrics, disparity_metrics, EvalError};
use sweepdepth::image::ImageF32;
use sweepdepth::io::{read_pfm, write_pfm, IoError};

/// A fresh, empty folder under the system temp dir, unique to this process and test.
fn temp_folder(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "sweepdepth_datasets_eval_{}_{name}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write_rgb(dir: &Path, name: &str, w: u32, h: u32, seed: u8) {
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([
            (x as u8).wrapping_mul(7).wrapping_add(seed),
            (y as u8).wrapping_mul(13),
            seed,
        ])
    });
    img.save(dir.join(name)).unwrap();
}

/// Grey image with `value` inside a `border`-pixel frame of zeros.
fn write_gt(dir: &Path, name: &str, w: u32, h: u32, border: u32, value: u8) {
    let img = image::GrayImage::from_fn(w, h, |x, y| {
        let inside = x >= border && y >= border && x + border < w && y + border < h;
        image::Luma([if inside { value } else { 0 }])
    });
    img.save(dir.join(name)).unwrap();
}

fn gt_disparity(gt: &GroundTruth) -> (&ImageF32, f64, u32) {
    match gt {
        GroundTruth::Disparity {
            disparity_eval_px,
            focal_baseline_eval,
            border_px,
            ..
        } => (disparity_eval_px, *focal_baseline_eval, *border_px),
        other => panic!("expected disparity ground truth, got {other:?}"),
    }
}

/// The pixel where the reference pixel (x, y) with eval-unit disparity `d_eval` lands in
/// camera `k` of the dataset's rig.
fn reproject(
    ds: &sweepdepth::datasets::Dataset,
    x: f64,
    y: f64,
    d_eval: f64,
    fb_eval: f64,
    k: usize,
) -> glam::DVec2 {
    let z = fb_eval / d_eval;
    let r = ds.reference_index();
    let ref_model = ds.rig.cameras[r].model;
    let p_ref = ref_model.unproject_z1(glam::DVec2::new(x, y)).unwrap() * z;
    let p_k = ds.rig.cam_from_ref(k).transform_point(p_ref);
    ds.rig.cameras[k].model.project(p_k).unwrap()
}

#[test]
fn middlebury2001_layout_reference_and_scaling() {
    let dir = temp_folder("mb2001");
    let (w, h) = (48, 40);
    for n in 1..=5 {
        write_rgb(&dir, &format!("scene1.row3.col{n}.ppm"), w, h, n as u8);
    }
    write_gt(&dir, "truedisp.row3.col3.pgm", w, h, 4, 80);
    std::fs::write(dir.join("SOURCE.md"), "notes").unwrap();
    let ds = load_dataset(&dir).unwrap();
    assert_eq!(ds.layout, Layout::Middlebury2001);
    assert_eq!(ds.rig.cameras.len(), 5);
    assert_eq!(ds.images.len(), 5);
    assert_eq!(ds.reference_index(), 2);
    assert_eq!(ds.rig.cameras[2].name, "scene1.row3.col3");
    assert_eq!(ds.reference_size(), (w, h));
    let (gt, fb, border) = gt_disparity(&ds.ground_truth);
    assert_eq!(border, 18);
    assert!((fb - f64::from(w) * 0.1).abs() < 1e-12, "fB = {fb}");
    assert!(gt.get(0, 0).is_nan());
    assert_eq!(gt.get(10, 10), 5.0); // 80 / 16
                                     // Sign convention (SOURCE.md): a col3 pixel at x is at x - (k - 3) d in col k.
    for (k, view) in [(0usize, 1i32), (1, 2), (3, 4), (4, 5)] {
        let p = reproject(&ds, 20.0, 15.0, 5.0, fb, k);
        let want = 20.0 - f64::from(view - 3) * 5.0;
        assert!(
            (p.x - want).abs() < 1e-9 && (p.y - 15.0).abs() < 1e-9,
            "col{view}: {p:?}"
        );
    }
    // Search range [0.5, 16 * w / 384] adjacent px in 0.5 eval-px steps, at most 128 planes.
    let max_adj = 16.0 * f64::from(w) / 384.0;
    assert!((ds.params.min_depth_m - fb / max_adj).abs() < 1e-9);
    assert!((ds.params.max_depth_m - fb / 0.5).abs() < 1e-9);
    assert_eq!(
        ds.params.num_planes,
        (((max_adj - 0.5) * 2.0).ceil() as u32 + 1).min(128)
    );
    assert_eq!(ds.name, dir.file_name().unwrap().to_string_lossy());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn middlebury2003_layout_reference_and_scaling() {
    let dir = temp_folder("mb2003");
    let (w, h) = (45, 30);
    for n in 0..=6 {
        // Mixed extensions are fine.
        let ext = if n % 2 == 0 { "ppm" } else { "png" };
        write_rgb(&dir, &format!("im{n}.{ext}"), w, h, n as u8);
    }
    write_gt(&dir, "disp2.pgm", w, h, 2, 100);
    write_gt(&dir, "disp6.pgm", w, h, 2, 60);
    let ds = load_dataset(&dir).unwrap();
    assert_eq!(ds.layout, Layout::Middlebury2003);
    assert_eq!(ds.rig.cameras.len(), 7);
    assert_eq!(ds.rig.cameras[ds.reference_index()].name, "im2");
    let (gt, fb, border) = gt_disparity(&ds.ground_truth);
    assert_eq!(border, 10);
    assert_eq!(gt.get(5, 5), 25.0); // 100 / 4, the im2-im6 disparity
    assert!(gt.get(0, 5).is_nan());
    assert!((fb - 4.0 * f64::from(w) * 0.1).abs() < 1e-12);
    // value / 16 per view step: im2 -> im6 moves 25 px left, im2 -> im3 6.25 px.
    let p6 = reproject(&ds, 30.0, 10.0, 25.0, fb, 6);
    assert!((p6.x - 5.0).abs() < 1e-9, "{p6:?}");
    let p3 = reproject(&ds, 30.0, 10.0, 25.0, fb, 3);
    assert!((p3.x - (30.0 - 6.25)).abs() < 1e-9, "{p3:?}");
    let max_adj = f64::from(w) * 16.0 / 450.0;
    assert_eq!(
        ds.params.num_planes,
        ((((max_adj - 0.5) * 4.0) * 2.0).ceil() as u32 + 1).min(128)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn middlebury2005_layout_reference_and_scaling() {
    let dir = temp_folder("mb2005");
    let (w, h) = (40, 30);
    for n in 0..=6 {
        write_rgb(&dir, &format!("view{n}.png"), w, h, n as u8);
    }
    write_gt(&dir, "disp1.png", w, h, 1, 90);
    write_gt(&dir, "disp5.png", w, h, 1, 30);
    std::fs::write(dir.join("dmin.txt"), "230\r\n").unwrap();
    let ds = load_dataset(&dir).unwrap();
    assert_eq!(ds.layout, Layout::Middlebury2005);
    assert_eq!(ds.rig.cameras.len(), 7);
    assert_eq!(ds.reference_index(), 1);
    assert_eq!(ds.rig.cameras[1].name, "view1");
    let (gt, fb, border) = gt_disparity(&ds.ground_truth);
    assert_eq!(border, 10);
    assert_eq!(gt.get(3, 3), 30.0); // 90 / 3 (ThirdSize-like width)
                                    // Adjacent-view disparity = value / 12.
    let p0 = reproject(&ds, 35.0, 3.0, 30.0, fb, 0);
    assert!((p0.x - (35.0 + 7.5)).abs() < 1e-9, "{p0:?}");
    let max_adj = f64::from(w) * 20.0 / 447.0;
    assert_eq!(
        ds.params.num_planes,
        ((((max_adj - 0.5) * 4.0) * 2.0).ceil() as u32 + 1).min(128)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn unknown_layout_lists_files_and_layouts() {
    let dir = temp_folder("unknown");
    write_rgb(&dir, "holiday.png", 8, 8, 1);
    std::fs::write(dir.join("notes.txt"), "x").unwrap();
    let err = load_dataset(&dir).unwrap_err();
    assert!(matches!(err, DatasetError::UnknownLayout { .. }), "{err}");
    let msg = err.to_string();
    for needle in [
        "holiday.png",
        "notes.txt",
        "middlebury2001",
        "icl-nuim",
        "middlebury-mview",
    ] {
        assert!(msg.contains(needle), "'{needle}' not in: {msg}");
    }
    let _ = std::fs::remove_dir_all(&dir);
    let missing = std::env::temp_dir().join("sweepdepth_datasets_eval_does_not_exist");
    assert!(matches!(
        load_dataset(&missing),
        Err(DatasetError::ListDir { .. })
    ));
}

#[test]
fn ground_truth_for_a_view_that_is_not_there() {
    let dir = temp_folder("missing_gt_view");
    write_rgb(&dir, "im0.ppm", 8, 6, 1);
    write_rgb(&dir, "im1.ppm", 8, 6, 2);
    write_gt(&dir, "disp5.pgm", 8, 6, 0, 40);
    let err = load_dataset(&dir).unwrap_err();
    assert!(
        matches!(err, DatasetError::MissingReference { .. }),
        "{err}"
    );
    assert!(err.to_string().contains('5'), "{err}");
    // No ground truth at all.
    std::fs::remove_file(dir.join("disp5.pgm")).unwrap();
    let err = load_dataset(&dir).unwrap_err();
    assert!(
        matches!(err, DatasetError::MissingGroundTruth { .. }),
        "{err}"
    );
    // 2001: truedisp for col9 while the views are col1, col2.
    let dir2 = temp_folder("missing_gt_view_2001");
    write_rgb(&dir2, "s.row1.col1.ppm", 8, 6, 1);
    write_rgb(&dir2, "s.row1.col2.ppm", 8, 6, 2);
    write_gt(&dir2, "truedisp.row1.col9.pgm", 8, 6, 0, 40);
    let err = load_dataset(&dir2).unwrap_err();
    assert!(
        matches!(err, DatasetError::MissingReference { .. }),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&dir2);
}

#[test]
fn size_mismatch_is_reported_with_the_file() {
    let dir = temp_folder("size_mismatch");
    write_rgb(&dir, "view0.png", 8, 6, 1);
    write_rgb(&dir, "view1.png", 10, 6, 2);
    write_gt(&dir, "disp0.png", 8, 6, 0, 40);
    let err = load_dataset(&dir).unwrap_err();
    match &err {
        DatasetError::SizeMismatch { path, .. } => assert!(path.ends_with("view1.png")),
        other => panic!("expected SizeMismatch, got {other}"),
    }
    assert!(err.to_string().contains("10x6"), "{err}");
    // Ground truth of the wrong size.
    write_rgb(&dir, "view1.png", 8, 6, 2);
    write_gt(&dir, "disp0.png", 9, 6, 0, 40);
    let err = load_dataset(&dir).unwrap_err();
    match &err {
        DatasetError::SizeMismatch { path, .. } => assert!(path.ends_with("disp0.png")),
        other => panic!("expected SizeMismatch, got {other}"),
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn pfm_round_trip_keeps_nan_and_stores_bottom_row_first() {
    let dir = temp_folder("pfm");
    let img = ImageF32 {
        width: 3,
        height: 2,
        data: vec![1.0, 2.0, 3.0, 4.0, f32::NAN, 6.0],
    };
    let path = dir.join("x.pfm");
    write_pfm(&path, &img).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header = b"Pf\n3 2\n-1.0\n";
    assert_eq!(&bytes[..header.len()], header);
    assert_eq!(bytes.len(), header.len() + 6 * 4);
    let first_row: Vec<f32> = bytes[header.len()..header.len() + 12]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    // The first stored row is the image's bottom row (4, NaN, 6).
    assert_eq!(first_row[0], 4.0);
    assert!(first_row[1].is_nan());
    assert_eq!(first_row[2], 6.0);
    let back = read_pfm(&path).unwrap();
    assert_eq!((back.width, back.height), (3, 2));
    assert_eq!(back.data[..4], [1.0, 2.0, 3.0, 4.0]);
    assert!(back.data[4].is_nan());
    assert_eq!(back.data[5], 6.0);

    // Colour PFM and garbage are refused with the path in the message.
    let colour = dir.join("colour.pfm");
    std::fs::write(&colour, b"PF\n1 1\n-1.0\n\0\0\0\0\0\0\0\0\0\0\0\0").unwrap();
    let err = read_pfm(&colour).unwrap_err();
    assert!(matches!(err, IoError::Pfm { .. }));
    assert!(err.to_string().contains("colour.pfm"), "{err}");
    let short = dir.join("short.pfm");
    std::fs::write(&short, b"Pf\n4 4\n-1.0\n\0\0\0\0").unwrap();
    assert!(read_pfm(&short).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}

fn img(w: u32, h: u32, data: Vec<f32>) -> ImageF32 {
    ImageF32 {
        width: w,
        height: h,
        data,
    }
}

#[test]
fn disparity_metrics_border_invalid_and_ranking() {
    // 4x3 image, border 1: only (1,1) and (2,1) are evaluated. f B = 12.
    let nan = f32::NAN;
    let gt = img(
        4,
        3,
        vec![
            9.0, 9.0, 9.0, 9.0, //
            9.0, 6.0, 3.0, 9.0, //
            9.0, 9.0, 9.0, 9.0,
        ],
    );
    // (1,1): d = 12 / 2 = 6 exact; (2,1): invalid. The rest would be bad but is in the border.
    let depth = img(
        4,
        3,
        vec![
            1.0, 1.0, 1.0, 1.0, //
            1.0, 2.0, nan, 1.0, //
            1.0, 1.0, 1.0, 1.0,
        ],
    );
    let conf = img(4, 3, vec![0.5; 12]);
    let m = disparity_metrics(&depth, &conf, &gt, 12.0, 1).unwrap();
    assert_eq!(m.evaluated_px, 2);
    assert_eq!(
        (m.bad1, m.bad2, m.bad1_valid, m.invalid),
        (50.0, 50.0, 0.0, 50.0)
    );
    assert!(m.confidence_ranking.is_none(), "one valid estimate only");

    // Border 0: 12 pixels; the confident half is right, the rest wrong.
    let gt = img(4, 1, vec![4.0, 4.0, 4.0, 4.0]);
    let depth = img(4, 1, vec![3.0, 3.0, 1.0, 1.0]); // d = 4, 4, 12, 12
    let conf = img(4, 1, vec![0.9, 0.8, 0.1, 0.2]);
    let m = disparity_metrics(&depth, &conf, &gt, 12.0, 0).unwrap();
    let r = m.confidence_ranking.unwrap();
    assert_eq!((r.bad1_confident_half, r.bad1_rest), (0.0, 100.0));
    assert_eq!(
        (m.bad1, m.bad2, m.bad1_valid, m.invalid),
        (50.0, 50.0, 50.0, 0.0)
    );

    // Size mismatch and nothing to evaluate are errors, not panics.
    assert!(matches!(
        disparity_metrics(&img(2, 1, vec![1.0; 2]), &conf, &gt, 12.0, 0),
        Err(EvalError::Size { .. })
    ));
    assert!(matches!(
        disparity_metrics(&depth, &conf, &gt, 12.0, 5),
        Err(EvalError::NoGroundTruthPixels(_))
    ));
}

#[test]
fn depth_metrics_by_hand() {
    let nan = f32::NAN;
    let gt = img(5, 1, vec![2.0, 2.0, 4.0, nan, 1.0]);
    // rel errors: 0.005, 0.03, 0.25, (no GT), invalid.
    let depth = img(5, 1, vec![2.01, 2.06, 5.0, 7.0, nan]);
    let m = depth_metrics(&depth, &gt).unwrap();
    assert_eq!(m.evaluated_px, 4);
    assert!(
        (m.mean_abs_rel - (0.005 + 0.03 + 0.25) / 3.0).abs() < 1e-6,
        "{m:?}"
    );
    assert_eq!(
        (m.within_1pct, m.within_5pct, m.invalid),
        (25.0, 50.0, 25.0)
    );
}

#[test]
fn shared_datasets_load() {
    let load = |name: &str| {
        let dir = common::shared_data::dataset("shared_datasets_load", name)?;
        Some(load_dataset(&dir).unwrap_or_else(|e| panic!("{name}: {e}")))
    };
    if let Some(ds) = load("middlebury2001_tsukuba") {
        assert_eq!(ds.layout, Layout::Middlebury2001);
        assert_eq!(ds.rig.cameras.len(), 5);
        assert_eq!(ds.reference_size(), (384, 288));
        assert_eq!(
            ds.rig.cameras[ds.reference_index()].name,
            "scene1.row3.col3"
        );
        let (gt, _, border) = gt_disparity(&ds.ground_truth);
        assert_eq!(border, 18);
        let known: Vec<f32> = gt.data.iter().copied().filter(|v| v.is_finite()).collect();
        let max = known.iter().copied().fold(0.0f32, f32::max);
        let min = known.iter().copied().fold(f32::INFINITY, f32::min);
        assert_eq!((min, max), (5.0, 14.0));
        assert_eq!(ds.params.num_planes, 32);
    }
    if let Some(ds) = load("middlebury2003_teddy_9view") {
        assert_eq!(ds.layout, Layout::Middlebury2003);
        assert_eq!(ds.rig.cameras.len(), 9);
        assert_eq!(ds.reference_size(), (450, 375));
        assert_eq!(ds.rig.cameras[ds.reference_index()].name, "im2");
    }
    if let Some(ds) = load("middlebury2005_Laundry_thirdsize") {
        assert_eq!(ds.layout, Layout::Middlebury2005);
        assert_eq!(ds.rig.cameras.len(), 7);
        assert_eq!(ds.reference_size(), (447, 370));
        assert_eq!(ds.rig.cameras[ds.reference_index()].name, "view1");
    }
    if let Some(ds) = load("iclnuim_livingroom_traj2_frames") {
        assert_eq!(ds.layout, Layout::IclNuim);
        assert_eq!(ds.rig.cameras.len(), 5);
        assert_eq!(ds.reference_size(), (640, 480));
        assert_eq!(ds.rig.cameras[ds.reference_index()].name, "scene_00_0020");
        for camera in &ds.rig.cameras {
            let k = camera.model.intrinsics;
            assert!(k.fy_px < 0.0, "{}: fy = {}", camera.name, k.fy_px);
            assert!((k.fx_px - 481.2).abs() < 0.1 && (k.fy_px + 480.0).abs() < 0.1);
        }
        // Camera centres from SOURCE.md.
        let c = ds.rig.cameras[ds.reference_index()].centre_in_rig();
        assert!(
            (c - DVec3::new(0.8169, 1.3002, 1.4627)).length() < 1e-3,
            "{c:?}"
        );
        match &ds.ground_truth {
            GroundTruth::Depth { depth_m } => {
                let valid: Vec<f32> = depth_m
                    .data
                    .iter()
                    .copied()
                    .filter(|v| v.is_finite())
                    .collect();
                assert!(valid.len() > 300_000);
                let min = valid.iter().copied().fold(f32::INFINITY, f32::min);
                let max = valid.iter().copied().fold(0.0f32, f32::max);
                // Ray distances are 2.243..4.368 m; z is at most that.
                assert!(min > 1.5 && max <= 4.37, "{min}..{max}");
            }
            other => panic!("expected depth ground truth, got {other:?}"),
        }
    }
    for name in [
        "middlebury_mview_templeSparseRing",
        "middlebury_mview_dinoSparseRing",
    ] {
        if let Some(ds) = load(name) {
            assert_eq!(ds.layout, Layout::MiddleburyMultiView);
            assert_eq!(ds.rig.cameras.len(), 5, "{name}");
            assert_eq!(ds.reference_index(), 0);
            assert!(matches!(ds.ground_truth, GroundTruth::None));
            let names: Vec<&str> = ds.rig.cameras.iter().map(|c| c.name.as_str()).collect();
            // templeSR0011 is the same viewpoint as the reference templeSR0001.
            assert!(!names.contains(&"templeSR0011"), "{names:?}");
            let ref_centre = ds.rig.cameras[0].centre_in_rig();
            for c in &ds.rig.cameras[1..] {
                assert!((c.centre_in_rig() - ref_centre).length() > 1e-3);
            }
            // The objects sit about 0.55-0.66 m from the cameras (SOURCE.md).
            assert!(
                ds.params.min_depth_m > 0.3 && ds.params.max_depth_m < 1.0,
                "{name}: {}..{}",
                ds.params.min_depth_m,
                ds.params.max_depth_m
            );
            println!(
                "{name}: cameras {names:?}, depth {:.3}..{:.3} m",
                ds.params.min_depth_m, ds.params.max_depth_m
            );
        }
    }
}
