#!/usr/bin/env python3
"""The peer of `sweepdepth bench --fusion`: Open3D's VoxelBlockGrid TSDF integration on the CPU.

Reads what the bench wrote into a folder (`frames.json`, and per frame `depth_N.npy`, float32
metres with 0 where invalid, and `colour_N.npy`, uint8 HxWx3, given to Open3D as float32 0..1
beside the float depth), and times the same steps as the
bench on the same depth maps, each the median of `--repeats` runs after one warm-up:

- `integrate_first`: frame 0 into an empty grid (`compute_unique_block_coordinates` then
  `integrate`, the tutorial's two calls; the grid made beforehand, untimed);
- `integrate_steady`: frame 1 into a grid that already holds frame 0 (made untimed);
- `extract_mesh`: `extract_triangle_mesh` of that grid (Open3D meshes the whole grid; it has no
  incremental meshing).

for each block resolution asked (`--block-resolutions 8,16`), on `CPU:0` (OpenMP over every
core). Prints one JSON object. Needs `open3d` (pip `open3d-cpu`, about 600 MB with numpy).
"""

import argparse
import json
import os
import statistics
import sys
import time


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    parser.add_argument("folder", help="the folder the bench wrote (frames.json and .npy files)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--block-resolutions", default="8,16")
    args = parser.parse_args()

    import numpy as np
    import open3d as o3d
    import open3d.core as o3c

    with open(os.path.join(args.folder, "frames.json")) as f:
        spec = json.load(f)
    device = o3c.Device("CPU:0")
    intrinsic = o3c.Tensor(np.array(spec["intrinsic"], dtype=np.float64))
    frames = []
    for i, frame in enumerate(spec["frames"]):
        depth = np.load(os.path.join(args.folder, f"depth_{i}.npy")).astype(np.float32)
        # Open3D takes (float depth, float colour) or (uint16 depth, uint8 colour).
        colour = np.load(os.path.join(args.folder, f"colour_{i}.npy")).astype(np.float32) / 255.0
        frames.append(
            (
                o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(depth), device=device)),
                o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(colour), device=device)),
                o3c.Tensor(np.array(frame["cam_from_world"], dtype=np.float64)),
            )
        )
    voxel = float(spec["voxel_size_m"])
    trunc = float(spec["truncation_voxels"])
    depth_max = float(spec["max_depth_m"])

    def new_grid(block_resolution):
        return o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=voxel,
            block_resolution=block_resolution,
            block_count=(20000 if block_resolution <= 8 else 4000),
            device=device,
        )

    def integrate(grid, frame):
        depth, colour, extrinsic = frame
        t0 = time.perf_counter()
        coords = grid.compute_unique_block_coordinates(
            depth, intrinsic, extrinsic, 1.0, depth_max, trunc
        )
        t1 = time.perf_counter()
        grid.integrate(coords, depth, colour, intrinsic, extrinsic, 1.0, depth_max, trunc)
        t2 = time.perf_counter()
        return (t2 - t0) * 1e3, (t1 - t0) * 1e3, coords.shape[0]

    results = []
    for res in [int(r) for r in args.block_resolutions.split(",") if r]:
        first, first_alloc, steady, steady_alloc, mesh = [], [], [], [], []
        blocks = triangles = 0
        for run in range(args.repeats + 1):
            grid = new_grid(res)
            ms, alloc, _ = integrate(grid, frames[0])
            if run > 0:
                first.append(ms)
                first_alloc.append(alloc)
            ms, alloc, blocks = integrate(grid, frames[1])
            if run > 0:
                steady.append(ms)
                steady_alloc.append(alloc)
            t0 = time.perf_counter()
            m = grid.extract_triangle_mesh(weight_threshold=0.0)
            t1 = time.perf_counter()
            triangles = int(m.triangle.indices.shape[0]) if "indices" in m.triangle else 0
            if run > 0:
                mesh.append((t1 - t0) * 1e3)
        results.append(
            {
                "block_resolution": res,
                "integrate_first_ms": statistics.median(first),
                "integrate_first_block_coords_ms": statistics.median(first_alloc),
                "integrate_steady_ms": statistics.median(steady),
                "integrate_steady_block_coords_ms": statistics.median(steady_alloc),
                "extract_mesh_ms": statistics.median(mesh),
                "blocks_in_frame": int(blocks),
                "triangles": triangles,
            }
        )
    print(
        json.dumps(
            {
                "peer": "Open3D VoxelBlockGrid (t.geometry) TSDF integration, CPU:0",
                "open3d": o3d.__version__,
                "threads": os.cpu_count(),
                "runs": args.repeats,
                "results": results,
            }
        )
    )


if __name__ == "__main__":
    sys.exit(main())
