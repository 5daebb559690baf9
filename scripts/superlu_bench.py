#!/usr/bin/env python3
"""Reference timing for `plumenet bench`: the same transport system solved with scipy's SuperLU.

Reads `matrix_rows.npy`, `matrix_cols.npy`, `matrix_vals.npy` (COO of the n x n operator) and
`rhs_rows.npy`, `rhs_cols.npy`, `rhs_vals.npy` (COO of the n x N right-hand sides, one column per
candidate source) from DIR, then times `splu` (factorisation) and one blocked `solve` of all
columns, `--repeats` times, and prints the medians as JSON. Also reports the largest difference
from plumenet's own solution (`plumenet_bank.npy`, n x N) so both sides are known to solve the
same system. Installs scipy with pip when it is missing (only this benchmark needs Python).
"""
import argparse
import json
import statistics
import subprocess
import sys
import time

try:
    import numpy as np
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla
except ImportError:
    subprocess.check_call([sys.executable, "-m", "pip", "install", "--quiet", "numpy", "scipy"])
    import numpy as np
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("dir")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    load = lambda name: np.load(f"{args.dir}/{name}.npy")
    n = int(load("matrix_rows").max()) + 1
    a = sp.csc_matrix((load("matrix_vals"), (load("matrix_rows"), load("matrix_cols"))), shape=(n, n))
    rhs_cols = load("rhs_cols")
    b = sp.csc_matrix((load("rhs_vals"), (load("rhs_rows"), rhs_cols)), shape=(n, int(rhs_cols.max()) + 1)).toarray()
    factor, solve = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        lu = sla.splu(a)
        t1 = time.perf_counter()
        x = lu.solve(b)
        t2 = time.perf_counter()
        factor.append(t1 - t0)
        solve.append(t2 - t1)
    ours = load("plumenet_bank")
    print(json.dumps({
        "unknowns": n,
        "sources": b.shape[1],
        "factor_s": statistics.median(factor),
        "solve_s": statistics.median(solve),
        "max_abs_difference": float(np.abs(x - ours).max()),
        "scipy": __import__("scipy").__version__,
    }))


if __name__ == "__main__":
    main()
