#!/usr/bin/env python3
"""Issue 34: per trace, in the cue band (contact, |z| <= 35 mm, 5 <= |x| <= 35 mm): the tilt of d
(proxy -> probe) from the press axis +y, its x component's sign against the side, the centre
ray's L, D and k, per side. usage: tilt.py trace.csv [...]"""
import csv, sys
import numpy as np
for f in sys.argv[1:]:
    with open(f) as fh:
        r = csv.reader(fh); h = next(r); a = np.array([[float(x) for x in row] for row in r])
    c = {k: a[:, i] for i, k in enumerate(h)}
    dv = np.stack([c["probe_x"] - c["proxy_x"], c["probe_y"] - c["proxy_y"], c["probe_z"] - c["proxy_z"]], 1)
    n = np.linalg.norm(dv, axis=1); ok = n > 1e-6
    tilt = np.degrees(np.arccos(np.clip(dv[:, 1] / np.maximum(n, 1e-12), -1, 1)))
    px, pz = c["proxy_x"] * 1e3, c["proxy_z"] * 1e3
    band = (c["contacts"] > 0) & (np.abs(pz) <= 35) & ok
    out = [f]
    for name, s in (("left", band & (px <= -5) & (px >= -35)), ("right", band & (px >= 5) & (px <= 35))):
        out.append(f"{name}: tilt median {np.median(tilt[s]):.0f} deg, d_x outward {np.mean(np.sign(dv[s,0]) == np.sign(px[s])):.2f}, "
                   f"L {1e3*np.mean(c['ray_length'][s]):.1f} mm, D {1e3*np.mean(c['distance'][s]):.2f} mm, k {np.mean(c['stiffness'][s]):.0f}")
    print(" | ".join(out))
