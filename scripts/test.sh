#!/usr/bin/env bash
# Runs every test of bdft-lab on a fresh Debian machine with the Rust toolchain.
# The README's test command; CI (.ci/run) calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."

# The end-to-end tests (tests/) run the product's binaries as real processes; cargo test
# does not rebuild another package's binaries, so build them first.
cargo build --workspace --bins --locked
cargo test --workspace --locked "$@"
