#!/usr/bin/env bash
# The README's test command: sets up what a fresh machine lacks, builds, and runs every test.
#
#   scripts/test.sh            all tests (unit, cross-process, scenario, browser)
#
# Tests and binaries use the release profile: simulation, ICP and mapping are too slow unoptimised,
# and one profile compiles the dependencies once.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '\n== %s\n' "$*" >&2; }

# Browser tests drive Debian's chromium (never a downloaded browser).
if ! command -v chromium >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        say "installing chromium (browser tests)"
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >/dev/null
    else
        say "chromium missing and cannot install it (not root): browser tests will be skipped"
    fi
fi

# The UI's npm dependencies (Leaflet; playwright-core for the browser tests), from the lock file.
if [ -f web/package-lock.json ] && command -v npm >/dev/null 2>&1; then
    if [ ! -d web/node_modules ] || [ web/package-lock.json -nt web/node_modules ]; then
        say "installing web UI dependencies (npm ci)"
        npm ci --prefix web --no-audit --no-fund --loglevel=error
    fi
fi

# tests/gnss_io.rs runs Debian's gpsd and socat; tests/ros2_io.rs checks our CDR against rosbags.
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    # command:package (tests/netns.rs needs `ip` and `tc` from iproute2)
    for cp in gpsd:gpsd socat:socat ip:iproute2 tc:iproute2; do
        c="${cp%%:*}" p="${cp#*:}"
        command -v "$c" >/dev/null 2>&1 || { say "installing $p"; apt-get update -qq; DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "$p" >/dev/null; }
    done
fi
python3 -c 'import rosbags' 2>/dev/null || { say "installing rosbags (pip)"; python3 -m pip install -q rosbags || pip install -q rosbags; }
# tests/record.rs reads recordings with an independent MCAP reader and validates their messages.
python3 -c 'import mcap, jsonschema' 2>/dev/null || { say "installing mcap, jsonschema (pip)"; python3 -m pip install -q mcap jsonschema || pip install -q mcap jsonschema; }

# Binaries and tests in one build: `cargo test` does not build every binary the cross-process
# tests start, and a separate `--bins` build resolves features without the dev-dependencies, so
# zenoh, axum and every workspace crate would be compiled twice (23 units, measured with
# `--unit-graph`).
say "building binaries and tests (release)"
cargo build --release --workspace --bins --tests

say "running tests (release)"
cargo test --release --workspace "$@"
