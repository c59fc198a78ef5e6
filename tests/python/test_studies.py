#!/usr/bin/env python3
"""Studies and maps from Python (issue 15 item 5): `palp palpate --map`'s machinery (a raster
binned into a stiffness map as numpy arrays, its figure, Otsu's mask) finds the AVC phantom's
hidden box where the phantom put it and plain coupling cannot; the displaced-bone study on the
rigid bone phantom: presses on each half feel the stiffer side where the bone is closer, as AVC's
law says (k = k_s L_ref / L); bad inputs raise palp's errors with palp's messages.

Run by ctest with Debian's /usr/bin/python3 and PYTHONPATH=<build>/python."""

import math
import os
import tempfile
import unittest

import numpy as np

import palp

BOX_QUADRANT = 2  # the AVC phantom's box under x < 0, z > 0 (quadrant = (x > 0) + 2 (z > 0))
BOX = (-0.015, 0.015)  # its centre (x, z), m; 10 mm wide, y in [20, 28] mm under the skin


def avc_scene():
    if not hasattr(avc_scene, "cached"):
        v = palp.phantom("avc", voxel_size=1e-3, quadrant=BOX_QUADRANT)
        avc_scene.cached = palp.Scene.from_volume(v)
    return avc_scene.cached


def map_plane():
    # 56 mm square over the plate (|x|, |z| <= 30 mm), 2 mm pixels, on the skin (y = 0).
    return palp.MapPlane(extent_u=0.056, extent_v=0.056, pixel=0.002)


def raster_trace(mode):
    """palp palpate --map's path: a raster over the map's square, 2 mm line spacing, 4 mm deep,
    0.1 m/s (17.5 s of simulated time, stepped in C++ with the GIL released). Without friction:
    friction tilts the proxy -> probe direction, and with it the rays, toward the motion, so the
    box would show shifted along each line."""
    params = palp.SessionParams()
    params.coupling = palp.scene_coupling_defaults("avc")  # AVC, volume accumulate
    params.coupling.mode = mode
    params.proxy.static_friction = 0
    params.proxy.dynamic_friction = 0
    raster = palp.RasterTrajectory(extent_u=0.056, extent_v=0.056, line_spacing=0.002,
                                   speed=0.1, depth=0.004)
    seconds = palp.trajectory_duration(raster)
    session = palp.Session(avc_scene(), palp.SimulatedDevice(raster), params)
    return session.run(int(math.ceil(seconds / 1e-3)))


def box_masks(plane, grow=0.0):
    """The box's footprint over the plane's pixels (grown by grow, m), from their centres."""
    c = plane.pixel_centres()
    half = 0.005 + grow
    return (np.abs(c[..., 0] - BOX[0]) < half) & (np.abs(c[..., 2] - BOX[1]) < half)


def quadrant_means(m):
    """Mean of a map's pixels per quadrant of the (x, z) plane, from the pixels' centres."""
    centres = m.plane.pixel_centres()
    q = (centres[..., 0] > 0).astype(int) + 2 * (centres[..., 2] > 0).astype(int)
    values = m.values
    return [float(np.nanmean(values[(q == i) & np.isfinite(values)])) for i in range(4)]


