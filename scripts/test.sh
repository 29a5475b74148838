#!/usr/bin/env bash
# Runs every test of bdft-lab on a fresh Debian machine with the Rust toolchain.
# The README's test command; CI (.ci/run) calls exactly this.
# `--slow` adds the 20-minute soak (on SQLite, after the rest); any other argument goes to
# `cargo test` (a test name, `-- --nocapture`, …). The other tests marked #[ignore] are run
# by name: each says why it is not in the suite.
set -euo pipefail
cd "$(dirname "$0")/.."

slow=0
args=()
for a in "$@"; do
  if [ "$a" = "--slow" ]; then slow=1; else args+=("$a"); fi
done

# The browser tests drive Debian's headless Chromium through chromedriver; the HTTPS test
# reads the server's certificate with openssl (an independent reading of its fingerprint).
missing=()
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
command -v chromedriver >/dev/null 2>&1 || missing+=(chromium-driver)
command -v openssl >/dev/null 2>&1 || missing+=(openssl)
# The LSL test runs in a network namespace of its own (unshare, util-linux; ip, iproute2).
command -v ip >/dev/null 2>&1 || missing+=(iproute2)
# The store's dialect test runs against a PostgreSQL server of its own (Debian's postgresql).
pg_bin() { ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1; }
[ -x "$(pg_bin)/initdb" ] || missing+=(postgresql)
if [ ${#missing[@]} -gt 0 ]; then
  echo "installing ${missing[*]} (Debian packages) for the tests"
  SUDO=""
  if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi

# The BIDS test checks an export with the BIDS validator (PyPI's bids-validator-deno, which
# brings deno), run offline in a network namespace; pinned, installed once into target/.
BIDS_VENV=target/tools/bids-validator
if [ ! -x "$BIDS_VENV/bin/bids-validator-deno" ]; then
  echo "installing bids-validator-deno (PyPI) into $BIDS_VENV for the BIDS test"
  python3 -m venv "$BIDS_VENV"
  "$BIDS_VENV/bin/pip" install -q "bids-validator-deno==3.0.2"
fi

# The LSL test reads the server's streams with pylsl (PyPI; its wheel bundles liblsl), in a
# network namespace; pinned, installed once into target/.
LSL_VENV=target/tools/pylsl
if ! "$LSL_VENV/bin/python" -c "import pylsl" >/dev/null 2>&1; then
  echo "installing pylsl (PyPI) into $LSL_VENV for the LSL test"
  python3 -m venv "$LSL_VENV"
  "$LSL_VENV/bin/pip" install -q "pylsl==1.18.6"
fi

# A PostgreSQL server for this run only: a fresh cluster in a private directory, listening on
# a Unix socket there and on no TCP port, stopped when the run ends. PostgreSQL refuses to run
# as root, so as root it runs as the package's postgres user. The tests find it through
# BDFT_TEST_POSTGRES and fail (never skip) without it.
PG_BIN=$(pg_bin)
PG_DIR=$(mktemp -d /tmp/bdft-pg.XXXXXX)
AS_PG=()
if [ "$(id -u)" = 0 ]; then
  chown postgres "$PG_DIR"
  AS_PG=(runuser -u postgres --)
fi
"${AS_PG[@]}" "$PG_BIN/initdb" -D "$PG_DIR/data" -U bdft -A trust -E UTF8 --no-sync >/dev/null
"${AS_PG[@]}" "$PG_BIN/pg_ctl" -D "$PG_DIR/data" -l "$PG_DIR/log" -w -s \
  -o "-c listen_addresses='' -k $PG_DIR -c fsync=off -c max_connections=200" start
stop_pg() {
  "${AS_PG[@]}" "$PG_BIN/pg_ctl" -D "$PG_DIR/data" -m fast -w -s stop || true
  rm -rf "$PG_DIR"
}
trap stop_pg EXIT
export BDFT_TEST_POSTGRES="postgres:///postgres?host=$PG_DIR&user=bdft"

# Style and lints first: they are part of the test (and the cheapest to fail).
cargo fmt --all -- --check
cargo clippy --workspace --all-targets --locked -- -D warnings

# The end-to-end tests (tests/) run the product's binaries as real processes; cargo test
# does not rebuild another package's binaries, so build them first.
cargo build --workspace --bins --locked
cargo test --workspace --locked ${args[@]+"${args[@]}"}

# The same end-to-end tests again with every server on a PostgreSQL database of its own
# (the multi-site store), but for these, named with why, never skipped silently:
pg_skips=(
  # They start no server: nothing of theirs touches a store.
  "controller_cli::" "controller_estop::" "controller_identification::"
  "controller_input_udp::" "controller_link_loss::" "controller_messages::"
  "controller_rig_udp::" "controller_starts::" "controller_trials::" "structure::"
  "env_sample::"
  # They run on PostgreSQL (or both stores) already in the first pass.
  "store_dialects::" "backups::on_postgresql" "audit_chain::on_postgresql"
  # A backup is a SQLite file (refused on PostgreSQL, which backups::on_postgresql_… tests).
  "backups::backups_taken_while_a_pilot_runs"
  "backups::a_restore_refuses_a_running_server"
  "backups::a_server_stopped_as_soon_as_it_is_up"
  "backups::scheduled_backups_keep_the_newest"
  "backups::relative_backup_paths_two_levels_up_work"
  # It checks the modes of the SQLite file, its backup and its restore.
  "file_modes::a_servers_keys_and_data_are_its_own_and_ignored_by_git"
  # Its fixtures are earlier releases' SQLite files.
  "upgrade::"
  # They tamper with copies of the SQLite file (audit_chain::on_postgresql_… do the same
  # with copies of a PostgreSQL database).
  "audit_chain::audit_verify_names_every_kind_of_tampering"
  "audit_chain::audit_verify_names_the_forgeries_of_issue_37"
  # Its disk-full fault caps the SQLite file's page count (PostgreSQL has no such cap: its
  # full-disk SQLSTATE is answered as SQLite's is, which no test here makes happen).
  "soak::"
)
echo "again on PostgreSQL: the end-to-end tests but ${pg_skips[*]}"
pg_args=(${args[@]+"${args[@]}"})
case " ${pg_args[*]-} " in
  *" -- "*) ;;
  *) pg_args+=(--) ;;
esac
for s in "${pg_skips[@]}"; do pg_args+=(--skip "$s"); done
BDFT_TEST_STORE=postgres cargo test -p bdft-tests --test integration --locked "${pg_args[@]}"

if [ "$slow" = 1 ]; then
  echo "the slow set: the lab-day soak"
  cargo test -p bdft-tests --test integration --locked soak:: -- --ignored
fi
