#!/usr/bin/env bash
# Side-by-side SLAM benchmark: terranav ICP vs KISS-ICP (pip package `kiss-icp`, default config,
# deskew off) on the same sequence, in one run. Prints a table with ratios.
#
#   scripts/bench-slam.sh [DIR] [CONFIG] [ROUNDS]
#
# DIR defaults to ../shared/data/lidar/kitti-seq, CONFIG to config/slam-kitti.toml. Each tool runs
# ROUNDS times (default 3), alternating, and the fastest round of each is reported: the machine is
# shared, and the minimum is the estimate least disturbed by other load. Accuracy is identical
# across rounds (both are deterministic). Time = registration only, file loading excluded.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
dir="${1:-$root/../shared/data/lidar/kitti-seq}"
config="${2:-$root/config/slam-kitti.toml}"
rounds="${3:-3}"
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

(cd "$root" && cargo build --release -q -p robot-agent)
bin="${CARGO_TARGET_DIR:-$root/target}/release/robot-agent"

for r in $(seq 1 "$rounds"); do
    if [ "$have_kiss" = 1 ]; then
        "$venv/bin/python" "$root/scripts/kiss_icp_run.py" "$dir" "$out/kiss_poses.txt" \
            | awk '{print $2}' >> "$out/kiss_ms.$$"
    fi
    "$bin" slam eval "$dir" --config "$config" --json --write-poses "$out/ours_poses.txt" 2>/dev/null \
        | tail -n 1 >> "$out/ours.$$"
done

kiss_json="{}"
if [ "$have_kiss" = 1 ]; then
    kiss_json="$("$bin" slam eval "$dir" --score-poses "$out/kiss_poses.txt" --json)"
fi
python3 - "$out/ours.$$" "$out/kiss_ms.$$" "$kiss_json" <<'PY'
import json, sys, os
ours = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
best = min(ours, key=lambda o: o["ms_per_frame"])
kiss = json.loads(sys.argv[3])
if os.path.exists(sys.argv[2]):
    kiss["ms_per_frame"] = min(float(l) for l in open(sys.argv[2]) if l.strip())
rows = [("ate_m", "ATE (m)"), ("rpe_m", "RPE (m/frame)"), ("rpe_deg", "RPE (deg/frame)"),
        ("drift_pct", "drift (%)"), ("ms_per_frame", "time (ms/frame)")]
print(f"frames {best['frames']}  path {best['path_m']:.1f} m  (rounds: {len(ours)}, fastest shown)")
print(f"{'metric':<18}{'terranav':>12}{'KISS-ICP':>12}{'KISS/ours':>12}")
for key, name in rows:
    o = best[key]
    k = kiss.get(key)
    if k is None:
        print(f"{name:<18}{o:>12.4f}{'n/a':>12}{'':>12}")
    else:
        ratio = k / o if o else float("inf")
        print(f"{name:<18}{o:>12.4f}{k:>12.4f}{ratio:>12.2f}")
print("all times (ms/frame): ours", [round(o["ms_per_frame"], 2) for o in ours])
PY
if [ -f "$out/kiss_ms.$$" ]; then echo "all times (ms/frame): KISS-ICP $(tr '\n' ' ' < "$out/kiss_ms.$$")"; fi
rm -f "$out/ours.$$" "$out/kiss_ms.$$"
