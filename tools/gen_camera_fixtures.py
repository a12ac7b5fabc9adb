#!/usr/bin/env python3
"""Camera-model fixtures for `tests/formats/camera_conventions.rs`, from OpenCV and image_geometry.

Writes `tests/fixtures/camera/opencv.json`:

- `cameras`: plumb_bob and equidistant cameras (mild, strong barrel, strong pincushion, a mild
  fisheye and a 190-degree-class fisheye). For rays from the optical axis out to the edge of
  where each model is defined (the image for plumb_bob, 89.5 degrees for the fisheye), the
  pixel OpenCV projects them to (`cv2.projectPoints`, `cv2.fisheye.projectPoints`, zero
  rvec/tvec), and OpenCV's undistortion of that pixel (`cv2.undistortPoints` and
  `cv2.fisheye.undistortPoints` with tight criteria: 100 iterations, eps 1e-14) with whether
  it recovered the ray (`opencv_recovers`: its own projection of its answer lands within
  1e-6 px of the pixel).
- `rectify`: a stereo pair rectified by `cv2.stereoRectify`, and for a grid of raw pixels of
  each camera the rectified pixel `cv2.undistortPoints(raw, K, D, R, P)` gives (tight criteria): the
  call image_geometry's `PinholeCameraModel::rectifyPoint` makes, fully converged; `rectifyPoint`
  itself passes OpenCV's default criteria (5 iterations) on float32 points, so it returns a
  less converged value than this fixture.

and `tests/fixtures/camera/image_geometry.json`: CameraInfo cases (ROI, binning) with the K and
P image_geometry uses for the image, computed by `image_geometry_from_camera_info` below, a
line-for-line transcription of `PinholeCameraModel::fromCameraInfo` and `reducedResolution`
(ros-perception/vision_opencv, branch rolling, image_geometry/src/pinhole_camera_model.cpp):
binning 0 is 1; an ROI of all zeros is the full image; the principal points of K and P move by
the ROI offset, then fx, cx and P's Tx are divided by binning_x (fy, cy, Ty by binning_y); the
image is the ROI divided by the binning, rounded down.

Usage (from the crate root; opencv-python-headless is pinned in tools/requirements-test.txt):

    target/test-venv/bin/python3 tools/gen_camera_fixtures.py          # write the fixtures
    target/test-venv/bin/python3 tools/gen_camera_fixtures.py --check  # compare, exit 1 if stale

Everything is deterministic (no random numbers), so `--check` regenerates the same numbers on
the same OpenCV version; across versions the comparison allows 1e-9 px.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

import cv2
import numpy as np

OUT = pathlib.Path(__file__).resolve().parent.parent / "tests" / "fixtures" / "camera"
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


def k_matrix(fx, fy, cx, cy):
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def radial_fold(model, d):
    """The undistorted radius (plumb_bob) or angle (equidistant) where the radial function stops
    increasing, or None: the first positive root of its derivative, a polynomial in s = v²."""
    if model == "plumb_bob":
        k1, k2, _, _, k3 = d
        coefficients = [1.0, 3 * k1, 5 * k2, 7 * k3]
    else:
        k1, k2, k3, k4 = d
        coefficients = [1.0, 3 * k1, 5 * k2, 7 * k3, 9 * k4]
    roots = np.roots(coefficients[::-1]) if any(coefficients[1:]) else []
    positive = [r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
    if not positive:
        return None
    return math.sqrt(min(positive))


def project(model, k, d, points):
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 1, 3)
    zero = np.zeros(3)
    if model == "plumb_bob":
        pixels, _ = cv2.projectPoints(pts, zero, zero, k, np.asarray(d))
    else:
        pixels, _ = cv2.fisheye.projectPoints(pts, zero, zero, k, np.asarray(d))
    return pixels.reshape(-1, 2)


def undistort(model, k, d, pixels):
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if model == "plumb_bob":
        out = cv2.undistortPoints(px, k, np.asarray(d), criteria=CRITERIA)
    else:
        out = cv2.fisheye.undistortPoints(px, k, np.asarray(d), criteria=CRITERIA)
    return out.reshape(-1, 2)


CAMERAS = [
    # name, model, width, height, (fx, fy, cx, cy), D
    ("plumb_bob_mild", "plumb_bob", 640, 480, (500.0, 505.0, 319.7, 241.3),
     [-0.28, 0.07, 0.001, -0.0005, 0.0]),
    ("plumb_bob_strong_barrel", "plumb_bob", 640, 480, (520.0, 518.0, 322.1, 238.4),
     [-0.42, 0.21, 0.001, 0.0015, -0.05]),
    ("plumb_bob_strong_pincushion", "plumb_bob", 640, 480, (900.0, 900.0, 320.5, 240.5),
     [0.9, 0.6, 0.002, -0.003, 0.4]),
    ("equidistant_mild", "equidistant", 640, 480, (300.0, 300.0, 319.5, 239.5),
     [0.01, -0.005, 0.001, 0.0]),
    ("equidistant_190", "equidistant", 1280, 1024, (330.0, 330.0, 640.0, 512.0),
     [-0.013, 0.021, -0.014, 0.0026]),
]


def camera_fixture(name, model, width, height, intr, d):
    k = k_matrix(*intr)
    fx, fy, cx, cy = intr
    fold = radial_fold(model, d)
    if model == "plumb_bob":
        # Out to the image's farthest corner (pixel edges), inside the fold.
        corners = [((x - cx) / fx, (y - cy) / fy) for x in (-0.5, width - 0.5)
                   for y in (-0.5, height - 0.5)]
        reach = max(math.hypot(*c) for c in corners)
        limit = reach * 1.6  # the undistorted radius may be larger; filtered by the image below
        if fold is not None:
            limit = min(limit, 0.995 * fold)
        max_angle = math.degrees(math.atan(limit))
    else:
        max_angle = 89.5
        if fold is not None:
            max_angle = min(max_angle, 0.995 * math.degrees(fold))
    samples = []
    angles = [0.0, 0.5, 2.0] + [float(a) for a in range(5, int(max_angle) + 1, 5)] + [max_angle]
    for i, angle in enumerate(angles):
        for j, azimuth in enumerate((0.0, 33.0, 90.0, 161.0, 245.0, 300.0)):
            if angle == 0.0 and j > 0:
                continue
            r = math.tan(math.radians(angle))
            a = math.radians(azimuth)
            depth = 1.0 + 0.37 * ((i + j) % 5)
            samples.append([r * math.cos(a) * depth, r * math.sin(a) * depth, depth])
    pixels = project(model, k, d, samples)
    undistorted = undistort(model, k, d, pixels)
    back = project(model, k, d, [[x, y, 1.0] for x, y in undistorted])
    rows = []
    for point, pixel, und, again in zip(samples, pixels, undistorted, back):
        if model == "plumb_bob" and not (-0.5 <= pixel[0] <= width - 0.5
                                         and -0.5 <= pixel[1] <= height - 0.5):
            continue
        rows.append({
            "point": point,
            "pixel": [float(pixel[0]), float(pixel[1])],
            "opencv_undistorted": [float(und[0]), float(und[1])],
            "opencv_recovers": bool(np.hypot(*(again - pixel)) < 1e-6),
        })
    return {
        "name": name,
        "model": model,
        "width": width,
        "height": height,
        "fx": fx, "fy": fy, "cx": cx, "cy": cy,
        "d": d,
        "samples": rows,
    }


def rectify_fixture():
    """A stereo pair, rectified by OpenCV; raw -> rectified pixels as rectifyPoint maps them."""
    width, height = 640, 480
    k1 = k_matrix(510.0, 508.0, 318.2, 243.9)
    d1 = np.array([-0.21, 0.05, 0.0007, -0.0004, 0.0])
    k2 = k_matrix(505.0, 506.5, 323.4, 236.1)
    d2 = np.array([-0.19, 0.04, -0.0006, 0.0009, 0.0])
    rvec = np.array([0.012, -0.035, 0.008])
    rotation, _ = cv2.Rodrigues(rvec)
    translation = np.array([[-0.12], [0.004], [-0.002]])
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(
        k1, d1, k2, d2, (width, height), rotation, translation, alpha=0.0,
        flags=cv2.CALIB_ZERO_DISPARITY)
    cameras = []
    for name, k, d, r, p in (("left", k1, d1, r1, p1), ("right", k2, d2, r2, p2)):
        grid = [[float(x), float(y)] for y in range(0, height, 60) for x in range(0, width, 80)]
        grid += [[width - 1.0, height - 1.0], [0.0, height - 1.0]]
        raw = np.asarray(grid).reshape(-1, 1, 2)
        rect = cv2.undistortPoints(raw, k, d, R=r, P=p, criteria=CRITERIA).reshape(-1, 2)
        cameras.append({
            "name": name,
            "width": width,
            "height": height,
            "k": [float(v) for v in k.flatten()],
            "d": [float(v) for v in d],
            "r": [float(v) for v in r.flatten()],
            "p": [float(v) for v in p.flatten()],
            "points": [{"raw": g, "rect": [float(v[0]), float(v[1])]}
                       for g, v in zip(grid, rect)],
        })
    return cameras


def image_geometry_from_camera_info(width, height, k, p, binning_x, binning_y, roi):
    """PinholeCameraModel::fromCameraInfo's K_ and P_, and reducedResolution()."""
    binning_x = binning_x if binning_x else 1  # "Binning = 0 is considered the same as 1"
    binning_y = binning_y if binning_y else 1
    x_offset, y_offset, roi_width, roi_height = roi
    if (x_offset, y_offset, roi_width, roi_height) == (0, 0, 0, 0):
        roi_width, roi_height = width, height  # "ROI all zeros ... same as full resolution"
    k_ = list(k)
    p_ = list(p)
    if x_offset != 0 or y_offset != 0:  # adjust_roi: "Move principal point by the offset"
        k_[2] -= x_offset
        k_[5] -= y_offset
        p_[2] -= x_offset
        p_[6] -= y_offset
    if binning_x > 1:
        scale_x = 1.0 / binning_x
        k_[0] *= scale_x
        k_[2] *= scale_x
        p_[0] *= scale_x
        p_[2] *= scale_x
        p_[3] *= scale_x
    if binning_y > 1:
        scale_y = 1.0 / binning_y
        k_[4] *= scale_y
        k_[5] *= scale_y
        p_[5] *= scale_y
        p_[6] *= scale_y
        p_[7] *= scale_y
    # reducedResolution(): the (raw, do_rectify false) ROI divided by the binning.
    size = [roi_width // binning_x, roi_height // binning_y]
    return k_, p_, size


def image_geometry_fixture():
    k = [612.5, 0.0, 331.25, 0.0, 610.0, 247.75, 0.0, 0.0, 1.0]
    p = [598.0, 0.0, 329.5, -71.76, 0.0, 598.0, 249.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    cases = []
    for name, binning_x, binning_y, roi in (
        ("full", 0, 0, (0, 0, 0, 0)),
        ("binning_1", 1, 1, (0, 0, 0, 0)),
        ("binning_2x2", 2, 2, (0, 0, 0, 0)),
        ("binning_4x2", 4, 2, (0, 0, 0, 0)),
        ("binning_3x3_odd_size", 3, 3, (0, 0, 0, 0)),
        ("roi", 0, 0, (100, 40, 400, 300)),
        ("roi_full_size", 0, 0, (0, 0, 640, 480)),
        ("roi_then_binning_2x2", 2, 2, (101, 41, 401, 301)),
        ("roi_then_binning_4x2", 4, 2, (96, 32, 448, 320)),
    ):
        k_, p_, size = image_geometry_from_camera_info(640, 480, k, p, binning_x, binning_y, roi)
        cases.append({
            "name": name,
            "width": 640, "height": 480, "k": k, "p": p,
            "binning_x": binning_x, "binning_y": binning_y,
            "roi": list(roi),
            "expected_k": k_,
            "expected_p": p_,
            "expected_size": size,
        })
    return {
        "source": "ros-perception/vision_opencv (rolling), image_geometry/src/"
                  "pinhole_camera_model.cpp: PinholeCameraModel::fromCameraInfo, "
                  "reducedResolution",
        "cases": cases,
    }


def fixtures():
    header = {
        "generator": "tools/gen_camera_fixtures.py",
        "opencv": cv2.__version__,
    }
    opencv = dict(header)
    opencv["cameras"] = [camera_fixture(*c) for c in CAMERAS]
    opencv["rectify"] = rectify_fixture()
    geometry = {"generator": "tools/gen_camera_fixtures.py"}
    geometry.update(image_geometry_fixture())
    return {"opencv.json": opencv, "image_geometry.json": geometry}


def close(a, b, path="$"):
    """Equal structure, numbers within 1e-9 (absolute); returns the first difference or None."""
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return f"{path}: keys {sorted(a)} vs {sorted(b)}"
        for key in a:
            if key == "opencv":
                continue
            diff = close(a[key], b[key], f"{path}.{key}")
            if diff:
                return diff
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path}: {len(a)} vs {len(b)} entries"
        for i, (x, y) in enumerate(zip(a, b)):
            diff = close(x, y, f"{path}[{i}]")
            if diff:
                return diff
        return None
    if isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str):
        return None if a == b else f"{path}: {a!r} vs {b!r}"
    if abs(float(a) - float(b)) <= 1e-9:
        return None
    return f"{path}: {a!r} vs {b!r}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="compare with the stored fixtures instead of writing them")
    args = parser.parse_args()
    stale = False
    for name, content in fixtures().items():
        path = OUT / name
        if args.check:
            stored = json.loads(path.read_text())
            diff = close(content, stored)
            if diff:
                print(f"{path}: differs from what OpenCV {cv2.__version__} gives: {diff}")
                stale = True
            else:
                print(f"{path}: reproduced")
        else:
            OUT.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(content, indent=1) + "\n")
            if name == "opencv.json":
                for camera in content["cameras"]:
                    samples = camera["samples"]
                    failed = [s for s in samples if not s["opencv_recovers"]]
                    print(f"{camera['name']}: {len(samples)} rays, OpenCV's undistortion "
                          f"misses {len(failed)}")
            print(f"wrote {path}")
    sys.exit(1 if stale else 0)


if __name__ == "__main__":
    main()
