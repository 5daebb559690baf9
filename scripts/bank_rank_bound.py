#!/usr/bin/env python3
"""How close a sum of K planes can come to a room's bank: the best rank-K approximation.

Reads a bank written by `plumenet bank --solver --layout L --out BANK.npy` ([N, H, W], one
field per candidate source) and, for each K, prints the median and 90th percentile over the
candidates of the relative L2 error of the bank's best rank-K approximation (truncated SVD of
the N x HW matrix). With `--speed U` the approximation is made in PlumeNet's target space,
`ln(1 + c (U / 0.75) / 0.01)`, and mapped back to concentrations (clipped at 0), as a network
that predicts the target would. A branch/trunk network sums K room planes weighted by the
source's coefficients; per room, no choice of planes and coefficients does better than the
truncated SVD.

Usage: python3 scripts/bank_rank_bound.py BANK.npy [--speed U] [--ranks 16,64,128,256,512]
"""
import argparse

import numpy as np


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bank")
    parser.add_argument("--speed", type=float, help="wind speed (m/s): fit the target space")
    parser.add_argument("--ranks", default="16,64,128,256,512")
    args = parser.parse_args()
    bank = np.load(args.bank).astype(np.float64)
    fields = bank.reshape(bank.shape[0], -1)
    scale = None if args.speed is None else (args.speed / 0.75) / 0.01
    target = fields if scale is None else np.log1p(fields * scale)
    u, s, vt = np.linalg.svd(target, full_matrices=False)
    norms = np.linalg.norm(fields, axis=1)
    for k in (int(r) for r in args.ranks.split(",")):
        approx = (u[:, :k] * s[:k]) @ vt[:k]
        if scale is not None:
            approx = np.maximum(np.expm1(approx) / scale, 0.0)
        err = np.linalg.norm(approx - fields, axis=1) / norms
        print(f"K={k}: median {np.median(err):.3f}, p90 {np.percentile(err, 90):.3f}")


if __name__ == "__main__":
    main()
