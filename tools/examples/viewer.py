#!/usr/bin/python3
"""A live palp session in VTK: the skin iso-surface (or a deformable body's deformed surface), the
probe, the proxy, the rays the coupling cast and the force arrow.

The session runs on palp's 1 kHz servo thread (C++); this program never runs there. A VTK timer
on the main thread redraws at display rate from the newest published snapshot
(Session.latest()), ray bundle (Session.rays()) and, on a deformable scene, surface
(Session.surface()); none of these calls waits for the servo thread.

    palp-viewer [--phantom avc|avcec|bone|stiffness|tumour | --volume SCAN [--press-axis +y]]
        [--deformable] [--mode vc|avc|avcec] [--path raster|circle|press] [--log device.csv]
        [--offscreen OUT_DIR --frames N]

(installed as bin/palp-viewer; from the source tree: /usr/bin/python3 tools/examples/viewer.py)

By default a simulated hand rasters the phantom (no device needed). --volume loads a scan instead
(a .vdb from `palp convert`, a NIfTI, NRRD or MetaImage file, or a DICOM folder; a CT in HU: skin
at -500, bone at 500; a scan without HU such as an MR: Otsu's threshold, no bone) and lays the hand's path on its skin as `palp palpate` does: on the
side across S/I with the most skin facing the press (or --press-axis), over that patch (40 mm at
most a side), 4 mm below the skin. --deformable makes the tissue a FEM body (5 mm elements,
solver auto: the whole mesh where it makes the 1 kHz tick, the threaded regions otherwise, as on
a head CT), fixed on the face opposite the press (the phantoms: at y_max) and in bone, and draws
its deformed surface. --offscreen renders N frames
at --fps to OUT_DIR/frame_NNN.png with OUT_DIR/frames.json (each frame's snapshot and the
proxy's pixel); VTK still needs an X display for that, e.g. `xvfb-run -a`.
Needs Debian's python3-vtk9 and the palp module (installed with palp next to this script's
prefix, or PYTHONPATH=build/release/python; found there automatically when run from the source
tree).
"""

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass

import numpy as np

def _import_palp():
    """The palp module: on the path; else the one installed with this script (PREFIX/bin/..
    -> PREFIX/lib/python3/dist-packages, the package's default, substituted at install); else
    the release build's, when run from the source tree."""
    try:
        import palp
        return palp
    except ModuleNotFoundError:
        pass
    here = os.path.dirname(os.path.abspath(__file__))
    python_dir = "@PALP_PYTHON_INSTALL_DIR@"  # the install writes its folder here
    candidates = [os.path.join(here, "..", "..", "build", "release", "python")]
    if not python_dir.startswith("@"):
        candidates.insert(0, os.path.join(here, "..", python_dir))
    for folder in candidates:
        if os.path.isfile(os.path.join(folder, "palp", "__init__.py")):
            sys.path.insert(0, os.path.normpath(folder))
            import palp
            return palp
    sys.exit("viewer: the palp Python module was not found (looked on sys.path and in " +
             ", ".join(os.path.normpath(c) for c in candidates) + "); set PYTHONPATH")


palp = _import_palp()

# VTK's modules one by one (a second faster to start than `import vtk`).
try:
    import vtkmodules.vtkRenderingFreeType  # noqa: F401 (text)
except ModuleNotFoundError:
    sys.exit("viewer: VTK's Python modules were not found (Debian: apt install python3-vtk9)")
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


DISPLAY_VOXELS = 4e6  # most voxels the drawn iso-surfaces are taken from


