#!/usr/bin/env python3
"""Peer benchmark for `bake bench cluster`: scipy's RBFInterpolator on the same data.

Usage: bench-scipy-rbf.py EXPORT_DIR [REPEAT]. Reads the folder written by `bake bench cluster
--export DIR` (positions.f32, values.f32, samples.f32, params.json, optionally truth.f32;
little-endian f32), fits RBFInterpolator(kernel="multiquadric", neighbors=k, epsilon=1/R,
degree=0) on the cluster samples and evaluates it at every instance, REPEAT times (default 1; the
fastest run is reported). scipy's multiquadric is -sqrt(1 + (eps r)^2) = -sqrt(R^2 + r^2)/R for
eps = 1/R: bake's kernel times a constant, which with the constant (degree-0) term gives the same
interpolant as bake's. Prints a human summary on stderr and one JSON line on stdout.

Bench-only dependency: `pip install scipy numpy` (CI does not need it).
"""
import json
import sys
import time
from pathlib import Path

import numpy as np
import scipy
from scipy.interpolate import RBFInterpolator


def load(d: Path, name: str, cols: int) -> np.ndarray:
    return np.fromfile(d / name, dtype="<f4").reshape(-1, cols)


def main() -> int:
    if len(sys.argv) not in (2, 3):
        print("usage: bench-scipy-rbf.py EXPORT_DIR [REPEAT]", file=sys.stderr)
        return 2
    d = Path(sys.argv[1])
    repeat = int(sys.argv[2]) if len(sys.argv) == 3 else 1
    params = json.loads((d / "params.json").read_text())
    dim, k, radius = int(params["dim"]), int(params["k"]), float(params["radius"])
    pos = load(d, "positions.f32", 3).astype(np.float64)
    vals = load(d, "values.f32", dim).astype(np.float64)
    samples = np.fromfile(d / "samples.f32", dtype="<f4").astype(np.int64)
    best = None
    for _ in range(max(repeat, 1)):
        t0, c0 = time.perf_counter(), time.process_time()
        rbf = RBFInterpolator(
            pos[samples],
            vals[samples],
            kernel="multiquadric",
            epsilon=1.0 / radius,
            neighbors=k,
            degree=0,
        )
        t1 = time.perf_counter()
        out = rbf(pos)
        t2, c2 = time.perf_counter(), time.process_time()
        if best is None or t2 - t0 < best[2] - best[0]:
            best = (t0, t1, t2, c0, c2)
    t0, t1, t2, c0, c2 = best
    rms = np.sqrt(np.mean(vals**2))
    doc = {
        "tool": f"scipy {scipy.__version__} RBFInterpolator(kernel='multiquadric', neighbors={k}, epsilon=1/{radius:.4g}, degree=0)",
        "instances": len(pos),
        "samples": len(samples),
        "fit_seconds": t1 - t0,
        "evaluate_seconds": t2 - t1,
        "seconds": t2 - t0,
        "cpu_seconds": c2 - c0,
        "repeat": repeat,
        "rms_error_relative": float(np.sqrt(np.mean((out - vals) ** 2)) / rms),
    }
    if (d / "truth.f32").exists():
        truth = load(d, "truth.f32", dim).astype(np.float64)
        doc["rms_error_vs_truth"] = float(np.sqrt(np.mean((out - truth) ** 2)) / rms)
    print(
        f"scipy: {doc['seconds']:.2f} s (fit {doc['fit_seconds']:.2f} s, CPU {doc['cpu_seconds']:.2f} s), "
        f"relative RMS error {doc['rms_error_relative']:.4%}",
        file=sys.stderr,
    )
    print(json.dumps(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
