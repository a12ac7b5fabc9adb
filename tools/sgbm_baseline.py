#!/usr/bin/env python3
"""OpenCV StereoSGBM baseline on three Middlebury stereo pairs (standalone).

Run (from anywhere):

    pip install opencv-python-headless numpy
    python3 tools/sgbm_baseline.py [DATA_ROOT] [--mode HH|SGBM|3WAY|HH4] [--pad-left]
    python3 tools/sgbm_baseline.py [DATA_ROOT] --icl [--check-pfm DEPTH_PFM]
    python3 tools/sgbm_baseline.py --time [--repeats N] [--json]
    python3 tools/sgbm_baseline.py --pair LEFT RIGHT --num-disp N --out DISP.pfm [--mode 3WAY]

--time is the speed peer of `sweepdepth bench`: StereoSGBM in MODE_SGBM_3WAY
(OpenCV's fastest full SGBM) on Tsukuba scene1.row3.col3 / col4 (the repo's
data/tsukuba, so no DATA_ROOT is needed) with 32 disparities and the settings
below, one warm-up then N timed runs; prints the median in milliseconds
(`--json`: one object). OpenCV's own thread count is left as it is.

DATA_ROOT defaults to <repo root>/../shared/data, computed from this file's
location (tools/ -> repo root -> its parent -> shared/data).  It must contain
the folders middlebury2001_tsukuba, middlebury2003_teddy_9view and
middlebury2005_Laundry_thirdsize (see the SOURCE.md in each for the
ground-truth encodings used below).

Evaluation protocol (the project's protocol)
--------------------------------------------
Dataset  | left (reference)      | right                 | GT (disparity of the pair, px)  | border
---------|-----------------------|-----------------------|---------------------------------|-------
Tsukuba  | scene1.row3.col3.ppm  | scene1.row3.col4.ppm  | truedisp.row3.col3.pgm / 16     | 18 px
Teddy    | im2.ppm               | im6.ppm               | disp2.pgm / 4                   | 10 px
Laundry  | view1.png             | view5.png             | disp1.png / 3  (ThirdSize px)   | 10 px

* GT value 0 = unknown; such pixels, and a border of the given width on all
  four sides, are excluded.  All metrics are over the remaining pixels
  ("evaluated pixels").
* A pixel whose SGBM output is invalid (OpenCV writes (minDisparity-1)*16,
  i.e. a value < minDisparity*16) has no estimate.
* bad>1 / bad>2: % of evaluated pixels with |d - gt| > 1 (resp. 2) px, where
  pixels with no valid estimate COUNT AS BAD.
* bad>1 (valid only): % of evaluated pixels with a valid estimate that have
  |d - gt| > 1 px.
* invalid %: % of evaluated pixels with no valid estimate.

SGBM configuration (commonly used, as in OpenCV's stereo_match sample):
minDisparity 0, numDisparities = smallest multiple of 16 >= max GT disparity
(Tsukuba 16, Teddy 64 [max 211/4 = 52.75], Laundry 80 [max 232/3 = 77.3]),
blockSize 5, P1 = 8*3*5^2 = 600, P2 = 32*3*5^2 = 2400 (3 = colour channels;
images are passed to SGBM as 3-channel BGR), uniquenessRatio 10,
speckleWindowSize 100, speckleRange 2 (OpenCV multiplies it by 16 internally,
so this is 2 px), disp12MaxDiff 1, preFilterCap 63, mode MODE_HH (full 8-path;
--mode selects another).  Note: OpenCV's SGBM marks the leftmost
minDisparity+numDisparities columns invalid (they count as bad / invalid
under this protocol; Tsukuba's 18 px border hides them, the 10 px borders of
Teddy and Laundry do not).  --pad-left (off by default, NOT the protocol)
replicate-pads the images on the left to avoid this, for reference only.
Output (CV_16S, 4 fractional bits) is divided by 16.

Two rows per dataset:
* "raw":    SGBM output, invalid pixels left invalid.
* "filled": every invalid pixel is filled along its scanline from the nearest
  valid disparity to its left and to its right, taking the minimum of the two
  (background-favouring fill; only one side is used when the other side has no
  valid pixel; a row with no valid pixel at all is filled with 0).  0 % invalid.

ICL-NUIM mode (--icl; folder iclnuim_livingroom_traj2_frames)
-------------------------------------------------------------
General poses, no rectified pair, depth ground truth.  `sweepdepth eval` takes
the middle frame (scene_00_0020) as reference and matches it against all four
other frames at once, so there is no single evaluation pair; SGBM is run once
per neighbour (0010, 0015, 0025, 0030), each a two-view pair with the
reference:

* Cameras as in src/datasets/icl_nuim.rs / SOURCE.md (POV-Ray .txt: fx = W|dir|/|right|,
  fy = -H|dir|/|up| < 0, cx = (W-1)/2, cy = (H-1)/2, X_c = R_wc^T (X_w - C)).
  OpenCV wants positive focal lengths, so both cameras are taken with their y
  axis flipped (F = diag(1,-1,1): X' = F X_c, fy' = -fy); the relative pose of
  the two flipped frames, R' = F R2 R1^T F, t' = F R2 (C1 - C2), is a proper
  rigid motion, and z (the depth) is unchanged.
* cv2.stereoRectify(K1', 0, K2', 0, R', t', CALIB_ZERO_DISPARITY, alpha=1:
  every original pixel stays inside the rectified image), remap (bilinear).
  When the neighbour lies to the left of the reference in the rectified frame
  (P2[0,3] > 0) both rectified images are mirrored so that the reference is
  SGBM's left image, and the disparity is mirrored back.
* StereoSGBM with the same settings as above (mode HH, block 5, P1 600,
  P2 2400, uniqueness 10, speckle 100/2, disp12MaxDiff 1, preFilterCap 63);
  numDisparities = smallest multiple of 16 >= f_rect B / (smallest GT depth).
* Back to the reference camera: for every original reference pixel, its ray
  is rotated into the rectified frame (R1) and projected with P1; the SGBM
  disparity at the nearest rectified pixel gives the rectified point
  X_r = (f_rect B / d) * ray_r / ray_r.z, which is rotated back by R1^T; its z
  is the depth.  An invalid SGBM disparity (or a ray falling outside the
  rectified image) stays invalid.
* Metric: the one `sweepdepth eval` prints for ICL (src/eval.rs
  depth_metrics): over pixels with ground truth, mean |z - gt| / gt over the
  valid estimates, % within 1 % / 5 % of gt with invalid pixels counted as
  not within, % invalid.  The ground truth is the reference's .depth file
  (ray distance, converted to z).
* --check-pfm DEPTH_PFM scores a depth.pfm written by
  `sweepdepth eval --save OUT` with this same code, as a cross-check of the
  metric against the numbers `eval` prints; --oracle feeds the ground-truth
  disparity of the rectified reference through the same path instead of
  SGBM's, to show what the rectification and mapping back cost by themselves.
"""

