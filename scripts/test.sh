#!/usr/bin/env bash
# Runs every test of bdft-lab on a fresh Debian machine with the Rust toolchain.
# The README's test command; CI (.ci/run) calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."

# The browser tests drive Debian's headless Chromium through chromedriver; the HTTPS test
# reads the server's certificate with openssl (an independent reading of its fingerprint).
missing=()
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
command -v chromedriver >/dev/null 2>&1 || missing+=(chromium-driver)
command -v openssl >/dev/null 2>&1 || missing+=(openssl)
if [ ${#missing[@]} -gt 0 ]; then
  echo "installing ${missing[*]} (Debian packages) for the tests"
  SUDO=""
  if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi

# Style and lints first: they are part of the test (and the cheapest to fail).
cargo fmt --all -- --check
cargo clippy --workspace --all-targets --locked -- -D warnings

# The end-to-end tests (tests/) run the product's binaries as real processes; cargo test
# does not rebuild another package's binaries, so build them first.
cargo build --workspace --bins --locked
cargo test --workspace --locked "$@"