class AvcMap(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.avc = raster_trace("avc")
        cls.vc = raster_trace("vc")

    def test_stiffness_map_finds_the_hidden_box(self):
        plane = map_plane()
        self.assertEqual((plane.rows, plane.cols), (28, 28))
        m = palp.bin_trace(self.avc, plane, quantity="stiffness")
        self.assertEqual(m.values.shape, (28, 28))
        self.assertEqual(m.counts.dtype, np.uint32)
        self.assertGreater(np.isfinite(m.values).mean(), 0.6)  # lines on pixel edges skip rows
        m.fill_gaps(2)
        self.assertTrue(np.isfinite(m.values).all())
        # The observer of the virtual experiments: the largest quadrant mean, ties within 5 %
        # broken by a seeded choice.
        means = quadrant_means(m)
        self.assertEqual(palp.pick_largest(means, 0.05, seed=7), BOX_QUADRANT, means)
        # Over the box the rays stop in it (k > 1.5 k_s); away from it (the plate alone does
        # not stop them) k is k_s.
        box, near = box_masks(plane), box_masks(plane, grow=0.004)
        self.assertGreater(m.values[box].mean(), 1.5 * 300, m.values[box])
        np.testing.assert_allclose(m.values[~near], 300.0, rtol=1e-6)
        # Otsu's mask of the map is the box's footprint.
        mask = m.threshold(m.otsu_threshold())
        self.assertEqual(mask.dtype, np.uint8)
        self.assertGreater(palp.intersection_over_union(mask, box), 0.7)
        self.assertEqual(int(mask[~near].sum()), 0)
        # The map agrees with the trace it came from: its range is that of the contact ticks.
        contact = (self.avc["contact_count"] > 0) & (self.avc["rays"] > 0)
        k = self.avc["stiffness"][contact]
        lo, hi = m.range
        self.assertGreaterEqual(lo, k.min() - 1e-9)
        self.assertLessEqual(hi, k.max() + 1e-9)
        # The pixel under a pressed proxy over the box's centre holds a stiffened mean.
        proxies = self.avc["proxy"][contact]
        near_box = np.argmin(np.hypot(proxies[:, 0] - BOX[0], proxies[:, 2] - BOX[1]))
        row, col = plane.pixel_of(proxies[near_box])
        self.assertTrue(box[row, col])
        self.assertGreater(m.values[row, col], 1.5 * 300)
        self.assertIsNone(plane.pixel_of((0.1, 0, 0)))

    def test_plain_coupling_maps_flat(self):
        m = palp.bin_trace(self.vc, map_plane(), quantity="stiffness")
        values = m.values[np.isfinite(m.values)]
        self.assertGreater(values.size, 500)
        np.testing.assert_array_equal(values, 300.0)  # VC: k_s everywhere
        means = quadrant_means(m)
        self.assertEqual(max(means), min(means))

    def test_ray_end_and_force_maps(self):
        s = palp.summarize(self.avc)
        self.assertEqual(s["ticks"], len(self.avc["time"]))
        self.assertGreater(s["contact_fraction"], 0.8)
        self.assertEqual(s["faulted_ticks"], 0)
        self.assertGreater(s["max_stiffness"], 1.5 * s["min_stiffness"])
        force = palp.bin_trace(self.avc, map_plane(), quantity="force")
        self.assertLessEqual(force.range[1], s["max_force"] + 1e-12)
        self.assertGreater(force.range[1], 0.5 * s["max_force"])
        # Without friction the rays run along the press: their ends lie under the proxy.
        end = palp.bin_trace(self.avc, map_plane(), anchor="ray-end")
        np.testing.assert_array_equal(np.isfinite(end.values),
                                      np.isfinite(palp.bin_trace(self.avc, map_plane()).values))
        # A slice of the trace is a trace: the first half's counts are within the whole's.
        half = {k: v[: len(v) // 2] for k, v in self.avc.items()}
        first = palp.bin_trace(half, map_plane())
        whole = palp.bin_trace(self.avc, map_plane())
        self.assertTrue(np.all(first.counts <= whole.counts))
        self.assertLess(first.counts.sum(), whole.counts.sum())

    def test_figure_and_underlay(self):
        m = palp.bin_trace(self.avc, map_plane())
        m.fill_gaps(2)
        skin = palp.skin_depth_map(avc_scene(), map_plane(), press=(0, 1, 0), length=0.05)
        np.testing.assert_allclose(skin.values, 0.0, atol=0.6)  # flat skin at y = 0, mm
        with tempfile.TemporaryDirectory() as d:
            png = os.path.join(d, "map.png")
            layout = m.write_figure(png, title="avc raster", underlay=skin, bright_low=True)
            with open(png, "rb") as f:
                self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n")
            x, y, w, h = layout["map_px"]
            self.assertAlmostEqual(w, h, delta=1e-6)  # square map, square pixels
            u0, u1 = layout["u_mm"]
            self.assertAlmostEqual(u1 - u0, 56.0, delta=1e-6)
            svg = os.path.join(d, "map.svg")
            m.write_figure(svg, quantity="stiffness", units="N/m")
            with open(svg) as f:
                self.assertIn("stiffness (N/m)", f.read())
            m.write_png(os.path.join(d, "bare.png"), scale=2, color_map="grey")
            with self.assertRaises(palp.ValueError):
                m.write_png(os.path.join(d, "bad.png"), color_map="jet")
        # A map from numpy: the values come back where they were put.
        values = np.full((28, 28), np.nan)
        values[3, 5] = 2.5
        back = palp.Map(map_plane(), values)
        np.testing.assert_array_equal(back.values, values)

    def test_bad_inputs_raise_palp_errors(self):
        with self.assertRaises(palp.ValueError) as e:
            palp.bin_trace(self.avc, map_plane(), quantity="pressure")
        self.assertIn("'pressure'", str(e.exception))
        with self.assertRaises(palp.ValueError) as e:
            palp.bin_trace(self.avc, map_plane(), anchor="tip")
        self.assertIn("'tip'", str(e.exception))
        bent = map_plane()
        bent.u = (0.8, 0.6, 0)  # unit, but u . v = 0.48 with v = (0, 0.6, 0.8)
        bent.v = (0, 0.6, 0.8)
        with self.assertRaises(palp.ValueError):
            palp.bin_trace(self.avc, bent)
        broken = dict(self.avc)
        del broken["stiffness"]
        with self.assertRaises(palp.ValueError) as e:
            palp.bin_trace(broken, map_plane())
        self.assertIn("'stiffness'", str(e.exception))
        broken = dict(self.avc)
        broken["proxy"] = broken["proxy"][:10]
        with self.assertRaises(palp.ValueError) as e:
            palp.bin_trace(broken, map_plane())
        self.assertIn("'proxy' of shape (%d, 3)" % len(self.avc["time"]), str(e.exception))
        with self.assertRaises(palp.ValueError):
            palp.MapPlane(pixel=0.0).validate()
        with self.assertRaises(palp.ValueError):
            palp.intersection_over_union(np.zeros((2, 2)), np.zeros((3, 3)))


class DisplacedBone(unittest.TestCase):
    """The thesis's displaced-bone study (paper VI) on rigid tissue: the bone slab tilted 10
    degrees so that one side lies closer to the skin (displacement -1: the patient's right,
    x < 0; +1: the left), pressed 3 mm at x = -+20 mm; AVCEC's k = k_s L_ref / L with L the
    depth of the bone's top under the proxy."""

    def press_stiffness(self, scene, x):
        params = palp.SessionParams()
        params.coupling = palp.scene_coupling_defaults("bone")  # AVCEC, first hit 500 HU
        press = palp.PressTrajectory(start=(x, -0.004, 0.0), direction=(0, 1, 0), depth=0.007,
                                     press_seconds=0.3, hold_seconds=0.4)
        session = palp.Session(scene, palp.SimulatedDevice(press), params)
        trace = session.run(650)
        held = (trace["time"] > 0.4) & (trace["contact_count"] > 0)
        self.assertGreater(held.sum(), 200)
        return float(trace["stiffness"][held].mean()), trace

    def test_the_stiffer_side_is_where_the_bone_is_closer(self):
        for displacement in (-1, 0, 1):
            v = palp.phantom("bone", voxel_size=1e-3, displacement=displacement)
            scene = palp.Scene.from_volume(v)
            right, _ = self.press_stiffness(scene, -0.020)
            left, trace = self.press_stiffness(scene, 0.020)
            ratio = math.log(left / right)
            if displacement == 0:
                self.assertLess(abs(ratio), 0.02, (left, right))
                # Level bone 25 mm under the skin: k = 300 x 40 / 25.
                self.assertAlmostEqual(left, 300 * 0.040 / 0.025, delta=0.02 * 480)
                continue
            self.assertEqual(np.sign(ratio), displacement, (displacement, left, right))
            # Tilted 10 degrees: the bone's top at 25 -+ 20 tan(10) mm under each press.
            near = 0.025 - 0.020 * math.tan(math.radians(10))
            far = 0.025 + 0.020 * math.tan(math.radians(10))
            self.assertAlmostEqual(abs(ratio), math.log(far / near), delta=0.03)  # 0.275 of 0.284
            self.assertLessEqual(palp.summarize(trace)["max_force"],
                                 palp.device_spec("3D Systems Touch").max_force + 1e-12)


class StudyFromPython(unittest.TestCase):
    """A viewer running a perception study (palp.Study): each interval rendered on its own
    device (a Python object pressing the DP box), the person's answer the interval that rendered
    stiffer; the log and the results follow, and a resumed study continues where it stopped."""

    STUDY = """{"study": "python", "seed": 4, "reference_stiffness": 100,
      "procedure": {"start_level": 20, "step_sizes": [4, 2, 1], "max_trials": 4},
      "fit": {"bootstrap": 0},
      "conditions": [{"name": "DP", "touch": "discontinuous-pressure"}]}"""

    class Press:
        """From 4 mm above the DP box (x = -50 mm) to 3 mm into it in 0.3 s, then held."""

        def __init__(self):
            self.tick = 0

        def read(self):
            t = self.tick * 1e-3
            self.tick += 1
            y = -0.004 + 0.007 * min(t / 0.3, 1.0)
            v = 0.007 / 0.3 if t < 0.3 else 0.0
            return (-0.05, y, 0.0), (0.0, v, 0.0)

        def write(self, force):
            pass

    def felt(self, study, interval):
        session = palp.Session(study.scene(), self.Press(), study.interval_params(interval),
                               spec=study.device)
        trace = session.run(500)
        contact = trace["contact_count"] > 0
        self.assertGreater(int(contact.sum()), 100)
        return float(trace["stiffness"][contact].mean())

    def test_a_viewer_renders_each_interval_and_logs_the_answers(self):
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "s.json")
            with open(path, "w") as f:
                f.write(self.STUDY)
            log = os.path.join(d, "p.csv")
            study = palp.Study(path, log=log, participant=0)
            reference = None
            for _ in range(2):
                trial = study.next()
                k = [self.felt(study, 1), self.felt(study, 2)]
                c = trial["comparison_interval"] - 1
                # The comparison renders the reference's stiffness times (1 + level / 100).
                self.assertAlmostEqual(k[c] / k[1 - c], 1 + trial["level_percent"] / 100, 9)
                self.assertEqual(trial["interval_stiffness"][c], 100 * (1 + trial["level_percent"] / 100))
                reference = k[1 - c] if reference is None else reference
                self.assertAlmostEqual(k[1 - c], reference, 9)
                study.answer(1 + int(k[1] > k[0]), response_seconds=0.7)
            del study
            # Resumed from its log: the third trial is the one an uninterrupted run gives.
            study = palp.Study(path, resume=log)
            self.assertEqual(study.participant, 0)
            while not study.finished:
                trial = study.next()
                k = [self.felt(study, 1), self.felt(study, 2)]
                study.answer(1 + int(k[1] > k[0]))
            results = study.results()
            self.assertEqual(len(results), 1)
            self.assertEqual(results[0]["trials"], 4)
            with open(log) as f:
                rows = [line.split(",") for line in f if line[0] not in "#s"]
            self.assertEqual(len(rows), 4)
            self.assertEqual([r[12] for r in rows], ["1"] * 4)  # every answer correct
            self.assertEqual([float(r[5]) for r in rows], [20, 16, 12, 8])  # 1-up-1-down start
            with self.assertRaises(palp.IoError) as e:
                palp.Study(path, log=log)
            self.assertIn("the study log exists", str(e.exception))
            with self.assertRaises(palp.ValueError):
                palp.Study(path)


if __name__ == "__main__":
    unittest.main(verbosity=2)