import argparse
import os
import sys
from pathlib import Path

import cv2
import numpy as np

DEFAULT_DATA_ROOT = Path(__file__).resolve().parent.parent.parent / "shared" / "data"

ICL_FOLDER = "iclnuim_livingroom_traj2_frames"
ICL_REFERENCE = "scene_00_0020"
ICL_NEIGHBOURS = ["scene_00_0010", "scene_00_0015", "scene_00_0025", "scene_00_0030"]

# name, folder, left, right, gt file, gt divisor, border, numDisparities, right view's gt file
DATASETS = [
    ("Tsukuba", "middlebury2001_tsukuba", "scene1.row3.col3.ppm", "scene1.row3.col4.ppm",
     "truedisp.row3.col3.pgm", 16.0, 18, 16, None),
    ("Teddy", "middlebury2003_teddy_9view", "im2.ppm", "im6.ppm",
     "disp2.pgm", 4.0, 10, 64, "disp6.pgm"),
    ("Laundry", "middlebury2005_Laundry_thirdsize", "view1.png", "view5.png",
     "disp1.png", 3.0, 10, 80, "disp5.png"),
]

NONOCC_TOLERANCE_PX = 1.0  # as src/datasets/middlebury.rs NONOCC_TOLERANCE_PX

MODES = {
    "HH": cv2.STEREO_SGBM_MODE_HH,
    "SGBM": cv2.STEREO_SGBM_MODE_SGBM,
    "3WAY": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "HH4": cv2.STEREO_SGBM_MODE_HH4,
}

BLOCK_SIZE = 5
MIN_DISPARITY = 0


def imread(path, flags):
    img = cv2.imread(str(path), flags)
    if img is None:
        sys.exit(f"error: cannot read {path}")
    return img


