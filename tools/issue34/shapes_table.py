#!/usr/bin/env python3
"""Issue 34: table of shapes.py's JSON lines: per (label, source, mode) the mean IoU over the
seeds per shape and over all shapes, by k at the proxy (iou_k), by k at the probe (iou_kp) and by
|F| at the probe (iou_f)."""
import json, sys
from collections import defaultdict
rows = [json.loads(l) for f in sys.argv[1:] for l in open(f) if l.strip()]
g = defaultdict(list)
for r in rows: g[(r.get("label") or "none", r["source"], r["mode"], r["shape"])].append(r)
keys = sorted({k[:3] for k in g})
shapes = ["circle", "triangle", "rectangle", "hexagon", "pentagon"]
for q in ("iou_k", "iou_kp", "iou_f"):
    print(f"{q}: label source mode | " + " ".join(f"{s[:5]:>6}" for s in shapes) + " |   mean  seeds")
    for k in keys:
        per = [sum(r[q] for r in g[k + (s,)]) / len(g[k + (s,)]) if g.get(k + (s,)) else float("nan") for s in shapes]
        seeds = sorted({r["seed"] for s in shapes for r in g.get(k + (s,), [])})
        print(f"  {k[0]:>9} {k[1]:>10} {k[2]:>5} | " + " ".join(f"{v:6.3f}" for v in per) +
              f" | {sum(per)/len(per):6.3f}  {seeds}")
