#!/usr/bin/env bash
# Before every commit: formatting and clippy with warnings as errors, in the release profile the
# tests use (so its build scripts and proc-macros are shared with the test build).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo fmt --all -- --check
cargo clippy --release --workspace --all-targets -- -D warnings
