#!/usr/bin/env python3
"""The 10-cell table of the calibration benchmark (docs/benchmarks.md, issue 21), and its check.

make: a published-style table (5 controllers x 2 stations, mean-squared tracking error with
sd and n) from a pilot of 8 synthetic subjects of a known population, the "truth": the default
study with other medians (TRUTH below). The pilot runs through `bdft-server pilot --params`
(the whole protocol with records, as a lab's pilot); the table's means, sds and ns are then
computed here with Python's `statistics` from the pilot's trials export (valid = 1 and
latest = 1 rows: what the study's statistics use), not by the server. Writes
tests/fixtures/calibration/table.csv (with its provenance as '#' comments, which the table
parser skips) and truth.json (the study parameters of the pilot).

check REPORT.json: reads `bdft-server calibrate`'s report and says per cell whether the fitted
prediction lies within its stated error (2.5 x the root sum of squares of the table's standard
error sd/sqrt(n) and the prediction's Monte-Carlo error: what
`fits_a_published_style_table_within_its_stated_error_and_predicts_the_rest` asserts) and
per fitted median whether its 95 % interval holds the truth. Exit 1 if a cell misses.

coverage SEEDS TRIAL_S: how often the fitted medians' 95 % intervals hold the truth over
pilots seeded 1..SEEDS (each: a table made as `make` makes it, with TRIAL_S-second tests,
calibrated from the default medians with 48 simulated subjects), one line per seed and the
count per parameter. A 95 % interval should miss about one seed in twenty.

Usage (from the repo root, after `cargo build --release -p bdft-server`):
    python3 tools/bench/calibration_table.py make
    python3 tools/bench/calibration_table.py check report.json
    python3 tools/bench/calibration_table.py coverage 20 20
Only the standard library is needed.
"""

import csv
import json
import math
import os
import sqlite3
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
# BDFT_SERVER names another build (a dev one, say); the figures are the same, only slower.
BIN = os.environ.get("BDFT_SERVER", os.path.join(ROOT, "target", "release", "bdft-server"))
OUT = os.path.join(ROOT, "tests", "fixtures", "calibration")

# The true population's medians (the default study's: 0.25 s, 0.3, 0.6, 0.50).
TRUTH = {
    "reaction_delay_s": 0.30,
    "error_gain": 0.36,
    "vibration_delay_s_per_m_s2": 0.45,
    "body_k_h": 0.50,
}
# The default study's controllers, in its order.
CONTROLLERS = ["pid", "pid-notch", "pid-shaper", "lqr", "lqr-cabvel"]
SUBJECTS = 8  # the thesis's eight people
SEED = 11


def run(*args):
    subprocess.run([BIN, *args], check=True, stdout=subprocess.DEVNULL)


def defaults(tmp):
    """The default study's parameters, as the server stores them."""
    run("pilot", "--db", f"{tmp}/defaults.db", "--subjects", "1", "--seed", "1")
    with sqlite3.connect(f"{tmp}/defaults.db") as db:
        return json.loads(db.execute("SELECT params_json FROM studies ORDER BY id LIMIT 1").fetchone()[0])


def pilot_cells(tmp, truth, seed):
    """Each cell's mean-squared tracking errors in a pilot of SUBJECTS of `truth` (a params
    file) seeded `seed`: the valid, latest rows of its trials export."""
    run("pilot", "--db", f"{tmp}/truth.db", "--params", truth, "--subjects", str(SUBJECTS), "--seed", str(seed))
    run("export", "--db", f"{tmp}/truth.db", "--kind", "trials", "--out", f"{tmp}/trials.csv")
    os.remove(f"{tmp}/truth.db")
    cells = {}
    with open(f"{tmp}/trials.csv", newline="") as f:
        for r in csv.DictReader(f):
            if r["valid"] == "1" and r["latest"] == "1":
                cells.setdefault((r["controller"], r["station"]), []).append(float(r["mse_tracking_mm2"]))
    return cells


def table_lines(cells):
    """The table's rows, header first; exits unless every one of the 10 cells has 2 or more."""
    lines = ["controller,station,metric,mean,sd,n"]
    for station in ["on", "off"]:
        for controller in CONTROLLERS:
            v = cells.get((controller, station), [])
            if len(v) < 2:
                continue
            lines.append(f"{controller},{station},mse_tracking_mm2,{statistics.fmean(v):.1f},{statistics.stdev(v):.1f},{len(v)}")
    if len(lines) != 1 + 10:
        sys.exit(f"expected 10 cells, got {len(lines) - 1}: {sorted(cells)}")
    return lines


