#!/usr/bin/env python3
"""A 10 s, 1 kHz offline session (AVC phantom at 0.5 mm, AVCEC, a raster) stepped three ways:
Session.run() (the C++ loop, GIL released), Session.step() from a Python loop, and run() with a
host device written in Python (a SimulatedDevice behind read()/write()). Best of 3.

PYTHONPATH=build/release/python /usr/bin/python3 bench/python/bench_session.py"""

import time

import palp

TICKS = 10000


def params():
    p = palp.SessionParams()
    p.coupling = palp.scene_coupling_defaults("avc")
    p.coupling.mode = "avcec"
    return p


def path():
    return palp.RasterTrajectory(extent_u=0.04, extent_v=0.04, line_spacing=0.004, speed=0.05)


class Host:
    def __init__(self):
        self.inner = palp.SimulatedDevice(path())

    def read(self):
        position, velocity, _ = self.inner.read()
        return position, velocity

    def write(self, force):
        self.inner.write(force)


def main():
    volume = palp.phantom("avc", voxel_size=0.5e-3)
    scene = palp.Scene.from_volume(volume, surface_iso=-500, hard_iso=500)
    base = None
    for name in ("run() (C++ loop)", "step() from Python", "Python device, run()"):
        best = float("inf")
        for _ in range(3):
            device = Host() if name.startswith("Python device") else palp.SimulatedDevice(path())
            session = palp.Session(scene, device, params())
            start = time.perf_counter()
            if name.startswith("step()"):
                for _ in range(TICKS):
                    session.step()
            else:
                session.run(TICKS)
            best = min(best, time.perf_counter() - start)
        base = base or best
        print(f"{name:22s} {best * 1e3:7.1f} ms / {TICKS} ticks  {best / TICKS * 1e6:5.1f} us/tick"
              f"  {best / base:4.2f}x")


if __name__ == "__main__":
    main()
