#!/usr/bin/env python3
"""Benchmark python-control's forced_response on the bdft-lab discrete closed loop.

Loop (dt = 1 ms), all discrete-time:
  * physical 7-state plant (input V, x = [xc, xc', xc'', xc''', y, y', y'']) ZOH-discretized;
  * feedthrough station on: r_c = K_BF (p_h - K_H xc), K_BF = 0.6;
  * notch on r_c: Tustin biquad of (s^2 + 2 zN wN s + wN^2)/(s + wN)^2 pre-warped at wN;
  * PID on e = r_f - y: P = Kp e; I[k+1] = I[k] + Kp dt/Ti e[k];
    D = Tustin of Kp Td s/(1 + Tf s), Tf = Td/N; V = P + I + D (no saturation).
  Input p_h: 70 steps, one every 2 s (140 s, 140,000 samples), values from
  numpy default_rng(1).uniform(-40, 40, 70) / K_BF.  Outputs [y, xc''].

Only the control.forced_response call is timed; prints one JSON line.
Usage: python3 tools/bench/forced_response.py [--runs N]
"""

import argparse
import json
import math
import time

import numpy as np
import scipy.signal as sig
import control as ct

K_VC, W_VC, Z_VC = 22.0, 21.2, 0.45
K_S = 0.45
W1, Z1 = 2 * math.pi * 4.0, 0.06
W2, Z2 = 2 * math.pi * 6.2, 0.04
K_H = 0.56
DT = 0.001
K_BF = 0.6
W_N, Z_N = 2 * math.pi * 5.1, 0.3
KU = 2 * Z_VC * W_VC / K_VC
TU = 2 * math.pi / W_VC
KP, TI, TD, N_D = 0.6 * KU, TU / 2, TU / 8, 10.0
TF = TD / N_D

TICKS = 140_000
STEP_TICKS = 2000
N_STEPS = 70


def plant_ct():
    npoly = np.polymul([2 * Z1 * W1, W1**2], [2 * Z2 * W2, W2**2])
    dpoly = np.polymul([1.0, 2 * Z1 * W1, W1**2], [1.0, 2 * Z2 * W2, W2**2])
    b2, b1, b0 = npoly
    _, a3, a2, a1, a0 = dpoly
    A = np.zeros((7, 7))
    A[0, 1] = A[1, 2] = A[2, 3] = 1.0
    A[3, :] = [-a0, -a1, -a2, -a3, K_S * b0, K_S * b1, K_S * b2]
    A[4, 5] = A[5, 6] = 1.0
    A[6, 5], A[6, 6] = -W_VC**2, -2 * Z_VC * W_VC
    B = np.zeros((7, 1))
    B[6, 0] = K_VC * W_VC**2
    return A, B


def discrete_parts():
    A, B = plant_ct()
    C = np.zeros((3, 7))
    C[0, 4] = 1.0  # y
    C[1, 0] = 1.0  # xc
    C[2, 2] = 1.0  # xc''
    Ad, Bd, Cd, Dd, _ = sig.cont2discrete((A, B, C, np.zeros((3, 1))), DT, method="zoh")
    fs_w = W_N / (2 * math.tan(W_N * DT / 2))
    nb, na = sig.bilinear([1.0, 2 * Z_N * W_N, W_N**2], [1.0, 2 * W_N, W_N**2], fs=fs_w)
    db, da = sig.bilinear([KP * TD, 0.0], [TF, 1.0], fs=1.0 / DT)
    return (Ad, Bd, Cd, Dd), (nb / na[0], na / na[0]), (db / da[0], da / da[0])


def build_loop():
    (Ad, Bd, Cd, Dd), (nb, na), (db, da) = discrete_parts()
    P = ct.ss(Ad, Bd, Cd, Dd, DT, inputs="V", outputs=["y", "xc", "xcdd"], name="plant")
    FT = ct.ss(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), [[K_BF, -K_BF * K_H]], DT,
               inputs=["ph", "xc"], outputs="rc", name="feedthrough")
    NOTCH = ct.tf(nb, na, DT, inputs="rc", outputs="rf", name="notch")
    ESUM = ct.summing_junction(inputs=["rf", "-y"], output="e", name="esum", dt=DT)
    PROP = ct.ss(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[KP]], DT,
                 inputs="e", outputs="vp", name="p")
    INTEG = ct.ss([[1.0]], [[KP * DT / TI]], [[1.0]], [[0.0]], DT,
                  inputs="e", outputs="vi", name="i")
    DERIV = ct.tf(db, da, DT, inputs="e", outputs="vd", name="d")
    VSUM = ct.summing_junction(inputs=["vp", "vi", "vd"], output="V", name="vsum", dt=DT)
    sys_ = ct.interconnect([P, FT, NOTCH, ESUM, PROP, INTEG, DERIV, VSUM],
                           inplist=["ph"], outlist=["y", "xcdd"], dt=DT)
    return ct.ss(sys_)


