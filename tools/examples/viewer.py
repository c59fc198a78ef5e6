#!/usr/bin/python3
"""A live palp session in VTK: the skin iso-surface (or a deformable body's deformed surface), the
probe, the proxy, the rays the coupling cast and the force arrow.

The session runs on palp's 1 kHz servo thread (C++); this program never runs there. A VTK timer
on the main thread redraws at display rate from the newest published snapshot
(Session.latest()), ray bundle (Session.rays()) and, on a deformable scene, surface
(Session.surface()); none of these calls waits for the servo thread.

    /usr/bin/python3 tools/examples/viewer.py [--phantom avc|avcec|bone|stiffness|tumour]
        [--deformable] [--mode vc|avc|avcec] [--path raster|circle|press] [--log device.csv]
        [--offscreen OUT_DIR --frames N]

By default a simulated hand rasters the phantom (no device needed). --offscreen renders N frames
at --fps to OUT_DIR/frame_NNN.png with OUT_DIR/frames.json (each frame's snapshot and the
proxy's pixel); VTK still needs an X display for that, e.g. `xvfb-run -a`.
Needs Debian's python3-vtk9 and the palp module (PYTHONPATH=build/release/python; found there
automatically when run from the source tree).
"""

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass

import numpy as np

try:
    import palp
except ModuleNotFoundError:  # run from the source tree: use the release build's module
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..",
                                    "build", "release", "python"))
    import palp

# VTK's modules one by one (a second faster to start than `import vtk`).
import vtkmodules.vtkRenderingFreeType  # noqa: F401 (text)
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401 (the OpenGL implementations)
from vtkmodules.util import numpy_support
from vtkmodules.vtkCommonCore import VTK_ID_TYPE, vtkPoints, vtkUnsignedCharArray
from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkImageData, vtkPolyData
from vtkmodules.vtkCommonMath import vtkMatrix4x4
from vtkmodules.vtkCommonTransforms import vtkTransform
from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D, vtkPolyDataNormals
from vtkmodules.vtkFiltersGeneral import vtkTransformPolyDataFilter
from vtkmodules.vtkFiltersSources import vtkArrowSource, vtkSphereSource
from vtkmodules.vtkInteractionStyle import vtkInteractorStyleTrackballCamera
from vtkmodules.vtkIOImage import vtkPNGWriter
from vtkmodules.vtkRenderingCore import (vtkActor, vtkCoordinate, vtkPolyDataMapper,
                                         vtkRenderer, vtkRenderWindow,
                                         vtkRenderWindowInteractor, vtkTextActor,
                                         vtkWindowToImageFilter)

# Unlit marker colours (RGB 0..255): the proxy and the force arrow are drawn without lighting so
# that every pixel of theirs has exactly this colour (the test segments them by colour).
PROXY_RGB = (0, 204, 0)
ARROW_RGB = (230, 0, 230)
PROBE_RGB = (60, 110, 255)
SKIN_RGB = (235, 190, 160)
HARD_RGB = (225, 225, 205)
CENTRE_RAY_RGB = (255, 80, 40)
RAY_RGB = (255, 215, 40)
BACKGROUND_RGB = (26, 26, 31)


def _rgb(c):
    return tuple(x / 255.0 for x in c)


def iso_surfaces(volume, isos):
    """The volume's iso-surfaces at each of isos (volume units) in world coordinates (LPS m),
    from one numpy copy of the volume's active box (flying edges in index space, then the
    affine)."""
    values, affine = volume.to_numpy(pad=1)
    image = vtkImageData()
    image.SetDimensions(*values.shape)
    image.GetPointData().SetScalars(
        numpy_support.numpy_to_vtk(values.ravel(order="F"), deep=True))  # i fastest
    matrix = vtkMatrix4x4()
    for r in range(4):
        for c in range(4):
            matrix.SetElement(r, c, float(affine[r, c]))
    transform = vtkTransform()
    transform.SetMatrix(matrix)
    surfaces = []
    for iso in isos:
        contour = vtkFlyingEdges3D()
        contour.SetInputData(image)
        contour.SetValue(0, iso)
        contour.ComputeNormalsOff()
        to_world = vtkTransformPolyDataFilter()
        to_world.SetInputConnection(contour.GetOutputPort())
        to_world.SetTransform(transform)
        normals = vtkPolyDataNormals()
        normals.SetInputConnection(to_world.GetOutputPort())
        normals.SplittingOff()
        normals.Update()
        out = vtkPolyData()
        out.DeepCopy(normals.GetOutput())
        surfaces.append(out)
    return surfaces


