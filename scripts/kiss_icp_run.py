#!/usr/bin/env python3
"""Run the pip-installed KISS-ICP (default config, deskew off) on a sequence folder laid out like
../shared/data/lidar/kitti-seq and write its poses in KITTI format. Prints `ms_per_frame T`
(time inside KissICP.register_frame only, file loading excluded), as our `slam eval` measures.

usage: kiss_icp_run.py DIR OUT_POSES [FRAMES] [--every N]
       kiss_icp_run.py --pair DIR OUT_MATRIX

--pair registers DIR/source.ply to DIR/target.ply (laid out like
../shared/data/lidar/registration-pair): target is fed first, then source from the identity, and
the 4x4 target<-source is written; prints `ms_total T` (both register_frame calls).

--every N uses every N-th scan of the first FRAMES (as `robot-agent slam eval --every N`).
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


PLY_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "<u1",
             "uint8": "<u1", "char": "<i1", "int8": "<i1", "ushort": "<u2", "uint16": "<u2",
             "short": "<i2", "int16": "<i2", "uint": "<u4", "uint32": "<u4", "int": "<i4",
             "int32": "<i4"}


def read_ply_xyz(path: Path) -> np.ndarray:
    """x, y, z of the vertex element of a PLY file (binary little endian or ascii, vertex first)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    fmt, n, props, in_vertex = None, 0, [], False
    for line in raw[:end].decode("ascii").splitlines():
        w = line.split()
        if not w:
            continue
        if w[0] == "format":
            fmt = w[1]
        elif w[0] == "element":
            in_vertex = w[1] == "vertex"
            if in_vertex:
                n = int(w[2])
        elif w[0] == "property" and in_vertex:
            if w[1] == "list":
                raise SystemExit(f"{path}: list properties in vertices are not supported")
            props.append((w[2], PLY_TYPES[w[1]]))
    dtype = np.dtype(props)
    if fmt == "binary_little_endian":
        arr = np.frombuffer(raw, dtype=dtype, count=n, offset=end)
    elif fmt == "ascii":
        arr = np.loadtxt(raw[end:].decode().splitlines()[:n], dtype=dtype, ndmin=1)
    else:
        raise SystemExit(f"{path}: unsupported PLY format {fmt}")
    xyz = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
    return xyz[np.isfinite(xyz).all(axis=1)]


def pair(seq: Path, out: Path) -> None:
    config = load_config(None)
    config.data.deskew = False
    odom = KissICP(config=config)
    clouds = [read_ply_xyz(seq / "target.ply"), read_ply_xyz(seq / "source.ply")]
    total = 0.0
    for xyz in clouds:
        t0 = time.perf_counter()
        odom.register_frame(xyz, np.zeros(len(xyz)))
        total += time.perf_counter() - t0
    with out.open("w") as f:
        for row in odom.last_pose:
            f.write(" ".join(f"{v:.9f}" for v in row) + "\n")
    print(f"ms_total {1e3 * total:.3f}")


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "--pair":
        pair(Path(sys.argv[2]), Path(sys.argv[3]))
        return
    args = sys.argv[1:]
    every = 1
    if "--every" in args:
        i = args.index("--every")
        every = int(args[i + 1])
        if every < 1:
            raise SystemExit("--every wants a positive integer")
        del args[i : i + 2]
    seq, out = Path(args[0]), Path(args[1])
    files = sorted((seq / "clouds").glob("*.pcd"))
    if len(args) > 2:
        files = files[: int(args[2])]
    files = files[::every]
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
