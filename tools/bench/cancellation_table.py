#!/usr/bin/env python3
"""The cancellation dry run's table (docs/cancellation.md, issue 38).

Runs `bdft-server pilot --cancellation ARMS` on the default study (a fresh database in a
temporary directory), exports its trials, and prints per compensator on the machine the
median over subjects of the mean-squared tracking error and of the ISO 2631-1 weighted cab
acceleration a_w, uncancelled and with each arm, with the paired median change and how many
subjects had both (only valid latest attempts count, as in the study's statistics), and the
share of cancelling tests not run (body not identified, or the model failed its check).
The numbers are computed here with Python's `statistics` from the trials export, not by the
server. Then the power plan of the comparison from the pilot's spread: per arm and metric,
`bdft-server plan --source pilot --cancellation ARM` (each compensator against itself
cancelled, exact Wilcoxon, Holm across the five), at `--plan-subjects`.

Usage (from the repo root, after `cargo build -p bdft-server`):
    python3 tools/bench/cancellation_table.py [--subjects 12] [--seed 11]
        [--arms personal,generic,wrong] [--wrong-gain 1.3] [--wrong-phase-lag-deg 0]
        [--plan-subjects 12,24,48] [--plan-draws 2000]
Only the standard library is needed.
"""

import argparse
import csv
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

BIN = Path(__file__).resolve().parents[2] / "target" / "debug" / "bdft-server"
COMPENSATORS = ["pid", "pid-notch", "pid-shaper", "lqr", "lqr-cabvel"]


def run(args, cwd):
    out = subprocess.run([str(BIN), *args], cwd=cwd, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"{' '.join(args)}: {out.stderr}")
    return out.stdout


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--subjects", type=int, default=12)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--arms", default="personal,generic,wrong")
    ap.add_argument("--wrong-gain", type=float)
    ap.add_argument("--wrong-phase-lag-deg", type=float)
    ap.add_argument("--plan-subjects", default="12,24,48")
    ap.add_argument("--plan-draws", type=int, default=2000)
    a = ap.parse_args()
    arms = a.arms.split(",")
    with tempfile.TemporaryDirectory() as d:
        pilot = ["pilot", "--db", "p.db", "--subjects", str(a.subjects), "--seed", str(a.seed),
                 "--cancellation", a.arms]
        if a.wrong_gain is not None:
            pilot += ["--wrong-gain", str(a.wrong_gain)]
        if a.wrong_phase_lag_deg is not None:
            pilot += ["--wrong-phase-lag-deg", str(a.wrong_phase_lag_deg)]
        run(pilot, d)
        run(["export", "--db", "p.db", "--kind", "trials", "--out", "t.csv"], d)
        rows = list(csv.DictReader(open(Path(d) / "t.csv")))
        plans = {}
        for arm in arms:
            for metric in ["mse_tracking_mm2", "ms_cab_accel"]:
                out = subprocess.run(
                    [str(BIN), "plan", "--db", "p.db", "--source", "pilot", "--cancellation", arm,
                     "--metric", metric, "--subjects", a.plan_subjects,
                     "--draws", str(a.plan_draws)],
                    cwd=d, capture_output=True, text=True)
                # Too few subjects with every cell of an arm is the planner's honest 409.
                plans[(arm, metric)] = (json.loads(out.stdout) if out.returncode == 0
                                        else out.stderr.strip().splitlines()[-1])
    on = [r for r in rows if r["phase"] == "test" and r["seat"] == "on"]
    cancelling = [r for r in on if r["cancellation"] != "off" and r["latest"] == "1"]
    not_run = [r for r in cancelling if r["status_reason"].startswith("not run:")]
    counted = [r for r in on if r["valid"] == "1" and r["latest"] == "1"]
    cell = {}
    for r in counted:
        cell[(r["compensator"], r["cancellation"], r["subject_code"])] = (
            float(r["mse_tracking_mm2"]), float(r["cab_aw_m_s2"]))
    subjects = sorted({r["subject_code"] for r in counted})
    print(f"pilot: {a.subjects} subjects, seed {a.seed}, arms {a.arms}; "
          f"{len(not_run)} of {len(cancelling)} cancelling tests not run")
    print()
    print("| compensator | arm | n | MSE tracking (mm²), median | change vs off, paired median "
          "| a_w (m/s²), median | change vs off, paired median |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for c in COMPENSATORS:
        for arm in ["off", *arms]:
            have = [s for s in subjects if (c, arm, s) in cell]
            if not have:
                continue
            mse = statistics.median(cell[(c, arm, s)][0] for s in have)
            aw = statistics.median(cell[(c, arm, s)][1] for s in have)
            if arm == "off":
                print(f"| {c} | off | {len(have)} | {mse:.1f} | | {aw:.3f} | |")
                continue
            both = [s for s in have if (c, "off", s) in cell]
            dm = statistics.median(
                cell[(c, arm, s)][0] / cell[(c, "off", s)][0] - 1 for s in both)
            da = statistics.median(
                cell[(c, arm, s)][1] / cell[(c, "off", s)][1] - 1 for s in both)
            print(f"| {c} | {arm} | {len(have)} ({len(both)} paired) | {mse:.1f} | "
                  f"{100 * dm:+.1f} % | {aw:.3f} | {100 * da:+.1f} % |")
    print_plans(plans, a.plan_subjects.split(","), a.plan_draws)


def print_plans(plans, ns, draws):
    """The power plan per arm and metric: a row per compensator, a column per n."""
    print()
    print(f"Power (pilot's spread, {draws} simulated studies each, alpha 0.05, Holm over the five):")
    print()
    print("| arm | metric | model's subjects | compensator | "
          + " | ".join(f"n = {n}" for n in ns) + " |")
    print("|---|---|---:|---|" + "---:|" * len(ns))
    for (arm, metric), rep in plans.items():
        if isinstance(rep, str):
            print(f"| {arm} | {metric} | | not planned: {rep} |" + " |" * len(ns))
            continue
        for i, pair in enumerate(rep["plans"][0]["pairs"]):
            cells = [f"{100 * p['pairs'][i]['power']:.0f} %" if p["pairs"][i]["possible"]
                     else "impossible" for p in rep["plans"]]
            print(f"| {arm} | {metric} | {rep['model']['pilot_n']} | {pair['a']} | "
                  + " | ".join(cells) + " |")
        print(f"| {arm} | {metric} | | any | "
              + " | ".join(f"{100 * p['any']:.0f} %" for p in rep["plans"]) + " |")


if __name__ == "__main__":
    main()
