"""Drift study: marker RMSE of every method over seeded fast-mode runs, side by side.

Usage: python tests/benchmarks/drift_study.py [--seeds N] [--scenarios corridor-loop office]
"""

from __future__ import annotations

import argparse
import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: one BLAS thread is faster

from markergraph.common.progress import ProgressBar
from markergraph.datasets.study import drift_study, summarise
from markergraph.estimator import chi2_interval


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--scenarios", nargs="+", default=["corridor-loop", "office"])
    args = parser.parse_args()
    with ProgressBar("runs") as bar:
        rows = drift_study(args.scenarios, range(args.seeds), progress=bar)
    summary = summarise(rows)
    low, high = (v / args.seeds for v in chi2_interval(3 * args.seeds))
    print(
        f"{args.seeds} seeds per scenario; EKF mean-NEES 95% band for 3 dof: "
        f"[{low:.2f}, {high:.2f}]"
    )
    header = (
        f"{'scenario':<14} {'method':<20} {'marker RMSE':>11} {'aligned':>8} "
        f"{'yaw RMSE':>9} {'ATE':>7} {'RPE/m':>7} {'NEES':>6} {'in 95%':>6} {'time':>7}"
    )
    print(header)
    for (name, method), f in summary.items():
        nees_text = "" if math.isnan(f["mean_nees"]) else f"{f['mean_nees']:.2f}"
        ate = "" if math.isnan(f["ate_m"]) else f"{f['ate_m']:.3f}"
        rpe = "" if math.isnan(f["rpe_m_per_m"]) else f"{f['rpe_m_per_m']:.3f}"
        inside = "" if math.isnan(f["ellipse_coverage"]) else f"{100 * f['ellipse_coverage']:.0f}%"
        print(
            f"{name:<14} {method:<20} {f['marker_rmse_m']:>9.3f} m"
            f" {f['marker_rmse_aligned_m']:>8.3f}"
            f" {math.degrees(f['marker_yaw_rmse_rad']):>7.2f}° {ate:>7} {rpe:>7} {nees_text:>6}"
            f" {inside:>6}"
            f" {f['seconds']:>6.2f}s"
        )
    for name in args.scenarios:
        closed = summary[(name, "closed-form/signed")]["marker_rmse_m"]
        for method in ("marker-graph", "slam", "isam2", "ekf"):
            ratio = closed / summary[(name, method)]["marker_rmse_m"]
            print(f"{name}: closed form / {method} marker RMSE = {ratio:.1f}x")


if __name__ == "__main__":
    main()
