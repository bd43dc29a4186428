"""Fill an embreex scene's triangle buffers with numpy and build its BVH without holding the GIL.

embreex's ``TriangleMesh`` copies a (m, 3, 3) triangle array into Embree one number at a time
through Python indexing (9 m ``ndarray.__getitem__`` calls): ~0.5 s for 0.36M triangles, the
largest single cost of a cached start-up, and it holds the GIL the whole time. Its
``EmbreeScene.run`` then builds the BVH (``rtcCommitScene``) on the first query, also with the
GIL held.

:func:`add_triangles` makes the same Embree geometry through Embree's C API (``ctypes`` on the
very ``libembree4`` that embreex has loaded): the same vertex buffer (float3 with a 16-byte
stride, vertex ``3 i + k`` = corner k of triangle i, rounded to float32 as embreex's C cast
rounds) and index buffer (``3 i, 3 i + 1, 3 i + 2``), attached to the embreex scene, so every
query gives the same answer bit for bit (tests/straylight/test_embree_build.py); numpy fills the
buffers in ~10 ms. :func:`commit` builds the BVH through ``ctypes``, which releases the GIL, so a
thread can build it while the process loads its compiled kernels.

The embreex scene's Embree handle is a private Cython field; it is read from the object's memory
only after three checks of the layout (the scene's device pointer is the device object we gave
it; the public ``is_committed`` field is where the layout puts it; Embree's own
``rtcGetSceneDevice`` of the handle is that device's handle). If anything does not match (another
embreex, another platform, no libembree4 found), :func:`add_triangles` returns False and the
caller uses ``TriangleMesh``.
"""
from __future__ import annotations

import ctypes
import threading

import numpy as np

_GEOMETRY_TYPE_TRIANGLE = 0  # embree4/rtcore_geometry.h
_BUFFER_TYPE_INDEX, _BUFFER_TYPE_VERTEX = 0, 1  # embree4/rtcore_buffer.h
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003  # embree4/rtcore_common.h
_PTR = ctypes.sizeof(ctypes.c_void_p)
_LIB: list = []  # [ctypes library or None], found once
_LOCK = threading.Lock()


def _loaded_embree_path():
    """Path of the libembree4 this process has loaded (Linux /proc/self/maps), or None."""
    try:
        with open("/proc/self/maps") as f:
            for line in f:
                path = line.split()[-1]
                if "/libembree4" in path and ".so" in path:
                    return path
    except OSError:
        pass
    return None


def _lib():
    with _LOCK:
        if not _LIB:
            lib = None
            import embreex.rtcore_scene  # noqa: F401 - loads libembree4 (the copy we must use)

            path = _loaded_embree_path()
            if path is not None:
                try:
                    lib = ctypes.CDLL(path)
                    vp, u, sz = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t
                    for name, res, args in (
                            ("rtcNewGeometry", vp, (vp, ctypes.c_int)),
                            ("rtcSetNewGeometryBuffer", vp, (vp, ctypes.c_int, u, ctypes.c_int, sz, sz)),
                            ("rtcCommitGeometry", None, (vp,)),
                            ("rtcAttachGeometry", u, (vp, vp)),
                            ("rtcReleaseGeometry", None, (vp,)),
                            ("rtcCommitScene", None, (vp,)),
                            ("rtcGetSceneDevice", vp, (vp,)),
                            ("rtcReleaseDevice", None, (vp,)),
                            ("rtcGetDeviceError", ctypes.c_int, (vp,))):
                        fn = getattr(lib, name)
                        fn.restype, fn.argtypes = res, args
                except (OSError, AttributeError):
                    lib = None
            _LIB.append(lib)
        return _LIB[0]


def _word(address: int) -> int:
    return ctypes.c_void_p.from_address(address).value or 0


def _scene_handle(scene, device) -> int | None:
    """The RTCScene of an embreex ``EmbreeScene(device=device)`` after checking the object layout
    (Cython: PyObject header, then the fields in .pxd order: scene_i, is_committed, device)."""
    lib = _lib()
    if lib is None or type(scene).__basicsize__ < 16 + 3 * _PTR:
        return None
    base = id(scene)
    handle, device_obj = _word(base + 16), _word(base + 16 + 2 * _PTR)
    if not handle or device_obj != id(device):
        return None
    was = scene.is_committed
    try:
        for probe in (0x5A5A5, 0):
            scene.is_committed = probe
            if ctypes.c_int.from_address(base + 16 + _PTR).value != probe:
                return None
    finally:
        scene.is_committed = was
    rtc_device = _word(id(device) + 16)
    got = lib.rtcGetSceneDevice(handle)  # Embree 4: returns a new reference
    if got:
        lib.rtcReleaseDevice(got)
    return handle if got and got == rtc_device else None


def add_triangles(scene, device, triangles_mm) -> bool:
    """Attach ``triangles_mm`` ((m, 3, 3) float64, C order) to an uncommitted embreex
    ``EmbreeScene(device=device)`` as one triangle geometry, the same as embreex's
    ``TriangleMesh(scene, triangles_mm)``; False (nothing done) if that cannot be done safely."""
    handle = _scene_handle(scene, device)
    if handle is None or scene.is_committed:
        return False
    lib = _lib()
    tri = np.ascontiguousarray(triangles_mm, dtype=np.float64)
    m = len(tri)
    if m == 0 or 3 * m >= 2**32:
        return False
    rtc_device = _word(id(device) + 16)
    geom = lib.rtcNewGeometry(rtc_device, _GEOMETRY_TYPE_TRIANGLE)
    if not geom:
        return False
    try:
        vptr = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, 16, 3 * m)
        iptr = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, 12, m)
        if not vptr or not iptr:
            return False
        vertices = np.ctypeslib.as_array((ctypes.c_float * (12 * m)).from_address(vptr)).reshape(3 * m, 4)
        vertices[:, :3] = tri.reshape(3 * m, 3)  # float64 -> float32: round to nearest, as a C cast
        vertices[:, 3] = 0.0
        index = np.ctypeslib.as_array((ctypes.c_uint32 * (3 * m)).from_address(iptr))
        index[:] = np.arange(3 * m, dtype=np.uint32)
        lib.rtcCommitGeometry(geom)
        if lib.rtcGetDeviceError(rtc_device) != 0:
            return False  # not attached: the caller builds the mesh the embreex way
        lib.rtcAttachGeometry(handle, geom)
        return True
    finally:
        lib.rtcReleaseGeometry(geom)  # the scene holds its own reference once attached


def commit(scene, device) -> bool:
    """Build the BVH of an embreex scene now, with the GIL released (``rtcCommitScene`` through ctypes);
    False if not possible (the scene then builds it on its first query, as embreex does)."""
    handle = _scene_handle(scene, device)
    if handle is None:
        return False
    if not scene.is_committed:
        _lib().rtcCommitScene(handle)
        scene.is_committed = 1
    return True
