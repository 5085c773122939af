#!/usr/bin/env bash
# Side-by-side SLAM benchmark: terranav ICP vs KISS-ICP (pip package `kiss-icp`, default config,
# deskew off) on the same data, in one run. Prints one table per case with ratios:
#
#   1. the sequence DIR (10 Hz KITTI: ../shared/data/lidar/kitti-seq),
#   2. the same sequence thinned to every 5th scan (`slam eval --every 5`: 2 Hz, ~4 m apart),
#   3. the registration pair PAIR (../shared/data/lidar/registration-pair) from the identity:
#      error against its T_target_source.txt, time of the whole pair (filters + registration).
#
#   scripts/bench-slam.sh [DIR] [CONFIG] [ROUNDS] [PAIR]
#
# CONFIG defaults to config/slam.toml (the one default configuration, "auto" keys). Each tool
# runs ROUNDS times per case (default 3), alternating, and the fastest round of each is
# reported: the machine is shared, and the minimum is the estimate least disturbed by other
# load. Accuracy is identical across rounds (both are deterministic). Time = registration only,
# file loading excluded.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
dir="${1:-$root/../shared/data/lidar/kitti-seq}"
config="${2:-$root/config/slam.toml}"
rounds="${3:-3}"
pair="${4:-$root/../shared/data/lidar/registration-pair}"
venv="$root/target/kiss-venv"
out="$root/target/bench-slam"
mkdir -p "$out"

if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import kiss_icp" 2>/dev/null; then
    echo "installing kiss-icp into $venv ..." >&2
    python3 -m venv "$venv" && "$venv/bin/pip" install -q kiss-icp >&2 || {
        echo "kiss-icp could not be installed; running ours only" >&2
    }
fi
have_kiss=0
"$venv/bin/python" -c "import kiss_icp" 2>/dev/null && have_kiss=1

# The CI build (the same feature set as `--workspace --bins --tests`, so nothing rebuilds).
(cd "$root" && nice -n 19 cargo build --release -q --workspace --bins --tests)
bin="${CARGO_TARGET_DIR:-$root/target}/release/robot-agent"

# bench_seq LABEL EVERY: one sequence case.
bench_seq() {
    local label="$1" every="$2"
    rm -f "$out/ours.$$" "$out/kiss_ms.$$"
    for _ in $(seq 1 "$rounds"); do
        if [ "$have_kiss" = 1 ]; then
            "$venv/bin/python" "$root/scripts/kiss_icp_run.py" "$dir" "$out/kiss_poses.txt" \
                --every "$every" | awk '{print $2}' >> "$out/kiss_ms.$$"
        fi
        "$bin" slam eval "$dir" --config "$config" --every "$every" --json \
            --write-poses "$out/ours_poses.txt" 2>/dev/null | tail -n 1 >> "$out/ours.$$"
    done
    local kiss_json="{}"
    if [ "$have_kiss" = 1 ]; then
        kiss_json="$("$bin" slam eval "$dir" --every "$every" --score-poses "$out/kiss_poses.txt" --json)"
    fi
    python3 - "$label" "$out/ours.$$" "$out/kiss_ms.$$" "$kiss_json" <<'PY'
import json, sys, os
label = sys.argv[1]
ours = [json.loads(l) for l in open(sys.argv[2]) if l.strip()]
best = min(ours, key=lambda o: o["ms_per_frame"])
kiss = json.loads(sys.argv[4])
kiss_ms = []
if os.path.exists(sys.argv[3]):
    kiss_ms = [float(l) for l in open(sys.argv[3]) if l.strip()]
    kiss["ms_per_frame"] = min(kiss_ms)
rows = [("ate_m", "ATE (m)"), ("rpe_m", "RPE (m/frame)"), ("rpe_deg", "RPE (deg/frame)"),
        ("drift_pct", "drift (%)"), ("ms_per_frame", "time (ms/frame)")]
print(f"== {label}: frames {best['frames']}  path {best['path_m']:.1f} m  "
      f"(rounds: {len(ours)}, fastest shown; ours: {best.get('recovered', 0)} recovered, "
      f"{best.get('fell_back', 0)} on the prior)")
print(f"{'metric':<18}{'terranav':>12}{'KISS-ICP':>12}{'KISS/ours':>12}")
for key, name in rows:
    o = best[key]
    k = kiss.get(key)
    if k is None:
        print(f"{name:<18}{o:>12.4f}{'n/a':>12}{'':>12}")
    else:
        ratio = k / o if o else float("inf")
        print(f"{name:<18}{o:>12.4f}{k:>12.4f}{ratio:>12.2f}")
print("all times (ms/frame): ours", [round(o["ms_per_frame"], 2) for o in ours],
      "KISS-ICP", [round(k, 2) for k in kiss_ms])
PY
    rm -f "$out/ours.$$" "$out/kiss_ms.$$"
}

