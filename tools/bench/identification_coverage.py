#!/usr/bin/env python3
"""How often a study's identification is right (docs/identification.md, "Coverage in a study";
issue 42): per parameter, the share of subjects whose 95 % interval holds their truth, how
many truths lie more than one interval width outside it, and per pilot the correlation of
identified against drawn ln k_h.

Each pilot is `bdft-server pilot --params P --subjects N --seed S`, P being the default
study's parameters with the default identification test (`--task` hold-still or relax) and
the population's body_k_h spread set to `--kh-cv` (default 0.45). Its figures are then read
from its exports alone, here, with Python's standard library: the `subjects` export gives
each subject's drawn body (drawn.*) and identified body (identified.*, with bounds and
status); the `trials` export finds the identification test; that test's `samples` export
gives the cab acceleration the subject felt, from which the truth is made.

The truth: the body as it was during the test. k_h, the torso's frequency and damping and
the arm's damping are the drawn ones. The arm's frequency is the drawn one times the grip the
subject held on average over the recorded periods: holding still, 1 + grip_stiffening x the
felt RMS cab acceleration (m/s^2) over those periods (the operator's grip is 1 +
grip_stiffening x its running 1-s RMS of the true cab acceleration, `SyntheticOperator::hold`;
the record's channel is the accelerometer's, so the accelerometer's white noise, the plant's
accel_noise_std, and the engine's tone, engine_vibration_rms, are taken out of its mean square); relaxed, the grip stays 1. The seated
body's feedthrough k_h(1 - T·A) is symmetric in torso and arm: the data cannot tell which is
which, and the fit names them by the population's prior, whose torso (1.1 Hz) is below its
arm (2.0 Hz), at equal spreads — the lower one the torso (unless the dampings weigh the other way). So the
truth names the lower resonance the torso (a subject whose gripped arm is below their torso is
compared resonance for resonance).

A parameter the fit names "not identified" has no interval: it is counted apart (neither
held nor missed). The correlation is over the subjects whose k_h is identified.

Usage (from the repo root, after `cargo build -p bdft-server --bins`):
    python3 tools/bench/identification_coverage.py --seeds 1-10 --subjects 12
    python3 tools/bench/identification_coverage.py --seeds 101-117 --subjects 12 --task relax
Options: --bin PATH (default target/debug/bdft-server), --keep DIR (keep the databases and
exports: about 650 MB a pilot), --jobs N (pilots run side by side; default 1), --rms-mm X (the multisine's RMS).
"""

import argparse
import concurrent.futures
import csv
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
PARAMETERS = ["k_h", "torso_f_hz", "torso_zeta", "arm_f_hz", "arm_zeta"]
DRAWN = {
    "k_h": "drawn.body_k_h",
    "torso_f_hz": "drawn.torso_f_hz",
    "torso_zeta": "drawn.torso_zeta",
    "arm_f_hz": "drawn.arm_f_hz",
    "arm_zeta": "drawn.arm_zeta",
}


def run(binary, *args, out=subprocess.DEVNULL):
    subprocess.run([binary, *args], check=True, stdout=out, stderr=subprocess.DEVNULL)


def default_params(binary, tmp):
    """The default study's parameters, as the server stores them (a 1-subject pilot's)."""
    db = os.path.join(tmp, "defaults.db")
    run(binary, "pilot", "--db", db, "--subjects", "1", "--seed", "1")
    import sqlite3

    with sqlite3.connect(db) as c:
        return json.loads(c.execute("SELECT params_json FROM studies ORDER BY id LIMIT 1").fetchone()[0])


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def felt_rms_m_s2(path, noise_mm_s2, skip_s):
    """RMS of the true cab acceleration over the recorded periods (m/s^2), from a samples
    export: the measured channel's mean square less the accelerometer noise's variance."""
    sq, n = 0.0, 0
    for r in read_csv(path):
        if float(r["t_s"]) < skip_s - 1e-9:
            continue
        a = float(r["cab_accel_mm_s2"])
        sq += a * a
        n += 1
    return math.sqrt(max(0.0, sq / n - noise_mm_s2**2)) * 1e-3


