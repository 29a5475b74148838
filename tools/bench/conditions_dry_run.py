#!/usr/bin/env python3
"""The default study on the thesis's stilts and in the field (docs/machine-conditions.md,
issue 41): what a lab would see running it on a machine on tires.

Runs `bdft-server pilot --condition C` for each condition (a fresh database each, the same
seed, so the same synthetic people), exports the trials, and prints per compensator and
seat the median over subjects of the mean-squared tracking error and cab acceleration
(valid latest attempts, as the study's statistics count them), and how many tests the
cab-vibration interlock stopped. A condition under which a design is unstable with the
body is run with `--acknowledge-instability` (simulation only), and says so. The numbers
are computed here with Python's `statistics` from the trials export, not by the server.

Usage (from the repo root, after `cargo build -p bdft-server`):
    python3 tools/bench/conditions_dry_run.py [--subjects 8] [--seed 11]
        [--conditions stilts,tires]
Only the standard library is needed.
"""

import argparse
import csv
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

BIN = Path(__file__).resolve().parents[2] / "target" / "debug" / "bdft-server"
COMPENSATORS = ["pid", "pid-notch", "pid-shaper", "lqr", "lqr-cabvel"]


def pilot(d, condition, subjects, seed):
    """Runs the pilot; returns whether the instability had to be acknowledged."""
    args = [str(BIN), "pilot", "--db", "p.db", "--subjects", str(subjects), "--seed", str(seed),
            "--condition", condition]
    out = subprocess.run(args, cwd=d, capture_output=True, text=True)
    if out.returncode == 0:
        return False
    if "unstable" not in out.stderr:
        sys.exit(f"pilot on {condition}: {out.stderr}")
    Path(d, "p.db").unlink()
    out = subprocess.run(args + ["--acknowledge-instability",
                                 f"the default study's designs on {condition}, in simulation"],
                         cwd=d, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"pilot on {condition}: {out.stderr}")
    return True


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--subjects", type=int, default=8)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--conditions", default="stilts,tires")
    a = ap.parse_args()
    table = {}
    for condition in a.conditions.split(","):
        with tempfile.TemporaryDirectory() as d:
            acked = pilot(d, condition, a.subjects, a.seed)
            out = subprocess.run([str(BIN), "export", "--db", "p.db", "--kind", "trials",
                                  "--out", "t.csv"], cwd=d, capture_output=True, text=True)
            if out.returncode != 0:
                sys.exit(out.stderr)
            rows = list(csv.DictReader(open(Path(d) / "t.csv")))
        tests = [r for r in rows if r["phase"] == "test" and r["latest"] == "1"]
        assert all(r["condition"] == condition for r in tests), condition
        table[condition] = (acked, tests)
    print(f"pilot: {a.subjects} subjects, seed {a.seed}")
    print()
    print("| condition | compensator | seat | valid | MSE tracking (mm²), median "
          "| mean-square cab acc. (10⁵ (mm/s²)²), median | stopped by the interlock |")
    print("|---|---|---|---:|---:|---:|---:|")
    for condition, (acked, tests) in table.items():
        label = condition + (" (instability acknowledged)" if acked else "")
        for c in COMPENSATORS:
            for seat in ["on", "off"]:
                cell = [r for r in tests if r["compensator"] == c and r["seat"] == seat]
                valid = [r for r in cell if r["valid"] == "1"]
                stopped = sum(r["status_reason"].startswith("cab vibration") for r in cell)
                mse = statistics.median(float(r["mse_tracking_mm2"]) for r in valid) if valid else float("nan")
                acc = statistics.median(float(r["ms_cab_accel_mm2_s4"]) for r in valid) / 1e5 if valid else float("nan")
                print(f"| {label} | {c} | {seat} | {len(valid)}/{len(cell)} | {mse:.1f} | {acc:.2f} | {stopped} |")


if __name__ == "__main__":
    main()