def iso_surfaces(volume, isos, max_voxels=DISPLAY_VOXELS):
    """The volume's iso-surfaces at each of isos (volume units) in world coordinates (LPS m),
    from one numpy copy of the volume's active box (flying edges in index space, then the
    affine). For display only: a volume of more than max_voxels voxels is sampled every s-th
    voxel along each axis (s the least that brings it within; a head CT at 0.5 mm: s = 3,
    about 250,000 triangles a surface instead of 2.2 million), so software OpenGL still draws
    frames at display rate. The phantoms (at 1 mm) are taken whole."""
    values, affine = volume.to_numpy(pad=1)
    stride = 1
    while values.size / stride ** 3 > max_voxels:
        stride += 1
    if stride > 1:
        values = np.ascontiguousarray(values[::stride, ::stride, ::stride])
        affine = affine.copy()
        affine[:3, :3] *= stride
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
        self.press = np.asarray(live.press, float)
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
        """Looks at the skin from the air side, against the press (palp's phantoms: surface
        y = 0 facing -y, pressed along +y), obliquely, with the air up on the screen."""
        b = np.array(self.surface.GetBounds()).reshape(3, 2)
        axis = int(np.argmax(np.abs(self.press)))
        sign = 1.0 if self.press[axis] > 0 else -1.0
        e1, e2 = [a for a in range(3) if a != axis]  # the lateral axes (x, z for a press +y)
        centre = b.mean(axis=1)
        centre[axis] = b[axis, 0] if sign > 0 else b[axis, 1]  # the face the press enters
        size = max(b[e1, 1] - b[e1, 0], b[e2, 1] - b[e2, 0])
        view = np.zeros(3)
        view[axis], view[e1], view[e2] = -0.75 * sign, 0.3, -0.6
        view /= np.linalg.norm(view)
        camera = self.scene_renderer.GetActiveCamera()
        camera.SetFocalPoint(*centre)
        camera.SetPosition(*(centre + 1.6 * size * view))
        camera.SetViewUp(*(-sign * np.eye(3)[axis]))
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
    """What the viewer shows: a session (not started yet), the skin iso-surface (None on a
    deformable scene: the session's surface is drawn) and the hard structures' iso-surface
    (bone, plates), both LPS m; the press axis (unit, into the body: the camera looks against
    it) and, on a deformable scene, the solver that runs and why (Scene.make_deformable's)."""
    session: object
    skin: object
    hard: object
    deformable: bool
    press: tuple = (0.0, 1.0, 0.0)
    solver: dict = None
    levels: object = None  # Thresholds: where the skin, tissue and hard structures are


PATH_DEPTH = 4e-3  # m below the skin: the simulated hand's press on every path
PATH_EXTENT = 0.04  # m: the raster's side (at most, on a scan's patch of skin)


def _axis_name(press):
    a = int(np.argmax(np.abs(press)))
    return ("+" if press[a] > 0 else "-") + "xyz"[a]


def skin_path(scene, patch, path):
    """A simulated hand's path on a scan's skin, as `palp palpate` lays it: the trajectory path
    ('raster', 'circle' or 'press') over patch (palp.find_skin_patch), laid on the skin's height
    measured over it (palp.SkinField; call it after make_deformable so that a body's path
    follows the body at rest), PATH_DEPTH below the skin."""
    u, v, press = (np.abs(np.asarray(patch.u)), np.abs(np.asarray(patch.v)),
                   np.asarray(patch.press, float))
    extent_u, extent_v = min(PATH_EXTENT, patch.extent_u), min(PATH_EXTENT, patch.extent_v)
    spacing, radius = 0.008, 0.015
    # Room for what leaves the rectangle (the raster's turns, the circle) and the smoothing.
    room_u = max(extent_u, 2 * radius) + 2 * spacing + 8e-3
    room_v = max(extent_v, 2 * radius) + 2 * spacing + 8e-3
    box_depth = 0.5  # m: rays long enough to cross any scan from its face
    field = palp.SkinField.measure(scene, patch.centre, u, v, press, room_u, room_v,
                                   ray_length=box_depth)
    centre = np.asarray(patch.centre, float)
    if path == "raster":
        t = palp.RasterTrajectory(centre=centre, u=u, v=v, press_direction=press,
                                  extent_u=extent_u, extent_v=extent_v, line_spacing=spacing,
                                  speed=0.05, depth=PATH_DEPTH)
    elif path == "circle":
        t = palp.CircleTrajectory(centre=centre, u=u, v=v, press_direction=press, radius=radius,
                                  frequency=0.5, depth=PATH_DEPTH)
    else:
        t = palp.PressTrajectory(start=centre - 5e-3 * press, direction=press,
                                 depth=PATH_DEPTH + 5e-3, press_seconds=2, hold_seconds=2)
    t.skin = field
    return t


