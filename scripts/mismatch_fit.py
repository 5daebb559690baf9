#!/usr/bin/env python3
"""Per reality of a mismatch suite's runs.csv (`plumenet experiment --mismatch`), over all its
layouts: the mean and median error and the highest reading's mean error; the goodness of fit
of the runs that end within 1 m of the source and of those more than 1.5 m off; and, for the
latter, where the source and the estimate were and how far off the highest reading was.

Usage: python3 scripts/mismatch_fit.py out/mismatch/runs.csv
"""
import csv
import statistics
import sys


def main(path):
    rows = list(csv.DictReader(open(path, newline="")))
    for reality in dict.fromkeys(r["reality"] for r in rows):
        runs = [r for r in rows if r["reality"] == reality]
        good = [float(r["fit"]) for r in runs if float(r["error_m"]) < 1.0]
        bad = [r for r in runs if float(r["error_m"]) > 1.5]
        error = [float(r["error_m"]) for r in runs]
        highest = [float(r["highest_error_m"]) for r in runs]
        print(f"{reality}: {len(runs)} runs, error mean {statistics.mean(error):.2f} m "
              f"(median {statistics.median(error):.2f}), highest reading "
              f"{statistics.mean(highest):.2f} m")
        if good:
            print(f"  within 1 m: {len(good)}, fit median {statistics.median(good):.3f}, "
                  f"largest {max(good):.3f}")
        if bad:
            fit = [float(r["fit"]) for r in bad]
            print(f"  over 1.5 m: {len(bad)}, fit median {statistics.median(fit):.3f}, "
                  f"smallest {min(fit):.3f}")
            for r in bad:
                print(f"    source x {float(r['source_x']):5.1f}, estimate x "
                      f"{float(r['estimate_x']):5.1f}, error {float(r['error_m']):5.2f} m, "
                      f"highest reading {float(r['highest_error_m']):5.2f} m off")


if __name__ == "__main__":
    main(sys.argv[1])