def pilot(binary, params, seed, subjects, work, keep):
    """One pilot's subjects: [(code, truth{param}, identified{param: (value, lo, hi) | why})].
    Its database (about 650 MB: every test's 1 kHz record) is removed once read unless
    `keep`, so a run of many seeds holds only the pilots in progress on disk."""
    os.makedirs(work, exist_ok=True)
    pfile = os.path.join(work, "params.json")
    with open(pfile, "w") as f:
        json.dump(params, f)
    db = os.path.join(work, "pilot.db")
    if os.path.exists(db):
        os.remove(db)
    run(binary, "pilot", "--db", db, "--params", pfile, "--subjects", str(subjects), "--seed", str(seed))
    subj_csv, trials_csv = os.path.join(work, "subjects.csv"), os.path.join(work, "trials.csv")
    run(binary, "export", "--db", db, "--kind", "subjects", "--out", subj_csv)
    run(binary, "export", "--db", db, "--kind", "trials", "--out", trials_csv)
    ident = params["identification"]
    spec = ident.get("excitation") or {}
    skip_s = spec.get("transient_periods", 1) * spec.get("period_s", 10.0)
    holding = ident.get("task", "hold-still") == "hold-still"
    # The accelerometer's white noise and the engine's tone: neither is felt in the hand.
    noise = math.hypot(params["plant"]["accel_noise_std"], params["plant"].get("engine_vibration_rms", 0.0))
    trial_of = {}
    for r in read_csv(trials_csv):
        if r["phase"] == "identification" and r["status"] == "complete" and r["latest"] == "1":
            trial_of[r["subject_code"]] = r["trial_id"]
    out = []
    for r in read_csv(subj_csv):
        code = r["subject_code"]
        if code not in trial_of or r["identified.k_h_status"] == "":
            out.append((code, None, None))
            continue
        grip = 1.0
        if holding:
            samples = os.path.join(work, f"samples-{code}.csv")
            run(binary, "export", "--db", db, "--kind", "samples", "--trial", trial_of[code], "--out", samples)
            grip = 1.0 + float(r["drawn.grip_stiffening_per_m_s2"]) * felt_rms_m_s2(samples, noise, skip_s)
            os.remove(samples)
        truth = {p: float(r[DRAWN[p]]) for p in PARAMETERS}
        truth["arm_f_hz"] *= grip
        if truth["torso_f_hz"] > truth["arm_f_hz"]:
            # 1 - T·A is symmetric in the two: the data cannot name them (module doc).
            truth["torso_f_hz"], truth["arm_f_hz"] = truth["arm_f_hz"], truth["torso_f_hz"]
            truth["torso_zeta"], truth["arm_zeta"] = truth["arm_zeta"], truth["torso_zeta"]
        fit = {}
        for p in PARAMETERS:
            status = r[f"identified.{p}_status"]
            if status == "identified":
                fit[p] = tuple(float(r[f"identified.{p}{s}"]) for s in ["", "_lo", "_hi"])
            else:
                fit[p] = status
        out.append((code, truth, fit))
    if not keep:
        shutil.rmtree(work, ignore_errors=True)
    return out


def pearson(xs, ys):
    if len(xs) < 3:
        return float("nan")
    return statistics.correlation(xs, ys)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", required=True, help="e.g. 1-10 or 3,5")
    ap.add_argument("--subjects", type=int, default=12)
    ap.add_argument("--task", choices=["hold-still", "relax"], default="hold-still")
    ap.add_argument("--kh-cv", type=float, default=0.45)
    ap.add_argument("--rms-mm", type=float, help="the multisine's RMS (default: the study's default)")
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "debug", "bdft-server"))
    ap.add_argument("--keep")
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    seeds = []
    for part in a.seeds.split(","):
        lo, _, hi = part.partition("-")
        seeds.extend(range(int(lo), int(hi or lo) + 1))
    tmp = a.keep or tempfile.mkdtemp(prefix="ident-coverage-")
    os.makedirs(tmp, exist_ok=True)
    params = default_params(a.bin, tmp)
    params["identification"] = {"task": a.task}
    if a.rms_mm is not None:
        params["identification"]["excitation"] = {"rms_mm": a.rms_mm}
    params["population"]["body_k_h"]["cv"] = a.kh_cv
    held = {p: 0 for p in PARAMETERS}
    judged = {p: 0 for p in PARAMETERS}
    unidentified = {p: 0 for p in PARAMETERS}
    far = {p: 0 for p in PARAMETERS}
    subjects_all = 0
    rms = "" if a.rms_mm is None else f", multisine {a.rms_mm} mm RMS"
    print(f"task {a.task}, body_k_h cv {a.kh_cv}{rms}, {a.subjects} subjects a pilot, seeds {a.seeds}")
    with concurrent.futures.ThreadPoolExecutor(max_workers=a.jobs) as ex:
        futures = {
            s: ex.submit(pilot, a.bin, params, s, a.subjects, os.path.join(tmp, f"seed{s}"), bool(a.keep))
            for s in seeds
        }
        for seed in seeds:
            rows = futures[seed].result()
            xs, ys, misses = [], [], []
            for code, truth, fit in rows:
                subjects_all += 1
                if truth is None:
                    misses.append(f"{code}: no fit")
                    continue
                for p in PARAMETERS:
                    e = fit[p]
                    if isinstance(e, str):
                        unidentified[p] += 1
                        continue
                    v, lo, hi = e
                    t = truth[p]
                    judged[p] += 1
                    if lo <= t <= hi:
                        held[p] += 1
                    else:
                        outside = lo - t if t < lo else t - hi
                        far[p] += outside > hi - lo
                        misses.append(f"{code} {p} {t:.3g} not in {v:.3g} [{lo:.3g}, {hi:.3g}]")
                if not isinstance(fit["k_h"], str):
                    xs.append(math.log(truth["k_h"]))
                    ys.append(math.log(fit["k_h"][0]))
            r = pearson(xs, ys)
            print(f"seed {seed}: corr(ln k_h identified, drawn) {r:.3f} over {len(xs)}; " + ("; ".join(misses) or "no misses"), flush=True)
    print()
    print("| parameter | interval holds the truth | share | more than one width outside | not identified |")
    print("|---|---:|---:|---:|---:|")
    for p in PARAMETERS:
        share = held[p] / judged[p] if judged[p] else float("nan")
        print(f"| {p} | {held[p]} of {judged[p]} | {100 * share:.1f} % | {far[p]} | {unidentified[p]} |")
    print(f"\n{subjects_all} subjects")
    if not a.keep:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