@dataclass
class Thresholds:
    """Where a volume's skin, tissue and hard structures are (volume units; None: none)."""
    skin: float = -500.0  # the skin iso-surface (the proxy's surface on a rigid scene)
    tissue: float = -200.0  # a deformable body's cells are tissue above this
    hard: float = 500.0  # bone and plates: drawn, hard meshes, a body's fixed nodes
    otsu: bool = False  # from Otsu's threshold: a scan without HU


def scan_thresholds(volume):
    """CT in HU (-500, -200, 500), unless the scan has no HU (`palp palpate`'s rule: its modality
    is not CT and no active value lies below -100, e.g. an MR): then its skin and tissue are
    Otsu's threshold of its active values (256 bins between their least and greatest) and it
    has no hard structure."""
    if volume.info.get("modality") == "CT":
        return Thresholds()
    values, _ = volume.to_numpy()
    active = values[values != volume.background].astype(np.float64)
    if active.size == 0:
        return Thresholds()
    lo, hi = float(active.min()), float(active.max())
    if not (lo >= -100.0 and hi > lo):
        return Thresholds()
    scale = 255.0 / (hi - lo)
    hist = np.bincount(np.clip((active - lo) * scale, 0, 255).astype(int), minlength=256)
    bins = np.arange(256, dtype=np.float64)
    below = np.cumsum(hist)[:-1].astype(np.float64)
    below_sum = np.cumsum(bins * hist)[:-1]
    above = active.size - below
    with np.errstate(divide="ignore", invalid="ignore"):
        between = below * above * (below_sum / below -
                                   (float(bins @ hist) - below_sum) / above) ** 2
    between[(below <= 0) | (above <= 0)] = -1
    split = int(np.argmax(between))
    threshold = lo + (split + 1.0) / scale
    return Thresholds(skin=threshold, tissue=threshold, hard=None, otsu=True)


def make_session(phantom="avc", deformable=False, mode=None, path="raster", log=None,
                 voxel_size=None, surface_iso=None, hard_iso=None, volume_path=None,
                 press=None, servo_priority=80):
    """A phantom (or, with volume_path, a scan) scene, a device (a simulated hand on path, or a
    CSV log) and a session on it (not started). voxel_size: m (None: 1 mm for a phantom, the
    file's own for a scan). surface_iso, hard_iso: volume units (None: -500 and 500 HU for a
    phantom or a CT, scan_thresholds() for a scan without HU). press: a scan's press axis
    ('+y', ...; None: palp chooses)."""
    if volume_path is not None:
        volume = palp.load(volume_path, voxel_size=voxel_size)
        levels = scan_thresholds(volume)
    else:
        volume = palp.phantom(phantom, voxel_size=voxel_size or 1e-3)
        levels = Thresholds()
    if surface_iso is not None:
        if levels.otsu:  # a scan without HU: its tissue starts at its skin
            levels.tissue = surface_iso
        levels.skin = surface_iso
    if hard_iso is not None:
        levels.hard = hard_iso
    surface_iso, hard_iso = levels.skin, levels.hard
    scene = palp.Scene.from_volume(volume, surface_iso=surface_iso, hard_iso=hard_iso)
    patch = None
    press_axis = (0.0, 1.0, 0.0)
    if volume_path is not None:
        # The patch on the iso-surface, before the body exists (palp palpate's order): the
        # body's 5 mm cells are a staircase with no patch of skin facing anywhere.
        patch = palp.find_skin_patch(scene, volume, press)
        press_axis = tuple(float(x) for x in patch.press)
    solver = None
    if deformable:
        a = int(np.argmax(np.abs(press_axis)))
        support = "xyz"[a] + ("_max" if press_axis[a] > 0 else "_min")  # opposite the press
        # On a scan the regions start under the path and slide over the skin of its patch
        # (palp palpate's choice): every move of the contact then comes from the body's factor.
        where = {} if patch is None else {"regions_centre": tuple(patch.centre),
                                          "slide_patch": patch}
        solver = scene.make_deformable(volume, element_size=5e-3, support_face=support,
                                       solver="auto", tissue_threshold=levels.tissue,
                                       bone_threshold=math.inf if hard_iso is None else hard_iso,
                                       **where)
    params = palp.SessionParams()
    params.coupling = (palp.scene_coupling_defaults(phantom) if volume_path is None else
                       palp.scan_coupling_defaults())
    if mode:
        params.coupling.mode = mode
    if log:
        device = palp.PlaybackDevice(log)
    elif patch is not None:
        device = palp.SimulatedDevice(skin_path(scene, patch, path))
    else:
        trajectories = {
            "raster": lambda: palp.RasterTrajectory(extent_u=PATH_EXTENT, extent_v=PATH_EXTENT,
                                                    line_spacing=0.008, speed=0.05),
            "circle": lambda: palp.CircleTrajectory(radius=0.015, frequency=0.5),
            "press": lambda: palp.PressTrajectory(start=[0, -0.005, 0], direction=[0, 1, 0],
                                                  depth=0.01, press_seconds=2, hold_seconds=2),
        }
        device = palp.SimulatedDevice(trajectories[path]())
    # servo_priority: SCHED_FIFO priority of the servo thread (0: normal priority, where a
    # session that cannot keep 1 kHz runs slower instead of giving up its force).
    session = palp.Session(scene, device, params, servo_priority=servo_priority)
    isos = ([] if deformable else [surface_iso]) + ([] if hard_iso is None else [hard_iso])
    surfaces = iso_surfaces(volume, isos)
    skin = None if deformable else surfaces.pop(0)  # a body's own surface is drawn instead
    hard = surfaces[0] if surfaces else vtkPolyData()  # none: a scan without HU
    return Live(session, skin, hard, deformable, press_axis, solver, levels)


