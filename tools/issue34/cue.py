#!/usr/bin/env python3
"""Issue 34 diagnosis: the displaced-bone cue from a `palp palpate` trace CSV.
Contact ticks with the proxy 5-35 mm right (+x) of the midline over those 5-35 mm left, within
35 mm of it in z: mean k (the coupling's), mean |F| (the hand's force), mean normal force -F_y,
mean |F| / probe depth (a felt stiffness: force over the hand's depth below the rest skin), the
energy-term forces' share. usage: cue.py trace.csv [...]  (one JSON line per file)"""
import csv, json, sys
import numpy as np

for path in sys.argv[1:]:
    with open(path) as f:
        r = csv.reader(f)
        head = next(r)
        a = np.array([[float(x) for x in row] for row in r])
    col = {h: a[:, i] for i, h in enumerate(head)}
    px, pz = col["proxy_x"] * 1e3, col["proxy_z"] * 1e3
    contact = col["contacts"] > 0
    band = contact & (np.abs(pz) <= 35)
    right = band & (px >= 5) & (px <= 35)
    left = band & (px <= -5) & (px >= -35)
    F = np.sqrt(col["force_x"] ** 2 + col["force_y"] ** 2 + col["force_z"] ** 2)
    Fn = -col["force_y"]
    depth = col["probe_y"] * 1e3  # mm below the rest skin (y = 0)
    Fe = np.sqrt(col["energy_force_x"] ** 2 + col["energy_force_y"] ** 2 + col["energy_force_z"] ** 2)
    Fp = np.sqrt(col["proxy_force_x"] ** 2 + col["proxy_force_y"] ** 2 + col["proxy_force_z"] ** 2)
    kd = col["stiffness"] * col["distance"]  # |spring term|
    def ratio(q):
        return float(np.mean(q[right]) / np.mean(q[left])) if right.any() and left.any() else float("nan")
    ok = depth > 0.5
    out = dict(trace=path, ticks=int(len(F)), right=int(right.sum()), left=int(left.sum()),
               k=ratio(col["stiffness"]), F=ratio(F), Fn=ratio(Fn), kD=ratio(kd),
               F_per_depth=float(np.mean((F / np.maximum(depth, 1e-9))[right & ok]) /
                                 np.mean((F / np.maximum(depth, 1e-9))[left & ok])),
               D_mm=ratio(col["distance"]),
               mean_k_left=float(np.mean(col["stiffness"][left])),
               mean_F_left=float(np.mean(F[left])),
               sphere_over_F=float(np.mean(Fe[band]) / np.mean(F[band])),
               surface_N=float(np.mean(Fp[band])),
               W_end=float(col["observer_energy"][-1]))
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()}),
          flush=True)