def input_signal():
    vals = np.random.default_rng(1).uniform(-40.0, 40.0, N_STEPS) / K_BF
    U = np.repeat(vals, STEP_TICKS)
    T = np.arange(TICKS) * DT
    return T, U, vals


def manual_sim(n, U):
    """Straight difference-equation simulation of the same loop (cross-check)."""
    (Ad, Bd, Cd, _), (nb, na), (db, da) = discrete_parts()
    x = np.zeros(7)
    nx = [0.0, 0.0, 0.0, 0.0]  # notch: r_c[k-1], r_c[k-2], r_f[k-1], r_f[k-2]
    dx = [0.0, 0.0]  # derivative: e[k-1], D[k-1]
    integ = 0.0
    y_out = np.zeros((2, n))
    for k in range(n):
        y, xc, xcdd = Cd @ x
        rc = K_BF * (U[k] - K_H * xc)
        rf = nb[0] * rc + nb[1] * nx[0] + nb[2] * nx[1] - na[1] * nx[2] - na[2] * nx[3]
        nx = [rc, nx[0], rf, nx[2]]
        e = rf - y
        d = db[0] * e + db[1] * dx[0] - da[1] * dx[1]
        dx = [e, d]
        v = KP * e + integ + d
        integ += KP * DT / TI * e
        y_out[:, k] = (y, xcdd)
        x = Ad @ x + Bd[:, 0] * v
    return y_out


def check(sys_, T, U, vals):
    poles = sys_.poles()
    rho = float(np.max(np.abs(poles)))
    resp = ct.forced_response(sys_, T, U)
    yout = np.asarray(resp.outputs)
    assert np.all(np.isfinite(yout)), "non-finite output"
    # cross-check the interconnection against a hand-written loop (first 6 s)
    n = 6000
    ym = manual_sim(n, U)
    assert np.allclose(yout[:, :n], ym, rtol=1e-9, atol=1e-9 * np.max(np.abs(ym))), \
        np.max(np.abs(yout[:, :n] - ym))
    # tracking: at the end of each 2 s step y should sit at the feedthrough steady state
    # y_ss = K_BF p_h / (1 + K_BF K_H K_S); target = K_BF p_h.
    y_end = yout[0, STEP_TICKS - 1::STEP_TICKS]
    y_ss = K_BF * vals / (1 + K_BF * K_H * K_S)
    settle_err = float(np.max(np.abs(y_end - y_ss)))
    track_err_end = float(np.max(np.abs(K_BF * vals - y_end)))
    # a single long step: the error to the feedthrough steady state must decay to ~0
    Tl = np.arange(30_000) * DT
    yl = np.asarray(ct.forced_response(sys_, Tl, np.full(Tl.shape, 10.0 / K_BF)).outputs)[0]
    yl_ss = 10.0 / (1 + K_BF * K_H * K_S)
    long_step_err = float(np.max(np.abs(yl[-1000:] - yl_ss)))
    return {"spectral_radius": rho, "stable": rho < 1.0, "settle_err_mm": settle_err,
            "tracking_err_end_of_step_mm": track_err_end,
            "long_step_err_after_29s_mm": long_step_err,
            "settled": bool(rho < 1.0 and long_step_err < 1e-6)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--check", action="store_true", help="print loop checks to stderr")
    args = ap.parse_args()
    sys_ = build_loop()
    T, U, vals = input_signal()
    info = check(sys_, T, U, vals)
    if args.check:
        import sys as _s
        print(json.dumps(info), file=_s.stderr)
    if not info["settled"]:
        import sys as _s
        print("WARNING: discrete closed loop does not settle: %s" % json.dumps(info),
              file=_s.stderr)
    times = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        ct.forced_response(sys_, T, U)
        times.append(time.perf_counter() - t0)
    print(json.dumps({"tool": "python-control", "version": ct.__version__, "ticks": TICKS,
                      "runs": args.runs, "median_s": float(np.median(times)),
                      "min_s": float(np.min(times))}))


if __name__ == "__main__":
    main()