bench_seq "$(basename "$dir")" 1
bench_seq "$(basename "$dir") --every 5" 5

# The registration pair, from the identity.
if [ -f "$pair/T_target_source.txt" ]; then
    rm -f "$out/pair_ours_ms.$$" "$out/pair_kiss_ms.$$"
    for _ in $(seq 1 "$rounds"); do
        if [ "$have_kiss" = 1 ]; then
            "$venv/bin/python" "$root/scripts/kiss_icp_run.py" --pair "$pair" "$out/pair_kiss.txt" \
                | awk '{print $2}' >> "$out/pair_kiss_ms.$$"
        fi
        "$bin" slam register "$pair/source.ply" "$pair/target.ply" --config "$config" \
            > "$out/pair_ours.txt" 2> "$out/pair_ours.err" || true
        sed -n 's/.* ms \([0-9.]*\)$/\1/p' "$out/pair_ours.err" >> "$out/pair_ours_ms.$$"
    done
    python3 - "$pair/T_target_source.txt" "$out/pair_ours.txt" "$out/pair_kiss.txt" \
        "$out/pair_ours_ms.$$" "$out/pair_kiss_ms.$$" "$have_kiss" <<'PY'
import math, sys, os
def mat(path):
    v = [float(x) for x in open(path).read().split()][:16]
    return [v[0:4], v[4:8], v[8:12], v[12:16]]
def err(ref, est):
    # ref^-1 * est for rigid 4x4: R = Rr^T Re, t = Rr^T (te - tr)
    rr = [[ref[i][j] for j in range(3)] for i in range(3)]
    re = [[est[i][j] for j in range(3)] for i in range(3)]
    r = [[sum(rr[k][i] * re[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    dt = [est[i][3] - ref[i][3] for i in range(3)]
    t = math.sqrt(sum(x * x for x in dt))
    # atan2 of the skew and symmetric parts: exact for small angles even when the reference
    # (printed with 6 digits) is not quite orthonormal, where acos of the trace is not.
    s = math.sqrt((r[2][1] - r[1][2]) ** 2 + (r[0][2] - r[2][0]) ** 2 + (r[1][0] - r[0][1]) ** 2) / 2
    c = (r[0][0] + r[1][1] + r[2][2] - 1) / 2
    return t, math.degrees(math.atan2(s, c))
ref = mat(sys.argv[1])
def best(path):
    if not os.path.exists(path):
        return None
    v = [float(l) for l in open(path) if l.strip()]
    return min(v) if v else None
rows = {}
try:
    rows["terranav"] = err(ref, mat(sys.argv[2])) + (best(sys.argv[4]),)
except (ValueError, IndexError, FileNotFoundError):
    rows["terranav"] = (float("nan"), float("nan"), best(sys.argv[4]))
if sys.argv[6] == "1":
    rows["KISS-ICP"] = err(ref, mat(sys.argv[3])) + (best(sys.argv[5]),)
o = rows["terranav"]
k = rows.get("KISS-ICP")
print(f"== {os.path.basename(os.path.dirname(sys.argv[1]))} (from the identity)")
print(f"{'metric':<18}{'terranav':>12}{'KISS-ICP':>12}{'KISS/ours':>12}")
for i, name in enumerate(["error (m)", "error (deg)", "time (ms/pair)"]):
    if k is None or k[i] is None or o[i] is None:
        print(f"{name:<18}{o[i] if o[i] is not None else float('nan'):>12.4f}{'n/a':>12}")
    else:
        print(f"{name:<18}{o[i]:>12.4f}{k[i]:>12.4f}{(k[i] / o[i] if o[i] else float('inf')):>12.2f}")
PY
    rm -f "$out/pair_ours_ms.$$" "$out/pair_kiss_ms.$$"
fi