def run_sgbm(left, right, num_disp, mode, pad_left=False):
    if pad_left:
        # OpenCV SGBM leaves the leftmost minDisparity+numDisparities columns
        # invalid; optionally pad both images on the left and crop afterwards.
        pad = MIN_DISPARITY + num_disp
        left = cv2.copyMakeBorder(left, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
        right = cv2.copyMakeBorder(right, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
    cn = left.shape[2] if left.ndim == 3 else 1
    sgbm = cv2.StereoSGBM_create(
        minDisparity=MIN_DISPARITY,
        numDisparities=num_disp,
        blockSize=BLOCK_SIZE,
        P1=8 * cn * BLOCK_SIZE ** 2,
        P2=32 * cn * BLOCK_SIZE ** 2,
        disp12MaxDiff=1,
        preFilterCap=63,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=mode,
    )
    raw = sgbm.compute(left, right)  # CV_16S, disparity * 16
    if pad_left:
        raw = raw[:, pad:]
    valid = raw >= MIN_DISPARITY * 16
    disp = raw.astype(np.float64) / 16.0
    disp[~valid] = np.nan
    return disp, valid


def fill_holes(disp, valid):
    """Scanline fill: min(nearest valid left, nearest valid right)."""
    h, w = disp.shape
    out = disp.copy()
    idx = np.arange(w)
    for y in range(h):
        v = valid[y]
        if v.all():
            continue
        if not v.any():
            out[y] = 0.0
            continue
        row = disp[y]
        # index of the nearest valid pixel at or to the left (-1 if none)
        li = np.where(v, idx, -1)
        li = np.maximum.accumulate(li)
        # index of the nearest valid pixel at or to the right (w if none)
        ri = np.where(v, idx, w)
        ri = np.minimum.accumulate(ri[::-1])[::-1]
        lv = np.where(li >= 0, row[np.clip(li, 0, w - 1)], np.inf)
        rv = np.where(ri < w, row[np.clip(ri, 0, w - 1)], np.inf)
        out[y, ~v] = np.minimum(lv, rv)[~v]
    return out, np.ones_like(valid)


def nonocc_mask(gt_left, gt_right, known_left):
    """src/datasets/middlebury.rs nonocc_mask: left pixel x with disparity d is kept when the right view's
    ground truth at round(x - d) is known (> 0) and within NONOCC_TOLERANCE_PX of d."""
    h, w = gt_left.shape
    xs = np.arange(w)[None, :].repeat(h, axis=0)
    # Rust's f32::round rounds halves away from zero; x - d >= -0.5 matters only near 0.
    xr = np.floor(xs - gt_left + 0.5)
    xr = np.where(xs - gt_left < 0, -np.floor(-(xs - gt_left) + 0.5), xr).astype(np.int64)
    inside = known_left & (xr >= 0) & (xr < w)
    ys = np.arange(h)[:, None].repeat(w, axis=1)
    dr = np.zeros_like(gt_left)
    dr[inside] = gt_right[ys[inside], xr[inside]]
    return inside & (dr > 0) & (np.abs(gt_left - dr) <= NONOCC_TOLERANCE_PX)


def metrics(disp, valid, gt, mask):
    n = int(mask.sum())
    ev_valid = valid & mask
    err = np.abs(np.where(ev_valid, disp, 0.0) - gt)
    bad1 = ev_valid & (err > 1.0)
    bad2 = ev_valid & (err > 2.0)
    bad05 = ev_valid & (err > 0.5)
    inval = mask & ~valid
    nv = int(ev_valid.sum())
    # Precision (issue 29), as src/eval.rs: signed d - gt over the valid estimates; the RMS of all
    # of them and of those within 2 px (the inliers).
    signed = (np.where(ev_valid, disp, 0.0) - gt)[ev_valid]
    inl = signed[np.abs(signed) <= 2.0]
    nan = float("nan")
    return {
        "bad05": 100.0 * (bad05.sum() + inval.sum()) / n,
        "rms": float(np.sqrt(np.mean(signed ** 2))) if nv else nan,
        "rms_inliers": float(np.sqrt(np.mean(inl ** 2))) if inl.size else nan,
        "mean_signed": float(np.mean(signed)) if nv else nan,
        "n": n,
        "bad1": 100.0 * (bad1.sum() + inval.sum()) / n,
        "bad2": 100.0 * (bad2.sum() + inval.sum()) / n,
        "bad1_valid": 100.0 * bad1.sum() / nv if nv else float("nan"),
        "invalid": 100.0 * inval.sum() / n,
    }


# ---------------------------------------------------------------------------------------------
# ICL-NUIM


def icl_camera(txt_path, width, height):
    """(K, R_cw, C) of a POV-Ray .txt camera, as src/datasets/icl_nuim.rs povray_camera_model (fy < 0)."""
    fields = {}
    for line in Path(txt_path).read_text().splitlines():
        if "=" not in line:
            continue
        key, value = (part.strip() for part in line.split("=", 1))
        value = value.rstrip(";").rstrip().rstrip("'").strip().strip("[]")
        fields[key] = np.array([float(v) for v in value.replace(",", " ").split()])
    pos, cdir, up, right = (fields[k] for k in ("cam_pos", "cam_dir", "cam_up", "cam_right"))
    k = np.array([
        [width * np.linalg.norm(cdir) / np.linalg.norm(right), 0.0, (width - 1) / 2.0],
        [0.0, -height * np.linalg.norm(cdir) / np.linalg.norm(up), (height - 1) / 2.0],
        [0.0, 0.0, 1.0],
    ])
    z = cdir / np.linalg.norm(cdir)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r_wc = np.stack([x, y, z], axis=1)
    return k, r_wc.T, pos


def icl_image(path):
    """16-bit RGB PNG -> 8-bit BGR, rounded as image-rs' to_rgba8 (v * 255 / 65535)."""
    img = imread(path, cv2.IMREAD_UNCHANGED)
    if img.dtype == np.uint16:
        img = np.round(img.astype(np.float64) * 255.0 / 65535.0).astype(np.uint8)
    return img[:, :, :3]


def icl_gt_depth(depth_path, k, width, height):
    """Ray distances (row-major text) -> z-depth; <= 0 or non-finite -> NaN."""
    r = np.loadtxt(depth_path, dtype=np.float64).reshape(-1)
    if r.size != width * height:
        sys.exit(f"error: {depth_path}: {r.size} values, expected {width * height}")
    r = r.reshape(height, width)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    a = (u - k[0, 2]) / k[0, 0]
    b = (v - k[1, 2]) / k[1, 1]
    z = r / np.sqrt(a * a + b * b + 1.0)
    z[~(np.isfinite(z) & (z > 0))] = np.nan
    return z


def depth_metrics(depth, gt):
    """src/eval.rs depth_metrics: GT pixels only; invalid = not within."""
    evaluated = np.isfinite(gt) & (gt > 0)
    valid = evaluated & np.isfinite(depth) & (depth > 0)
    n = int(evaluated.sum())
    rel = np.abs(depth[valid] - gt[valid]) / gt[valid]
    return {
        "n": n,
        "absrel": float(rel.mean()) if rel.size else float("nan"),
        "within1": 100.0 * float((rel <= 0.01).sum()) / n,
        "within5": 100.0 * float((rel <= 0.05).sum()) / n,
        "invalid": 100.0 * (n - int(valid.sum())) / n,
    }


def read_pfm(path):
    """Single-channel PFM (rows bottom to top) -> float64 array, top row first."""
    data = Path(path).read_bytes()
    tokens, pos = [], 0
    while len(tokens) < 4:  # "Pf", width, height, scale; then one whitespace byte
        while data[pos:pos + 1].isspace():
            pos += 1
        start = pos
        while not data[pos:pos + 1].isspace():
            pos += 1
        tokens.append(data[start:pos].decode())
    pos += 1
    if tokens[0] != "Pf":
        sys.exit(f"error: {path}: not a single-channel PFM")
    w, h, scale = int(tokens[1]), int(tokens[2]), float(tokens[3])
    img = np.frombuffer(data, dtype="<f4" if scale < 0 else ">f4", count=w * h, offset=pos)
    return img.reshape(h, w)[::-1].astype(np.float64)


def icl_sgbm(root, neighbour, mode, oracle=False):
    """SGBM on (reference, neighbour), depth in the original reference camera (NaN invalid).

    oracle: instead of SGBM, the ground-truth disparity of the rectified reference (each GT
    point moved into the rectified frame and splatted to its nearest pixel), to check that the
    rectification and the mapping back lose nothing by themselves."""
    d = root / ICL_FOLDER
    ref_img = icl_image(d / f"{ICL_REFERENCE}.png")
    nb_img = icl_image(d / f"{neighbour}.png")
    h, w = ref_img.shape[:2]
    k1, r1_cw, c1 = icl_camera(d / f"{ICL_REFERENCE}.txt", w, h)
    k2, r2_cw, c2 = icl_camera(d / f"{neighbour}.txt", w, h)
    gt = icl_gt_depth(d / f"{ICL_REFERENCE}.depth", k1, w, h)
    flip = np.diag([1.0, -1.0, 1.0])
    k1f, k2f = k1.copy(), k2.copy()
    k1f[1, 1], k2f[1, 1] = -k1[1, 1], -k2[1, 1]
    r_rel = flip @ r2_cw @ r1_cw.T @ flip
    t_rel = flip @ r2_cw @ (c1 - c2)
    assert abs(np.linalg.det(r_rel) - 1.0) < 1e-9
    zero = np.zeros(5)
    r1, r2, p1, p2, _q, _roi1, _roi2 = cv2.stereoRectify(
        k1f, zero, k2f, zero, (w, h), r_rel, t_rel.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=1.0)
    m1 = cv2.initUndistortRectifyMap(k1f, zero, r1, p1[:, :3], (w, h), cv2.CV_32FC1)
    m2 = cv2.initUndistortRectifyMap(k2f, zero, r2, p2[:, :3], (w, h), cv2.CV_32FC1)
    ref_r = cv2.remap(ref_img, m1[0], m1[1], cv2.INTER_LINEAR)
    nb_r = cv2.remap(nb_img, m2[0], m2[1], cv2.INTER_LINEAR)
    f_r = p1[0, 0]
    baseline = abs(p2[0, 3] / p2[0, 0])
    mirrored = p2[0, 3] > 0  # the neighbour is left of the reference
    if mirrored:
        ref_r, nb_r = ref_r[:, ::-1].copy(), nb_r[:, ::-1].copy()
    ndisp = int(np.ceil(f_r * baseline / np.nanmin(gt) / 16.0)) * 16
    # Every original reference pixel's ray, in the rectified frame.
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.linalg.inv(k1f) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    rays_r = r1 @ rays
    if oracle:
        points_r = rays_r * gt.ravel()  # the flipped ray has z = 1: gt z scales it
        q = p1[:, :3] @ points_r
        ok = np.isfinite(points_r[2]) & (points_r[2] > 0)
        qu = np.rint(q[0, ok] / q[2, ok]).astype(np.int64)
        qv = np.rint(q[1, ok] / q[2, ok]).astype(np.int64)
        inside = (qu >= 0) & (qu < w) & (qv >= 0) & (qv < h)
        disp = np.full((h, w), np.nan)
        disp[qv[inside], qu[inside]] = f_r * baseline / points_r[2, ok][inside]
        valid = np.isfinite(disp)
    else:
        disp, valid = run_sgbm(ref_r, nb_r, ndisp, mode)
        if mirrored:
            disp, valid = disp[:, ::-1], valid[:, ::-1]
    # Each original reference pixel takes the disparity at its nearest rectified pixel.
    q = p1[:, :3] @ rays_r
    qu = np.rint(q[0] / q[2]).astype(np.int64)
    qv = np.rint(q[1] / q[2]).astype(np.int64)
    inside = (qu >= 0) & (qu < w) & (qv >= 0) & (qv < h) & (rays_r[2] > 0)
    dq = np.full(u.size, np.nan)
    dq[inside] = np.where(valid[qv[inside], qu[inside]], disp[qv[inside], qu[inside]], np.nan)
    dq[~(dq > 0)] = np.nan  # disparity 0 = infinitely far: no depth
    z_r = f_r * baseline / dq
    x_r = rays_r / rays_r[2] * z_r
    x_ref = r1.T @ x_r  # flipped-y reference frame: z is the reference camera's z
    depth = x_ref[2].reshape(h, w)
    info = {
        "baseline_cm": 100.0 * np.linalg.norm(c1 - c2),
        "ndisp": ndisp,
        "disp_range": (f_r * baseline / np.nanmax(gt), f_r * baseline / np.nanmin(gt)),
        "mirrored": bool(mirrored),
        "sgbm_invalid": 100.0 * (1.0 - valid.mean()),
    }
    return depth, gt, info


def main_icl(args):
    root = Path(args.data_root)
    d = root / ICL_FOLDER
    print(f"OpenCV {cv2.__version__}, numpy {np.__version__}; StereoSGBM mode={args.mode}, "
          f"blockSize={BLOCK_SIZE}, P1=8*3*bs^2, P2=32*3*bs^2, uniquenessRatio=10, "
          f"speckleWindowSize=100, speckleRange=2, disp12MaxDiff=1, preFilterCap=63")
    print(f"data: {d.resolve()}; reference {ICL_REFERENCE}; metric over GT pixels, "
          "invalid = not within"
          + ("; ORACLE: ground-truth disparity instead of SGBM" if args.oracle else ""))
    print()
    if args.check_pfm:
        k1, _, _ = icl_camera(d / f"{ICL_REFERENCE}.txt", 640, 480)
        gt = icl_gt_depth(d / f"{ICL_REFERENCE}.depth", k1, 640, 480)
        m = depth_metrics(read_pfm(args.check_pfm), gt)
        print(f"{args.check_pfm}: GT px {m['n']}, absrel {m['absrel']:.4f}, "
              f"within 1% {m['within1']:.2f}%, within 5% {m['within5']:.2f}%, "
              f"invalid {m['invalid']:.2f}%")
        return
    print("| pair | baseline | disparity range (px) | numDisparities | GT px | mean abs rel "
          "| within 1 % | within 5 % | invalid % |")
    print("|---|---|---|---|---|---|---|---|---|")
    for nb in ICL_NEIGHBOURS:
        depth, gt, info = icl_sgbm(root, nb, MODES[args.mode], oracle=args.oracle)
        m = depth_metrics(depth, gt)
        lo, hi = info["disp_range"]
        print(f"| {ICL_REFERENCE} / {nb} | {info['baseline_cm']:.1f} cm | {lo:.1f}..{hi:.1f} "
              f"| {info['ndisp']} | {m['n']} | {m['absrel']:.4f} | {m['within1']:.2f} "
              f"| {m['within5']:.2f} | {m['invalid']:.2f} |")


TIME_NUM_DISPARITIES = 32
REPO_TSUKUBA = Path(__file__).resolve().parent.parent / "data" / "tsukuba"


def synthetic_pair(width, height, num_disp):
    """A textured pair of the given size (mono8 as a ROS stereo camera sends, as BGR for SGBM):
    smooth noise, the right view shifted by a quarter of the disparity range."""
    rng = np.random.default_rng(7)
    noise = rng.random((height // 4 + 2, width // 4 + 2)).astype(np.float32)
    texture = cv2.resize(noise, (width + num_disp, height + 8), interpolation=cv2.INTER_CUBIC)
    grey = np.clip(texture * 255.0, 0, 255).astype(np.uint8)
    shift = max(1, num_disp // 4)
    left = cv2.cvtColor(np.ascontiguousarray(grey[:height, shift:shift + width]), cv2.COLOR_GRAY2BGR)
    right = cv2.cvtColor(np.ascontiguousarray(grey[:height, :width]), cv2.COLOR_GRAY2BGR)
    return left, right


def rectification_maps(width, height):
    """image_geometry's StereoCameraModel path for a raw pair: plumb_bob intrinsics (the mild
    barrel `sweepdepth bench` renders with), 10 cm baseline, cv2.stereoRectify then
    cv2.initUndistortRectifyMap per camera (made once per calibration, as a driver does)."""
    f = 0.8 * width
    k = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]], np.float64)
    d = np.array([-0.12, 0.02, 0.0, 0.0, 0.0])
    r = cv2.Rodrigues(np.array([0.0, 0.01, 0.0]))[0]
    t = np.array([[-0.1], [0.0], [0.0]])
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(k, d, k, d, (width, height), r, t, alpha=0)
    return [cv2.initUndistortRectifyMap(k, d, ri, pi, (width, height), cv2.CV_16SC2)
            for ri, pi in ((r1, p1), (r2, p2))]


def main_time(args):
    import json
    import time

    if args.size:
        width, height = args.size
        num_disp = max(16, -(-args.num_disp // 16) * 16)
        left, right = synthetic_pair(width, height, num_disp)
        pair = f"synthetic {'raw plumb_bob (remap + SGBM)' if args.rectify else 'rectified'} pair"
    else:
        left = imread(REPO_TSUKUBA / "scene1.row3.col3.png", cv2.IMREAD_COLOR)
        right = imread(REPO_TSUKUBA / "scene1.row3.col4.png", cv2.IMREAD_COLOR)
        num_disp = TIME_NUM_DISPARITIES
        pair = "Tsukuba scene1.row3.col3 / col4"
    maps = rectification_maps(left.shape[1], left.shape[0]) if args.rectify else None
    mode = cv2.STEREO_SGBM_MODE_SGBM_3WAY

    def one():
        l, r = left, right
        if maps is not None:
            l = cv2.remap(l, maps[0][0], maps[0][1], cv2.INTER_LINEAR)
            r = cv2.remap(r, maps[1][0], maps[1][1], cv2.INTER_LINEAR)
        run_sgbm(l, r, num_disp, mode)

    one()
    times_ms = []
    for _ in range(max(1, args.repeats)):
        started = time.perf_counter()
        one()
        times_ms.append((time.perf_counter() - started) * 1e3)
    times_ms.sort()
    n = len(times_ms)
    median = times_ms[n // 2] if n % 2 else 0.5 * (times_ms[n // 2 - 1] + times_ms[n // 2])
    result = {
        "peer": "OpenCV StereoSGBM MODE_SGBM_3WAY",
        "opencv": cv2.__version__,
        "threads": cv2.getNumThreads(),
        "pair": pair,
        "width": int(left.shape[1]),
        "height": int(left.shape[0]),
        "num_disparities": num_disp,
        "runs": n,
        "ms_median": round(median, 3),
        "ms_min": round(times_ms[0], 3),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['peer']} (OpenCV {result['opencv']}, {result['threads']} threads) on "
              f"{result['pair']} {result['width']}x{result['height']}, {num_disp} "
              f"disparities: median {median:.2f} ms over {n} runs (min {times_ms[0]:.2f} ms)")


def write_pfm(path, disp):
    """Single-channel little-endian PFM, rows bottom first (NaN stays NaN)."""
    h, w = disp.shape
    with open(path, "wb") as f:
        f.write(f"Pf\n{w} {h}\n-1.0\n".encode())
        f.write(np.ascontiguousarray(np.flipud(disp).astype("<f4")).tobytes())


def main_pair(args):
    """The peer of `sweepdepth eval --peer sgbm`: SGBM on one rectified pair, its disparity
    (px, NaN invalid) into a PFM, and the time of the compute call."""
    import json
    import time

    left_path, right_path = args.pair
    left = imread(left_path, cv2.IMREAD_COLOR)
    right = imread(right_path, cv2.IMREAD_COLOR)
    num_disp = max(16, -(-args.num_disp // 16) * 16)
    started = time.perf_counter()
    disp, _ = run_sgbm(left, right, num_disp, MODES[args.mode])
    ms = (time.perf_counter() - started) * 1e3
    write_pfm(args.out, disp.astype(np.float32))
    print(json.dumps({"mode": args.mode, "num_disparities": num_disp, "ms": round(ms, 3),
                      "opencv": cv2.__version__}))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data_root", nargs="?", default=str(DEFAULT_DATA_ROOT),
                    help=f"data root (default: {DEFAULT_DATA_ROOT})")
    ap.add_argument("--mode", choices=sorted(MODES), default="HH",
                    help="StereoSGBM mode (default HH)")
    ap.add_argument("--pad-left", action="store_true",
                    help="NOT part of the protocol (supplementary): replicate-pad both images "
                         "on the left by numDisparities so SGBM does not blank the leftmost "
                         "numDisparities columns")
    ap.add_argument("--mask", choices=["all", "nonocc"], default="all",
                    help="evaluated pixels: all with ground truth (the protocol), or only the "
                         "non-occluded ones (left-right check of the two ground-truth maps, "
                         "as `sweepdepth eval --mask nonocc`; Teddy and Laundry only)")
    ap.add_argument("--icl", action="store_true",
                    help="ICL-NUIM mode: rectify the reference with each neighbour frame, SGBM, "
                         "depth mapped back into the reference camera, eval's depth metric")
    ap.add_argument("--check-pfm", metavar="DEPTH_PFM",
                    help="with --icl: score a depth.pfm from `sweepdepth eval --save` instead")
    ap.add_argument("--oracle", action="store_true",
                    help="with --icl: the rectified ground-truth disparity instead of SGBM's "
                         "(checks the rectification and the mapping back)")
    ap.add_argument("--time", action="store_true",
                    help="speed peer: time SGBM 3-way on the repo's Tsukuba pair, 32 disparities")
    ap.add_argument("--repeats", type=int, default=21, help="with --time: timed runs")
    ap.add_argument("--size", type=int, nargs=2, metavar=("W", "H"),
                    help="with --time: a synthetic pair of this size instead of Tsukuba "
                         "(--num-disp disparities)")
    ap.add_argument("--rectify", action="store_true",
                    help="with --time --size: a raw plumb_bob pair, each view remapped "
                         "(cv2.remap with image_geometry's rectification maps) before SGBM")
    ap.add_argument("--json", action="store_true", help="with --time: one JSON object")
    ap.add_argument("--pair", nargs=2, metavar=("LEFT", "RIGHT"),
                    help="one rectified pair: SGBM's disparity into --out (PFM, px, NaN "
                         "invalid), a JSON line with its time on stdout (`sweepdepth eval "
                         "--peer sgbm`)")
    ap.add_argument("--num-disp", type=int, default=64,
                    help="with --pair: disparities searched (rounded up to a multiple of 16)")
    ap.add_argument("--out", help="with --pair: the disparity PFM to write")
    args = ap.parse_args()
    if args.pair:
        if not args.out:
            sys.exit("error: --pair needs --out")
        main_pair(args)
        return
    if args.time:
        main_time(args)
        return
    if args.icl:
        main_icl(args)
        return
    root = Path(args.data_root)

    rows = []
    for name, folder, lf, rf, gf, div, border, ndisp, rgf in DATASETS:
        d = root / folder
        left = imread(d / lf, cv2.IMREAD_COLOR)
        right = imread(d / rf, cv2.IMREAD_COLOR)
        gt_raw = imread(d / gf, cv2.IMREAD_UNCHANGED)
        if gt_raw.ndim != 2 or gt_raw.dtype != np.uint8:
            sys.exit(f"error: unexpected GT format {gt_raw.shape} {gt_raw.dtype} in {gf}")
        if gt_raw.shape != left.shape[:2] or left.shape != right.shape:
            sys.exit(f"error: size mismatch in {folder}")
        gt = gt_raw.astype(np.float64) / div
        gt_max = gt.max()
        if gt_max >= MIN_DISPARITY + ndisp:
            print(f"warning: {name}: GT max {gt_max:.2f} >= numDisparities {ndisp}",
                  file=sys.stderr)

        mask = gt_raw > 0
        if args.mask == "nonocc":
            if rgf is None:
                print(f"{name}: skipped, no ground truth for {rf} (no left-right check)",
                      file=sys.stderr)
                continue
            mask &= nonocc_mask(gt, imread(d / rgf, cv2.IMREAD_UNCHANGED).astype(np.float64) / div,
                                gt_raw > 0)
        mask[:border, :] = False
        mask[-border:, :] = False
        mask[:, :border] = False
        mask[:, -border:] = False

        disp, valid = run_sgbm(left, right, ndisp, MODES[args.mode], args.pad_left)
        pair = f"{lf} / {rf}"
        rows.append((name, pair, ndisp, "raw", metrics(disp, valid, gt, mask)))
        fdisp, fvalid = fill_holes(disp, valid)
        rows.append((name, pair, ndisp, "filled", metrics(fdisp, fvalid, gt, mask)))

    print(f"OpenCV {cv2.__version__}, numpy {np.__version__}; StereoSGBM mode={args.mode}, "
          f"blockSize={BLOCK_SIZE}, P1=8*3*bs^2, P2=32*3*bs^2, uniquenessRatio=10, "
          f"speckleWindowSize=100, speckleRange=2, disp12MaxDiff=1, preFilterCap=63"
          + ("; SUPPLEMENTARY --pad-left (not the protocol)" if args.pad_left else "")
          + ("; non-occluded pixels only (left-right check of the two GT maps, 1 px)"
             if args.mask == "nonocc" else ""))
    print(f"data root: {root.resolve()}")
    print()
    print("| dataset | pair | numDisparities | variant | eval px | bad>0.5 % | bad>1 % | bad>2 % "
          "| bad>1 % (valid only) | invalid % | RMS px | RMS within 2 px | mean signed px |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, pair, ndisp, variant, m in rows:
        print(f"| {name} | {pair} | {ndisp} | {variant} | {m['n']} | {m['bad05']:.2f} "
              f"| {m['bad1']:.2f} | {m['bad2']:.2f} | {m['bad1_valid']:.2f} | {m['invalid']:.2f} "
              f"| {m['rms']:.3f} | {m['rms_inliers']:.3f} | {m['mean_signed']:+.3f} |")


if __name__ == "__main__":
    main()
