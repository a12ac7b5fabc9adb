#!/usr/bin/env python3
"""OpenCV StereoSGBM baseline on three Middlebury stereo pairs (standalone).

Run (from anywhere):

    pip install opencv-python-headless numpy
    python3 tools/sgbm_baseline.py [DATA_ROOT] [--mode HH|SGBM|3WAY|HH4] [--pad-left]

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
"""

import argparse
import os
import sys
from pathlib import Path

import cv2
import numpy as np

DEFAULT_DATA_ROOT = Path(__file__).resolve().parent.parent.parent / "shared" / "data"

# name, folder, left, right, gt file, gt divisor, border, numDisparities
DATASETS = [
    ("Tsukuba", "middlebury2001_tsukuba", "scene1.row3.col3.ppm", "scene1.row3.col4.ppm",
     "truedisp.row3.col3.pgm", 16.0, 18, 16),
    ("Teddy", "middlebury2003_teddy_9view", "im2.ppm", "im6.ppm",
     "disp2.pgm", 4.0, 10, 64),
    ("Laundry", "middlebury2005_Laundry_thirdsize", "view1.png", "view5.png",
     "disp1.png", 3.0, 10, 80),
]

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


def metrics(disp, valid, gt, mask):
    n = int(mask.sum())
    ev_valid = valid & mask
    err = np.abs(np.where(ev_valid, disp, 0.0) - gt)
    bad1 = ev_valid & (err > 1.0)
    bad2 = ev_valid & (err > 2.0)
    inval = mask & ~valid
    nv = int(ev_valid.sum())
    return {
        "n": n,
        "bad1": 100.0 * (bad1.sum() + inval.sum()) / n,
        "bad2": 100.0 * (bad2.sum() + inval.sum()) / n,
        "bad1_valid": 100.0 * bad1.sum() / nv if nv else float("nan"),
        "invalid": 100.0 * inval.sum() / n,
    }


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
    args = ap.parse_args()
    root = Path(args.data_root)

    rows = []
    for name, folder, lf, rf, gf, div, border, ndisp in DATASETS:
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
          + ("; SUPPLEMENTARY --pad-left (not the protocol)" if args.pad_left else ""))
    print(f"data root: {root.resolve()}")
    print()
    print("| dataset | pair | numDisparities | variant | eval px | bad>1 % | bad>2 % "
          "| bad>1 % (valid only) | invalid % |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, pair, ndisp, variant, m in rows:
        print(f"| {name} | {pair} | {ndisp} | {variant} | {m['n']} | {m['bad1']:.2f} "
              f"| {m['bad2']:.2f} | {m['bad1_valid']:.2f} | {m['invalid']:.2f} |")


if __name__ == "__main__":
    main()
