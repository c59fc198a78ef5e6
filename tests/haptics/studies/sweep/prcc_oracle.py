#!/usr/bin/python3
"""Independent partial rank correlations of a sweep table, for test_prcc.

Usage: prcc_oracle.py TABLE.csv RESPONSE VAR[,VAR...] LEVEL
Prints JSON {"openturns": {"r": [...]}, "scipy": {"r", "t", "p", "lower", "upper"}}: OpenTURNS'
CorrelationAnalysis.computePRCC() and a numpy/scipy computation (average ranks, least-squares
residuals on the other ranks with an intercept, t with n - 2 - k dof, Fisher z interval).
"""
import json
import sys

import numpy as np
import openturns as ot
from scipy import stats


def main():
    table, response, names, level = sys.argv[1], sys.argv[2], sys.argv[3].split(","), float(sys.argv[4])
    with open(table) as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(table, delimiter=",", skiprows=1, ndmin=2)
    y = data[:, header.index(response)]
    keep = np.isfinite(y)
    x = data[keep][:, [header.index(n) for n in names]]
    y = y[keep]
    n, m = x.shape
    k = m - 1

    prcc_ot = ot.CorrelationAnalysis(ot.Sample(x), ot.Sample(y[:, None])).computePRCC()

    rx = np.column_stack([stats.rankdata(x[:, j]) for j in range(m)])
    ry = stats.rankdata(y)
    out = {"r": [], "t": [], "p": [], "lower": [], "upper": []}
    dof = n - 2 - k
    z = stats.norm.ppf(0.5 + 0.5 * level)
    for j in range(m):
        a = np.column_stack([np.ones(n)] + [rx[:, c] for c in range(m) if c != j])
        ex = rx[:, j] - a @ np.linalg.lstsq(a, rx[:, j], rcond=None)[0]
        ey = ry - a @ np.linalg.lstsq(a, ry, rcond=None)[0]
        r = float(ex @ ey / np.sqrt((ex @ ex) * (ey @ ey)))
        t = r * np.sqrt(dof / (1 - r * r))
        out["r"].append(r)
        out["t"].append(float(t))
        out["p"].append(float(2 * stats.t.sf(abs(t), dof)))
        se = 1 / np.sqrt(n - 3 - k)
        out["lower"].append(float(np.tanh(np.arctanh(r) - z * se)))
        out["upper"].append(float(np.tanh(np.arctanh(r) + z * se)))
    print(json.dumps({"n": int(n), "openturns": {"r": [float(v) for v in prcc_ot]},
                      "scipy": out}))


if __name__ == "__main__":
    main()
