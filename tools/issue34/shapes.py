#!/usr/bin/env python3
"""Issue 34 diagnosis: the AVCEC plate-silhouette study (test_experiments.cpp's
AvcecRasterRecoversEachPlateSilhouette) with chosen noise seeds, AVC vs AVCEC (MODES), the
shapes in SHAPES, each line tagged with LABEL (all three from the environment). Observers: the project's
(stiffness binned at the proxy, 2 mm pixels, fill_gaps(2), Otsu, IoU) and two hand observers
(force magnitude, and stiffness, binned at the probe, same pipeline).

usage: LABEL=... python3 shapes.py SEED[,SEED...] [--spacing MM] [--source first-hit]
prints one JSON line per (seed, shape, mode)."""
import json, math, os, sys, time
import numpy as np
sys.path.insert(0, os.environ.get("PALP_PY") or os.path.join(os.path.dirname(os.path.abspath(__file__)), "../../build/release/python"))
import palp

seeds = [int(s) for s in sys.argv[1].split(",")]
spacing = 1.0
source = None
tau_stop = None
args = sys.argv[2:]
while args:
    a = args.pop(0)
    if a == "--spacing": spacing = float(args.pop(0))
    elif a == "--source": source = args.pop(0)
    elif a == "--tau-stop": tau_stop = float(args.pop(0))
shapes = sys.argv[3].split(",") if False else ["circle", "triangle", "rectangle", "hexagon", "pentagon"]
if os.environ.get("SHAPES"): shapes = os.environ["SHAPES"].split(",")
modes = os.environ.get("MODES", "avc,avcec").split(",")

R = 0.020
def inside(shape, x, z):
    if shape == "circle": return x * x + z * z < R * R
    if shape == "rectangle": return (abs(x) < 0.020) & (abs(z) < 0.012)
    sides = {"triangle": 3, "pentagon": 5, "hexagon": 6}[shape]
    ap = R * math.cos(math.pi / sides)
    ok = np.ones_like(x, dtype=bool)
    for k in range(sides):
        a = 0.5 * math.pi + 2 * math.pi * k / sides + math.pi / sides
        ok &= (math.cos(a) * x + math.sin(a) * z) < ap
    return ok

plane = palp.MapPlane(extent_u=0.056, extent_v=0.056, pixel=0.002)
c = plane.pixel_centres()
def otsu_iou(m, truth):
    m.fill_gaps(2)
    t = m.otsu_threshold()
    v = m.values
    mask = np.nan_to_num(v, nan=-np.inf) > t
    return palp.intersection_over_union(mask, truth)

for seed in seeds:
    for shape in shapes:
        vol = palp.phantom("avcec", voxel_size=1e-3, shape=shape, noise_sigma_hu=10, seed=seed)
        scene = palp.Scene.from_volume(vol)
        truth = inside(shape, c[..., 0], c[..., 2])
        for mode in modes:
            raster = palp.RasterTrajectory(extent_u=0.056, extent_v=0.056, line_spacing=spacing * 1e-3,
                                           speed=0.1, depth=0.004)
            secs = raster.duration + 0.1
            p = palp.SessionParams()
            p.coupling = palp.scene_coupling_defaults("avcec")
            if source: p.coupling.source = source
            if tau_stop: p.coupling.accumulate_tau_stop = tau_stop
            p.coupling.mode = mode
            t0 = time.time()
            s = palp.Session(scene, palp.SimulatedDevice(raster), p)
            tr = s.run(int(math.ceil(secs / 1e-3)))
            wall = time.time() - t0
            iou_k = otsu_iou(palp.bin_trace(tr, plane, quantity="stiffness"), truth)
            hand = dict(tr); hand["proxy"] = tr["probe"]
            iou_f = otsu_iou(palp.bin_trace(hand, plane, quantity="force"), truth)
            iou_kp = otsu_iou(palp.bin_trace(hand, plane, quantity="stiffness"), truth)
            F = np.linalg.norm(tr["force"], axis=1)
            cc = tr["contact_count"] > 0
            rej = float(np.mean(tr["uphill_rejected"][cc])) if "uphill_rejected" in tr else -1.0
            print(json.dumps(dict(label=os.environ.get("LABEL", ""), source=(source or "first-hit") + (f"/tau{tau_stop:g}" if tau_stop else ""),
                                  seed=seed, shape=shape, mode=mode, iou_k=round(iou_k, 4),
                                  iou_f=round(iou_f, 4), iou_kp=round(iou_kp, 4),
                                  maxF=round(float(F.max()), 3),
                                  maxD_mm=round(1e3 * float(np.max(tr["distance"])), 2),
                                  W_end=float(tr["observer_energy"][-1]), rejected=round(rej, 4),
                                  wall=round(wall, 1))), flush=True)
