#!/usr/bin/env python3
"""Issue 34: the held-press buzz criteria from a `palp palpate` trace, over t in [t0, t1) (default
0.5 s to the end): the mean tick-to-tick change of the force vector over the mean |F| (and of
|F| itself), and the share of the force's energy above 50 Hz (the three components' squared
DFT, the mean included; also the share of the fluctuation's energy, the mean removed).
usage: holdstat.py trace.csv [t0] [t1]"""
import csv, sys
import numpy as np
f = sys.argv[1]
with open(f) as fh:
    r = csv.reader(fh); h = next(r); a = np.array([[float(x) for x in row] for row in r])
c = {k: a[:, i] for i, k in enumerate(h)}
t = c["t"]
t0 = float(sys.argv[2]) if len(sys.argv) > 2 else 0.5
t1 = float(sys.argv[3]) if len(sys.argv) > 3 else t[-1] + 1e-9
m = (t >= t0) & (t < t1)
F = np.stack([c["force_x"], c["force_y"], c["force_z"]], 1)[m]
Fm = np.linalg.norm(F, axis=1)
dv = np.linalg.norm(np.diff(F, axis=0), axis=1)
dt = np.median(np.diff(t))
spec = np.abs(np.fft.rfft(F, axis=0)) ** 2
fr = np.fft.rfftfreq(len(F), dt)
hi = spec[fr > 50].sum() / spec.sum()
Fz = F - F.mean(0)
sz = np.abs(np.fft.rfft(Fz, axis=0)) ** 2
hiz = sz[fr > 50].sum() / max(sz.sum(), 1e-300)
Ft = np.hypot(F[:, 0], F[:, 2])
print(f"{f}: hold {t0:.2f}-{t[m][-1]:.2f} s ({m.sum()} ticks), |F| {Fm.mean():.4f} N, "
      f"vector change {100*dv.mean()/Fm.mean():.2f} % (max {100*dv.max()/Fm.mean():.1f} %), "
      f"|F| change {100*np.abs(np.diff(Fm)).mean()/Fm.mean():.2f} %, F_t {Ft.mean():.4f} N, "
      f">50 Hz {100*hi:.3f} % of energy ({100*hiz:.0f} % of the fluctuation's), "
      f"k {c['stiffness'][m].min():.0f}-{c['stiffness'][m].max():.0f}")
