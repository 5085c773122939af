#!/usr/bin/env python3
"""Run the pip-installed KISS-ICP (default config, deskew off) on a sequence folder laid out like
../shared/data/lidar/kitti-seq and write its poses in KITTI format. Prints `ms_per_frame T`
(time inside KissICP.register_frame only, file loading excluded), as our `slam eval` measures.

usage: kiss_icp_run.py DIR OUT_POSES [FRAMES]
"""
import sys
import time
from pathlib import Path

import numpy as np
from kiss_icp.config import load_config
from kiss_icp.kiss_icp import KissICP

TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "<u1", ("U", 2): "<u2", ("U", 4): "<u4",
         ("I", 1): "<i1", ("I", 2): "<i2", ("I", 4): "<i4"}


def read_pcd_xyz(path: Path) -> np.ndarray:
    """x, y, z of a PCD v0.7 file (ascii or binary)."""
    raw = path.read_bytes()
    header = {}
    pos = 0
    while True:
        end = raw.index(b"\n", pos)
        line = raw[pos:end].decode("ascii").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
    names = header["FIELDS"]
    sizes = [int(s) for s in header["SIZE"]]
    types = header["TYPE"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
    n = int(header["POINTS"][0])
    dtype = np.dtype([(f"{nm}_{i}" if c > 1 else nm, TYPES[(t, s)], (c,) if c > 1 else ())
                      for i, (nm, s, t, c) in enumerate(zip(names, sizes, types, counts))])
    if header["DATA"][0] == "binary":
        arr = np.frombuffer(raw, dtype=dtype, count=n, offset=pos)
    elif header["DATA"][0] == "ascii":
        arr = np.loadtxt(raw[pos:].decode().splitlines(), dtype=dtype, ndmin=1)
    else:
        raise SystemExit(f"{path}: unsupported DATA {header['DATA'][0]}")
    xyz = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
    return xyz[np.isfinite(xyz).all(axis=1)]


def main() -> None:
    seq, out = Path(sys.argv[1]), Path(sys.argv[2])
    files = sorted((seq / "clouds").glob("*.pcd"))
    if len(sys.argv) > 3:
        files = files[: int(sys.argv[3])]
    config = load_config(None)
    config.data.deskew = False
    odom = KissICP(config=config)
    clouds = [read_pcd_xyz(f) for f in files]
    poses = []
    total = 0.0
    for xyz in clouds:
        t0 = time.perf_counter()
        odom.register_frame(xyz, np.zeros(len(xyz)))
        total += time.perf_counter() - t0
        poses.append(odom.last_pose.copy())
    with out.open("w") as f:
        for p in poses:
            f.write(" ".join(f"{v:.9f}" for v in p[:3, :].reshape(-1)) + "\n")
    print(f"ms_per_frame {1e3 * total / max(len(files), 1):.3f}")


if __name__ == "__main__":
    main()
