"""palp: haptic volume palpation from Python.

Volumes (palp.load, palp.phantom, palp.convert, palp.volume_from_numpy, Volume.to_numpy,
pyopenvdb interop), scenes and sessions stepped offline (palp.Scene, palp.Session with a
SimulatedDevice, PlaybackDevice or a Python object as the device), snapshots and traces as
numpy arrays, studies and maps (palp.MapPlane, palp.bin_trace -> palp.Map with numpy values,
figures and underlays, Otsu masks, palp.summarize, palp.pick_largest). World coordinates are
LPS metres unless a function says otherwise. Errors are palp.ValueError / palp.FormatError
(subclasses of ValueError) and palp.IoError (an OSError), all palp.Error, carrying palp's
messages.

The C++ core is palp._palp; see README.md, "Python" (and docs/api.md for the whole reference).
"""

import os
import tempfile

import numpy as np

from ._palp import *  # noqa: F401,F403 (the module's public names)
from ._palp import _volume_from_array

__all__ = [n for n in dir() if not n.startswith("_")] + [
    "volume_from_numpy", "to_pyopenvdb", "volume_from_pyopenvdb"]

_DTYPES = tuple(np.dtype(t) for t in (
    np.int8, np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.float32, np.float64))


def volume_from_numpy(array, affine, frame="LPS", units="m", voxel_size=None,
                      background_threshold=None, modality="", name="numpy array"):
    """A Volume from a 3-D array whose voxel (i, j, k) lies at affine @ (i, j, k, 1).

    affine: 4x4 index-to-world in frame 'LPS' (palp's, DICOM's) or 'RAS' (NIfTI's, Slicer's),
    units 'm' or 'mm'. modality 'CT' makes values below -900 (or background_threshold)
    inactive background of -1000 HU, like a CT read from a file; 'MR' has no threshold (every
    value kept, signed field maps and phase images included); otherwise the threshold defaults
    to 0. The voxels are resampled onto isotropic voxels of voxel_size metres
    (default: the finest axis spacing), checked like a file reader's input (palp.ValueError
    naming the value).

    Copies: int8..int32, uint8..uint32, float32 and float64 arrays in native byte order are
    read in place, any strides (Fortran, C or sliced views); the values are then converted to
    float slices once, as for a file. Other dtypes (bool, float16, int64, ...), byte-swapped
    arrays and arrays with negative strides are first copied into a C-ordered array (int64 and
    uint64 to float64, anything else to float32).
    """
    a = np.asarray(array)
    if a.dtype not in _DTYPES or not a.dtype.isnative or any(s < 0 for s in a.strides):
        target = a.dtype.newbyteorder("=") if a.dtype.newbyteorder("=") in _DTYPES else (
            np.float64 if a.dtype.kind in "iu" else np.float32)
        a = np.ascontiguousarray(a, dtype=target)
    m = np.asarray(affine, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"affine: expected a 4x4 matrix, found shape {m.shape}")
    return _volume_from_array(a, m, frame, units, voxel_size, background_threshold, modality,
                              name)


def _pyopenvdb():
    try:
        import pyopenvdb
    except ImportError as e:  # Debian: python3-openvdb
        raise ImportError("palp's pyopenvdb interop needs pyopenvdb (Debian: python3-openvdb)"
                          ) from e
    version = tuple(getattr(pyopenvdb, "LIBRARY_VERSION", (0, 0, 0)))
    if version < (10, 0, 0):
        raise ImportError(f"palp's pyopenvdb interop needs OpenVDB 10 or later (palp's .vdb "
                          f"files), found pyopenvdb {version}")
    return pyopenvdb


def to_pyopenvdb(volume):
    """The volume as a pyopenvdb.FloatGrid (grid 'scan', palp's metadata, index -> LPS metres).

    pyopenvdb (Boost.Python) and palp each link their own OpenVDB, so the grid crosses through
    a temporary .vdb file (a copy of the sparse tree, compressed; no dense copy)."""
    vdb = _pyopenvdb()
    with tempfile.TemporaryDirectory(prefix="palp_") as d:
        path = os.path.join(d, "scan.vdb")
        volume.save(path, compression="active-mask")
        return vdb.read(path, "scan")


def volume_from_pyopenvdb(grid):
    """A Volume from a pyopenvdb.FloatGrid (through a temporary .vdb file, checked like any
    .vdb palp reads: linear transform, cubic voxels, finite values). World: the grid's
    index-to-world map taken as LPS metres."""
    vdb = _pyopenvdb()
    with tempfile.TemporaryDirectory(prefix="palp_") as d:
        path = os.path.join(d, "grid.vdb")
        if grid.name != "scan":
            grid = grid.deepCopy()
            grid.name = "scan"
        vdb.write(path, grids=[grid])
        return load(path)  # noqa: F405 (from _palp)