def _unlit(actor, rgb):
    p = actor.GetProperty()
    p.SetColor(_rgb(rgb))
    p.LightingOff()
    p.SetAmbient(1.0)
    p.SetDiffuse(0.0)
    p.SetSpecular(0.0)


def _frame_matrix(origin, axis, length, width):
    """A 4x4 taking vtkArrowSource's unit arrow (along +x) to one of @p length along unit
    @p axis from @p origin, @p width across."""
    a = np.asarray(axis, float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    m = vtkMatrix4x4()
    for r in range(3):
        m.SetElement(r, 0, a[r] * length)
        m.SetElement(r, 1, e1[r] * width)
        m.SetElement(r, 2, e2[r] * width)
        m.SetElement(r, 3, origin[r])
    return m


class Viewer:
    """The scene's actors and the window; update() reads the session, render() draws.

    Two renderers share one camera: layer 0 the skin (translucent), layer 1 the probe, proxy,
    rays and force arrow, drawn over the skin so that a probe pressed under the skin stays
    visible. Everything here runs on the thread that created it (the main thread)."""

    def __init__(self, live, size=(800, 600), offscreen=False):
        self.session = live.session
        self.deformable = live.deformable
        self.snapshot = None
        self._last = None  # (tick, wall time) of the previous update, for the servo rate
        self.servo_hz = float("nan")

        self.window = vtkRenderWindow()
        self.window.SetSize(*size)
        self.window.SetMultiSamples(0)  # exact marker colours (no MSAA blending at edges)
        self.window.SetNumberOfLayers(2)
        self.window.SetWindowName("palp viewer")
        if offscreen:
            self.window.SetOffScreenRendering(1)
        self.scene_renderer = vtkRenderer()
        self.scene_renderer.SetBackground(_rgb(BACKGROUND_RGB))
        self.scene_renderer.SetLayer(0)
        self.tool_renderer = vtkRenderer()
        self.tool_renderer.SetLayer(1)
        self.tool_renderer.InteractiveOff()
        self.tool_renderer.SetActiveCamera(self.scene_renderer.GetActiveCamera())
        self.window.AddRenderer(self.scene_renderer)
        self.window.AddRenderer(self.tool_renderer)

        # The skin: a fixed iso-surface, or the deformable body's surface (points per frame).
        self.surface = vtkPolyData()
        if self.deformable:
            vertices, triangles = self.session.surface()
            self.surface.SetPoints(vtkPoints())
            self._set_surface_points(vertices)
            cells = vtkCellArray()
            offsets = np.arange(0, 3 * len(triangles) + 1, 3, dtype=np.int64)
            cells.SetData(numpy_support.numpy_to_vtk(offsets, deep=True,
                                                     array_type=VTK_ID_TYPE),
                          numpy_support.numpy_to_vtk(triangles.astype(np.int64).ravel(),
                                                     deep=True, array_type=VTK_ID_TYPE))
            self.surface.SetPolys(cells)
            normals = vtkPolyDataNormals()
            normals.SetInputData(self.surface)
            normals.SplittingOff()
            skin_mapper = vtkPolyDataMapper()
            skin_mapper.SetInputConnection(normals.GetOutputPort())
        else:
            self.surface.DeepCopy(live.skin)
            skin_mapper = vtkPolyDataMapper()
            skin_mapper.SetInputData(self.surface)
        b = self.surface.GetBounds()
        extent = max(b[1] - b[0], b[3] - b[2], b[5] - b[4])
        self.marker_radius = 0.025 * extent  # proxy sphere, m
        self.newtons_to_m = 0.25 * extent  # arrow length per newton
        self.arrow_max = 0.4 * extent
        skin_mapper.ScalarVisibilityOff()
        self.skin_actor = vtkActor()
        self.skin_actor.SetMapper(skin_mapper)
        self.skin_actor.GetProperty().SetColor(_rgb(SKIN_RGB))
        self.skin_actor.GetProperty().SetOpacity(0.45)
        # Closed iso-surfaces: only the faces toward the camera, so the far side does not show
        # through the translucent near side.
        self.skin_actor.GetProperty().BackfaceCullingOn()
        self.skin_actor.GetProperty().SetSpecular(0.2)
        self.scene_renderer.AddActor(self.skin_actor)
        # Hard structures (bone, plates) at rest, opaque, seen through the skin.
        hard_mapper = vtkPolyDataMapper()
        hard_mapper.SetInputData(live.hard)
        hard_mapper.ScalarVisibilityOff()
        self.hard_actor = vtkActor()
        self.hard_actor.SetMapper(hard_mapper)
        self.hard_actor.GetProperty().SetColor(_rgb(HARD_RGB))
        self.scene_renderer.AddActor(self.hard_actor)

        # Proxy (unlit), probe (lit) and the force arrow (unlit).
        self.proxy_actor = self._sphere(self.marker_radius, PROXY_RGB, lit=False)
        self.probe_actor = self._sphere(0.6 * self.marker_radius, PROBE_RGB, lit=True)
        arrow = vtkArrowSource()
        arrow.SetTipLength(0.3)
        arrow.SetTipRadius(0.5)
        arrow.SetShaftRadius(0.18)
        arrow.SetTipResolution(24)
        arrow.SetShaftResolution(16)
        arrow_mapper = vtkPolyDataMapper()
        arrow_mapper.SetInputConnection(arrow.GetOutputPort())
        self.arrow_actor = vtkActor()
        self.arrow_actor.SetMapper(arrow_mapper)
        _unlit(self.arrow_actor, ARROW_RGB)
        self.tool_renderer.AddActor(self.arrow_actor)

        # Rays: one polydata of line segments, coloured per ray (centre ray apart).
        self.rays = vtkPolyData()
        self.ray_colours = vtkUnsignedCharArray()
        self.ray_colours.SetNumberOfComponents(3)
        ray_mapper = vtkPolyDataMapper()
        ray_mapper.SetInputData(self.rays)
        ray_mapper.SetScalarModeToUseCellData()
        self.ray_actor = vtkActor()
        self.ray_actor.SetMapper(ray_mapper)
        self.ray_actor.GetProperty().SetLineWidth(2.0)
        self.ray_actor.GetProperty().LightingOff()
        self.tool_renderer.AddActor(self.ray_actor)

        self.text = vtkTextActor()
        self.text.GetTextProperty().SetFontSize(14)
        self.text.GetTextProperty().SetColor(0.9, 0.9, 0.9)
        self.text.SetDisplayPosition(10, 10)
        self.tool_renderer.AddActor2D(self.text)

        self._place_camera()

    def _sphere(self, radius, rgb, lit):
        source = vtkSphereSource()
        source.SetRadius(radius)
        source.SetThetaResolution(32)
        source.SetPhiResolution(24)
        mapper = vtkPolyDataMapper()
        mapper.SetInputConnection(source.GetOutputPort())
        actor = vtkActor()
        actor.SetMapper(mapper)
        if lit:
            actor.GetProperty().SetColor(_rgb(rgb))
        else:
            _unlit(actor, rgb)
        self.tool_renderer.AddActor(actor)
        return actor

    def _set_surface_points(self, vertices):
        self.surface.GetPoints().SetData(
            numpy_support.numpy_to_vtk(np.ascontiguousarray(vertices, dtype=np.float32),
                                       deep=True))
        self.surface.GetPoints().Modified()
        self.surface.Modified()

    def _place_camera(self):
        """Looks at the skin from the air side (palp's phantoms: surface y = 0 facing -y),
        obliquely, with the air up on the screen."""
        b = self.surface.GetBounds()
        centre = np.array([(b[0] + b[1]) / 2, b[2], (b[4] + b[5]) / 2])
        size = max(b[1] - b[0], b[5] - b[4])
        view = np.array([0.3, -0.75, -0.6])
        view /= np.linalg.norm(view)
        camera = self.scene_renderer.GetActiveCamera()
        camera.SetFocalPoint(*centre)
        camera.SetPosition(*(centre + 1.6 * size * view))
        camera.SetViewUp(0.0, -1.0, 0.0)
        camera.OrthogonalizeViewUp()
        camera.SetViewAngle(35.0)
        self.scene_renderer.ResetCameraClippingRange()
        camera.SetClippingRange(0.02 * size, 6.0 * size)

    def update(self):
        """Reads the newest snapshot (and deformed surface) and moves the actors; returns the
        snapshot drawn."""
        s = self.session.latest()
        now = time.monotonic()
        if self._last is not None and now > self._last[1] and s.tick > self._last[0]:
            rate = (s.tick - self._last[0]) / (now - self._last[1])
            self.servo_hz = rate if math.isnan(self.servo_hz) else 0.8 * self.servo_hz + 0.2 * rate
        self._last = (s.tick, now)
        self.snapshot = s
        if self.deformable:
            surface = self.session.surface()
            if surface is not None:
                self._set_surface_points(surface[0])
        self.proxy_actor.SetPosition(*s.proxy)
        self.probe_actor.SetPosition(*s.probe)
        self._update_arrow(s)
        self._update_rays(s)
        self.text.SetInput(
            f"t {s.time:6.2f} s   tick {s.tick}   |F| {np.linalg.norm(s.force):.2f} N   "
            f"k {s.stiffness:.0f} N/m   {s.mode}   rays {s.rays}   "
            f"servo {self.servo_hz:.0f} Hz" +
            (f"   max displacement {1e3 * s.max_displacement:.1f} mm" if self.deformable else ""))
        return s

    def _update_arrow(self, s):
        f = np.asarray(s.force)
        magnitude = float(np.linalg.norm(f))
        if magnitude < 1e-6:
            self.arrow_actor.VisibilityOff()
            return
        axis = f / magnitude
        length = min(self.newtons_to_m * magnitude, self.arrow_max)
        base = np.asarray(s.proxy) + self.marker_radius * axis  # starts on the proxy sphere
        self.arrow_actor.SetUserMatrix(_frame_matrix(base, axis, length, 0.5 * self.marker_radius))
        self.arrow_actor.VisibilityOn()

    def _update_rays(self, s):
        points = vtkPoints()
        lines = vtkCellArray()
        self.ray_colours.Reset()
        # The newest tick's bundle (published by the servo thread like the snapshot; the two
        # may be a tick apart): the first s.rays rays were traced.
        bundle = self.session.rays()
        n = min(int(s.rays), len(bundle["lengths"]))
        if n > 0:
            for r in list(range(1, n)) + [0]:  # the centre ray last, over the others
                o = bundle["origins"][r]
                # The centre ray ends where the tick measured it (L); the others at L_max
                # (their lengths are not published).
                length = s.ray_length if r == 0 else bundle["lengths"][r]
                lines.InsertNextCell(2)
                lines.InsertCellPoint(points.InsertNextPoint(*o))
                lines.InsertCellPoint(points.InsertNextPoint(*(o + length *
                                                               bundle["directions"][r])))
                self.ray_colours.InsertNextTuple3(*(CENTRE_RAY_RGB if r == 0 else RAY_RGB))
        self.rays.SetPoints(points)
        self.rays.SetLines(lines)
        self.rays.GetCellData().SetScalars(self.ray_colours)
        self.rays.Modified()

    def render(self):
        self.window.Render()

    def save_png(self, path):
        grab = vtkWindowToImageFilter()
        grab.SetInput(self.window)
        grab.SetInputBufferTypeToRGB()
        grab.ReadFrontBufferOff()
        grab.Update()
        writer = vtkPNGWriter()
        writer.SetFileName(path)
        writer.SetInputConnection(grab.GetOutputPort())
        writer.Write()

    def to_display(self, world):
        """World point (m) -> display pixel (x right, y up from the bottom-left, VTK's display
        coordinates) through the current camera."""
        c = vtkCoordinate()
        c.SetCoordinateSystemToWorld()
        c.SetValue(*[float(x) for x in world])
        return np.array(c.GetComputedDoubleDisplayValue(self.scene_renderer))


@dataclass
class Live:
    """What the viewer shows: a session (not started yet), the skin iso-surface (None on a deformable scene: the session's surface is drawn) and the
    hard structures' iso-surface (bone, plates), both LPS m."""
    session: object
    skin: object
    hard: object
    deformable: bool


def make_session(phantom="avc", deformable=False, mode=None, path="raster", log=None,
                 voxel_size=1e-3, surface_iso=-500.0, hard_iso=500.0):
    """A phantom scene, a device (a simulated hand on path, or a CSV log) and a session on it
    (not started)."""
    volume = palp.phantom(phantom, voxel_size=voxel_size)
    scene = palp.Scene.from_volume(volume, surface_iso=surface_iso, hard_iso=hard_iso)
    if deformable:
        scene.make_deformable(volume, element_size=5e-3, support_face="y_max")
    params = palp.SessionParams()
    params.coupling = palp.scene_coupling_defaults(phantom)
    if mode:
        params.coupling.mode = mode
    if log:
        device = palp.PlaybackDevice(log)
    else:
        trajectories = {
            "raster": lambda: palp.RasterTrajectory(extent_u=0.04, extent_v=0.04,
                                                    line_spacing=0.008, speed=0.05),
            "circle": lambda: palp.CircleTrajectory(radius=0.015, frequency=0.5),
            "press": lambda: palp.PressTrajectory(start=[0, -0.005, 0], direction=[0, 1, 0],
                                                  depth=0.01, press_seconds=2, hold_seconds=2),
        }
        device = palp.SimulatedDevice(trajectories[path]())
    session = palp.Session(scene, device, params)
    skin, hard = iso_surfaces(volume, [surface_iso, hard_iso])
    return Live(session, None if deformable else skin, hard, deformable)


def frame_record(viewer, s):
    return {
        "tick": int(s.tick), "time": float(s.time),
        "proxy": [float(x) for x in s.proxy], "probe": [float(x) for x in s.probe],
        "force": [float(x) for x in s.force], "rays": int(s.rays),
        "proxy_pixel": [float(x) for x in viewer.to_display(s.proxy)[:2]],
    }


def run_offscreen(viewer, out_dir, frames, fps):
    os.makedirs(out_dir, exist_ok=True)
    records = []
    period = 1.0 / fps
    next_frame = time.monotonic()
    for i in range(frames):
        next_frame += period
        time.sleep(max(0.0, next_frame - time.monotonic()))
        start = time.perf_counter()
        s = viewer.update()
        viewer.render()
        drawn = time.perf_counter()
        path = os.path.join(out_dir, f"frame_{i:03d}.png")
        viewer.save_png(path)
        records.append(dict(frame_record(viewer, s), png=os.path.basename(path),
                            draw_ms=1e3 * (drawn - start),
                            png_ms=1e3 * (time.perf_counter() - drawn)))
    with open(os.path.join(out_dir, "frames.json"), "w") as f:
        json.dump({"frames": records}, f, indent=1)
    return records


def run_interactive(viewer, fps, frames=None):
    """The window with mouse interaction; a repeating VTK timer (main thread) redraws at fps
    until the window closes, or after frames redraws. Returns the ticks of the snapshots drawn."""
    interactor = vtkRenderWindowInteractor()
    interactor.SetRenderWindow(viewer.window)
    interactor.SetInteractorStyle(vtkInteractorStyleTrackballCamera())
    interactor.Initialize()
    ticks = []

    def on_timer(_obj, _event):
        ticks.append(viewer.update().tick)
        viewer.render()
        if frames is not None and len(ticks) >= frames:
            interactor.TerminateApp()

    interactor.AddObserver("TimerEvent", on_timer)
    interactor.CreateRepeatingTimer(max(1, int(1000 / fps)))
    viewer.update()
    viewer.render()
    interactor.Start()
    return ticks


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phantom", default="avc",
                    choices=["avc", "avcec", "bone", "stiffness", "tumour"])
    ap.add_argument("--deformable", action="store_true",
                    help="FEM body (5 mm elements, supported at y_max): draws its deformed "
                         "surface")
    ap.add_argument("--mode", choices=["vc", "avc", "avcec"],
                    help="coupling mode (default: the phantom's)")
    ap.add_argument("--path", default="raster", choices=["raster", "circle", "press"],
                    help="the simulated hand's path")
    ap.add_argument("--log", help="replay a device log (CSV) instead of a simulated hand")
    ap.add_argument("--voxel-size", type=float, default=1e-3, help="phantom voxel size, m")
    ap.add_argument("--fps", type=float, default=30.0, help="display rate, frames/s")
    ap.add_argument("--size", default="800x600", help="window size WxH, pixels")
    ap.add_argument("--offscreen", metavar="OUT_DIR",
                    help="render --frames frames to OUT_DIR/frame_NNN.png and frames.json")
    ap.add_argument("--frames", type=int, default=30)
    a = ap.parse_args(argv)
    if a.offscreen and a.frames < 1:
        ap.error(f"--frames: expected at least 1, found {a.frames}")
    try:
        width, height = (int(x) for x in a.size.lower().split("x"))
    except ValueError:
        ap.error(f"--size: expected WxH (e.g. 800x600), found '{a.size}'")
    if not os.environ.get("DISPLAY"):
        sys.exit("viewer: no X display (DISPLAY is unset); VTK renders through X even off-screen: "
                 "run under `xvfb-run -a`")
    live = make_session(a.phantom, a.deformable, a.mode, a.path, a.log, a.voxel_size)
    session = live.session
    viewer = Viewer(live, (width, height), offscreen=bool(a.offscreen))
    session.start()  # the 1 kHz servo thread (C++); VTK stays on this thread
    try:
        if a.offscreen:
            records = run_offscreen(viewer, a.offscreen, a.frames, a.fps)
            ticks = records[-1]["tick"] - records[0]["tick"]
            seconds = records[-1]["time"] - records[0]["time"]
            draw = np.median([r["draw_ms"] for r in records[1:]] or [records[0]["draw_ms"]])
            print(f"viewer: {len(records)} frames in {a.offscreen}; median update + render "
                  f"{draw:.1f} ms; servo {viewer.servo_hz:.0f} Hz of wall time, "
                  f"{ticks} ticks in {seconds:.3f} s of session time")
        else:
            run_interactive(viewer, a.fps)
    finally:
        session.stop()


if __name__ == "__main__":
    main()
