#!/usr/bin/env python3
"""Where the posterior of the arena's unresolved runs lies: a peak on the source, a tail upwind.

Reads the arena suite's `runs.csv` of `plumenet calibration` (or of `plumenet experiment` in
the paper's arena, whose wind comes from the west), runs every run that spent its iteration
budget again with `plumenet localize ... --json` (same source, start, seed and plume model;
the files are kept in --json-dir and reused), checks that each ends as the study says, and
prints per plume model: the runs, their mean error, how many hold half the posterior in one or
two cells, how many keep a tenth of it or more 1.5 m or more from the estimate, and how many of
those have most of that far mass upwind of the westmost point the robot reached (by more than
0.5 m), where no reading was taken.

Usage: python3 scripts/posterior_tail.py RUNS.csv [--plumenet target/release/plumenet] [--json-dir out/tail-runs]
"""
import argparse
import csv
import json
import math
import os
import subprocess

FAR_M = 1.5
FAR_MASS = 0.1
UPWIND_MARGIN_M = 0.5
TWO_CELLS_M2 = 0.125


def rerun(binary, row, path):
    if not os.path.exists(path):
        command = [
            binary, "localize",
            "--source", f"{row['source_x']},{row['source_y']}",
            "--start", f"{row['start_x']},{row['start_y']}",
            "--seed", row["seed"],
            "--json", path,
        ]
        if row["model"] == "solver":
            command.append("--solver")
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    with open(path) as f:
        run = json.load(f)
    if run["converged"] or abs(run["error_m"] - float(row["error_m"])) > 1e-9:
        raise SystemExit(f"{path}: the rerun differs from the study's run {row['run']}")
    return run


def tail(run):
    xmin = min(point[1] for point in run["trajectory"])
    ex, ey = run["estimate"]
    far = upwind = 0.0
    for p, (x, y) in zip(run["posterior"], run["candidates"]):
        if math.hypot(x - ex, y - ey) >= FAR_M:
            far += p
            if x < xmin - UPWIND_MARGIN_M:
                upwind += p
    return far, upwind


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs")
    parser.add_argument("--plumenet", default="target/release/plumenet")
    parser.add_argument("--json-dir", default="out/tail-runs")
    args = parser.parse_args()
    os.makedirs(args.json_dir, exist_ok=True)
    with open(args.runs) as f:
        rows = [r for r in csv.DictReader(f) if r["converged"] == "false"]
    print("| model | unresolved runs | error mean | half the posterior in 1-2 cells "
          "| a tenth or more 1.5 m off | most of it upwind of the path |")
    print("|---|---|---|---|---|---|")
    for model in sorted({r["model"] for r in rows}):
        mine = [r for r in rows if r["model"] == model]
        tails = [tail(rerun(args.plumenet, r, os.path.join(args.json_dir, f"{model}-{r['run']}.json")))
                 for r in mine]
        error = sum(float(r["error_m"]) for r in mine) / len(mine)
        peaked = sum(float(r["area_50_m2"]) <= TWO_CELLS_M2 for r in mine)
        far = [t for t in tails if t[0] >= FAR_MASS]
        upwind = sum(u > 0.5 * f for f, u in far)
        print(f"| {model} | {len(mine)} | {error:.2f} m | {peaked} | {len(far)} | {upwind} |")


if __name__ == "__main__":
    main()