def make():
    with tempfile.TemporaryDirectory() as tmp:
        params = defaults(tmp)
        for name, median in TRUTH.items():
            params["population"][name]["median"] = median
        os.makedirs(OUT, exist_ok=True)
        truth = os.path.join(OUT, "truth.json")
        with open(truth, "w") as f:
            json.dump(params, f, indent=2, sort_keys=True)
            f.write("\n")
        rows = table_lines(pilot_cells(tmp, truth, SEED))
    lines = [
        "# Calibration benchmark table (issue 21): mean-squared tracking error of a pilot of",
        f"# {SUBJECTS} synthetic subjects (seed {SEED}) of truth.json: the default study with the medians",
        "# " + ", ".join(f"{k} {v}" for k, v in TRUTH.items()) + ".",
        "# Made by tools/bench/calibration_table.py make (means and sample sds by Python's statistics",
        "# from the pilot's trials export, valid and latest rows).",
        *rows,
    ]
    with open(os.path.join(OUT, "table.csv"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


def check(path):
    with open(path) as f:
        report = json.load(f)
    fit = report["fit"]
    missed = 0
    print("| controller | station | table mean | sd | n | fitted | MC error | z |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for c in fit["cells"]:
        se = c["target_sd"] / math.sqrt(c["target_n"])
        stated = math.hypot(se, c["monte_carlo_error"])
        z = (c["prediction"] - c["target"]) / stated
        missed += abs(z) > 2.5
        print(f"| {c['controller']} | {c['station']} | {c['target']:.1f} | {c['target_sd']:.1f} | {c['target_n']} | {c['prediction']:.1f} | {c['monte_carlo_error']:.1f} | {z:+.2f} |")
    print()
    print("| parameter | before | fitted | 95 % interval | truth | in it |")
    print("|---|---:|---:|---|---:|---|")
    for p in fit["parameters"]:
        t = TRUTH.get(p["name"])
        inside = "" if t is None else ("yes" if p["low"] <= t <= p["high"] else "no")
        print(f"| {p['name']} | {p['before']:.3g} | {p['fitted']:.3g} | [{p['low']:.3g}, {p['high']:.3g}] | {'' if t is None else t} | {inside} |")
    print()
    print(f"iterations {fit['iterations']}, objective {fit['objective_before']:.1f} -> {fit['objective']:.2f}; not identified: {fit['not_identified']}")
    print(f"cells outside 2.5 x their stated error: {missed} of {len(fit['cells'])}")
    sys.exit(1 if missed else 0)


def coverage(seeds, trial_s):
    held = {name: 0 for name in TRUTH}
    fitted = {name: 0 for name in TRUTH}
    with tempfile.TemporaryDirectory() as tmp:
        start = defaults(tmp)
        start["trial_s"] = trial_s
        start["practice_s"] = min(trial_s, 120.0)
        truth = json.loads(json.dumps(start))
        for name, median in TRUTH.items():
            truth["population"][name]["median"] = median
        for name, params in [("start", start), ("truth", truth)]:
            with open(f"{tmp}/{name}.json", "w") as f:
                json.dump(params, f)
        # The study calibrated: the default medians, TRIAL_S-second tests.
        run("pilot", "--db", f"{tmp}/start.db", "--params", f"{tmp}/start.json", "--subjects", "1", "--seed", "1")
        for seed in range(1, seeds + 1):
            with open(f"{tmp}/table.csv", "w") as f:
                f.write("\n".join(table_lines(pilot_cells(tmp, f"{tmp}/truth.json", seed))) + "\n")
            subprocess.run(["cp", f"{tmp}/start.db", f"{tmp}/run.db"], check=True)
            out = subprocess.run(
                [BIN, "calibrate", "--db", f"{tmp}/run.db", "--study", "1", "--table", f"{tmp}/table.csv", "--subjects", "48", "--seed", "1"],
                check=True, capture_output=True, text=True,
            ).stdout
            line = [f"seed {seed}:"]
            for p in json.loads(out)["fit"]["parameters"]:
                t = TRUTH.get(p["name"])
                if t is None:
                    continue
                fitted[p["name"]] += 1
                inside = p["low"] <= t <= p["high"]
                held[p["name"]] += inside
                line.append(f"{p['name']} {p['fitted']:.3g} [{p['low']:.3g}, {p['high']:.3g}]{'' if inside else ' MISSES'}")
            print("  ".join(line), flush=True)
    for name in TRUTH:
        print(f"{name}: the interval holds the truth {TRUTH[name]} in {held[name]} of the {fitted[name]} fits that identified it")


if __name__ == "__main__":
    if sys.argv[1:2] == ["make"]:
        make()
    elif sys.argv[1:2] == ["check"] and len(sys.argv) == 3:
        check(sys.argv[2])
    elif sys.argv[1:2] == ["coverage"] and len(sys.argv) == 4:
        try:
            seeds, trial_s = int(sys.argv[2]), float(sys.argv[3])
        except ValueError:
            sys.exit(f"coverage SEEDS TRIAL_S: a whole number of seeds and a test length in seconds, not {sys.argv[2:]}")
        if seeds < 1 or not 1.0 <= trial_s <= 600.0:
            sys.exit("coverage SEEDS TRIAL_S: SEEDS at least 1, TRIAL_S from 1 to 600 s")
        coverage(seeds, trial_s)
    else:
        sys.exit(__doc__)
