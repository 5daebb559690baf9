#!/usr/bin/env python3
"""A study's runs.csv (`plumenet experiment`) summed up over all its layouts, per plume model,
reality, paths, feature and sensor: runs, error mean / median / 90th percentile / max, runs
ending more than 1.5 m off, the highest-reading baseline's mean error, median iterations, the
share converged, and the goodness of fit of the runs within 1 m and over 1.5 m off.
Standard library only.

Usage: python3 scripts/study_summary.py out/study/runs.csv [--markdown]
"""
import argparse
import csv
import statistics


def percentile(values, q):
    """The q-quantile by linear interpolation between order statistics."""
    s = sorted(values)
    k = (len(s) - 1) * q
    lo, hi = int(k), min(int(k) + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", help="runs.csv of a study")
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    args = ap.parse_args()
    rows = list(csv.DictReader(open(args.runs, newline="")))
    keys = ("model", "reality", "paths", "feature", "sensor")
    groups = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    header = ["model", "reality", "paths", "feature", "sensor", "runs", "mean (m)",
              "median (m)", "p90 (m)", "max (m)", "over 1.5 m", "highest reading (m)",
              "median iterations", "converged"]
    if args.markdown:
        print("| " + " | ".join(header) + " |")
        print("|" + "---|" * len(header))
    for key, runs in groups.items():
        error = [float(r["error_m"]) for r in runs]
        highest = [float(r["highest_error_m"]) for r in runs]
        iterations = [int(r["iterations"]) for r in runs]
        converged = sum(r["converged"] == "true" for r in runs) / len(runs)
        cells = list(key) + [
            str(len(runs)),
            f"{statistics.mean(error):.2f}",
            f"{statistics.median(error):.2f}",
            f"{percentile(error, 0.9):.2f}",
            f"{max(error):.2f}",
            str(sum(e > 1.5 for e in error)),
            f"{statistics.mean(highest):.2f}",
            f"{statistics.median(iterations):g}",
            f"{100 * converged:.0f}%",
        ]
        if args.markdown:
            print("| " + " | ".join(cells) + " |")
            continue
        print(", ".join(f"{h} {c}" for h, c in zip(header, cells)))
        fit = lambda sel: sorted(float(r["fit"]) for r in sel if r["fit"])
        good = fit(r for r in runs if float(r["error_m"]) < 1.0)
        bad = fit(r for r in runs if float(r["error_m"]) > 1.5)
        if good:
            print(f"  fit within 1 m: median {statistics.median(good):.3f}, largest {good[-1]:.3f}")
        if bad:
            print(f"  fit over 1.5 m: median {statistics.median(bad):.3f}, smallest {bad[0]:.3f}")


if __name__ == "__main__":
    main()