def frame_record(viewer, s):
    return {
        "tick": int(s.tick), "time": float(s.time),
        "proxy": [float(x) for x in s.proxy], "probe": [float(x) for x in s.probe],
        "force": [float(x) for x in s.force], "rays": int(s.rays),
        "contact_count": int(s.contact_count), "max_displacement": float(s.max_displacement),
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
    ap.add_argument("--volume", metavar="SCAN",
                    help="a scan instead of a phantom: .vdb (palp convert), NIfTI, NRRD, "
                         "MetaImage or a DICOM folder (CT, HU); the path is laid on its skin")
    ap.add_argument("--press-axis", choices=["+x", "-x", "+y", "-y", "+z", "-z"],
                    help="--volume: the press axis into the body (default: the side across "
                         "S/I with the most skin facing it)")
    ap.add_argument("--surface-iso", type=float,
                    help="the skin's value (default -500 HU; a scan without HU: Otsu's "
                         "threshold)")
    ap.add_argument("--hard-iso", type=float,
                    help="bone and plates above this value (default 500 HU; a scan without "
                         "HU: none)")
    ap.add_argument("--deformable", action="store_true",
                    help="FEM body (5 mm elements, solver auto, supported on the face opposite "
                         "the press and in bone): draws its deformed surface")
    ap.add_argument("--mode", choices=["vc", "avc", "avcec"],
                    help="coupling mode (default: the phantom's)")
    ap.add_argument("--path", default="raster", choices=["raster", "circle", "press"],
                    help="the simulated hand's path")
    ap.add_argument("--log", help="replay a device log (CSV) instead of a simulated hand")
    ap.add_argument("--voxel-size", type=float,
                    help="voxel size, m (default: 1 mm for a phantom, the scan's own for "
                         "--volume)")
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
    if a.press_axis and not a.volume:
        ap.error("--press-axis: expected with --volume (a phantom is pressed along +y)")
    if a.voxel_size is not None and not a.voxel_size > 0:
        ap.error(f"--voxel-size: expected a size > 0 m, found {a.voxel_size}")
    if a.volume and not os.path.exists(a.volume):
        ap.error(f"--volume: expected a scan file or DICOM folder, found no '{a.volume}'")
    try:
        live = make_session(a.phantom, a.deformable, a.mode, a.path, a.log, a.voxel_size,
                            surface_iso=a.surface_iso, hard_iso=a.hard_iso,
                            volume_path=a.volume, press=a.press_axis)
    except palp.Error as e:
        sys.exit(f"viewer: error: {e}")
    if a.volume:
        if live.levels.otsu:
            print(f"viewer: {a.volume}: no HU: skin and tissue above {live.levels.skin:.4g} "
                  f"(Otsu), no bone")
        print(f"viewer: {a.volume}: path on the skin, pressed along {_axis_name(live.press)}")
    if live.solver:
        print(f"viewer: deformable, {live.solver['reason']}")
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
