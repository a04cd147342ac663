"""Bulk helpers of the Gaussian write path: numpy -> ``Vt`` arrays at copy speed (or no copy at
all for arrays a reader decoded into ``Vt`` storage), and the 3-sigma extent of a
:class:`~usd_gs.gaussians.GaussianSet` without (N,)-sized float64 passes.

They return what the plain calls return (``Vt.*Array.FromNumpy(arr)``,
``GaussianSet.extent(n_sigma)``), bit for bit; they only take less time and memory. No numba here.
"""

from __future__ import annotations

import ctypes

import numpy as np

from usd_gs.usd.vt_alloc import new_vt_array, vt_class_name

#: below this many bytes ``FromNumpy`` is used as it is (nothing to gain)
_SMALL = 1 << 16


#: attribute of the ctypes buffer behind a :func:`vt_backed_empty` array that holds its Vt array
_OWNER = "_usdgs_vt_array"

def vt_backed_empty(shape: tuple, dtype=np.float32, vt=None) -> np.ndarray:
    """A writable numpy array of ``shape`` (float32, C order) whose memory is the storage of a
    fresh ``Vt.FloatArray`` (``shape`` (N,)) or ``Vt.Vec3fArray`` (``(N, ..., 3)``, N * ... vectors);
    other shapes and dtypes get a plain ``np.empty``. Values start at 0.

    :func:`vt_from_numpy` of such an array (or of a C-contiguous view of all of it) returns that
    Vt array itself instead of a copy: a reader decodes straight into what USD writes. The
    contract: the numpy array is not modified after it was handed to USD (the Vt array would
    change with it). ``vt``: such a Vt array already allocated (``usd_gs.usd.vt_alloc.new_vt_array
    (shape)``), used instead of a fresh one.
    """
    shape = tuple(int(d) for d in shape)
    if np.dtype(dtype) != np.float32 or vt_class_name(shape) is None:
        return np.zeros(shape, dtype)
    out = vt if vt is not None and type(vt).__name__ == vt_class_name(shape) else new_vt_array(shape)
    view = np.asarray(out)
    if view.dtype != np.float32 or view.size != int(np.prod(shape)) or not view.flags.c_contiguous:
        return np.zeros(shape, dtype)
    if view.nbytes == 0:
        return np.zeros(shape, dtype)
    raw = (ctypes.c_char * view.nbytes).from_address(view.__array_interface__["data"][0])
    setattr(raw, _OWNER, out)  # keeps the Vt array alive as long as any numpy view of it
    return np.frombuffer(raw, np.float32).reshape(shape)


def _vt_owner(vt_cls, arr: np.ndarray):
    """The Vt array of class ``vt_cls`` whose whole storage ``arr`` is (:func:`vt_backed_empty`), or None."""
    base = arr
    while base is not None and not hasattr(base, _OWNER):
        base = getattr(base, "base", None)
    if base is None:
        return None
    owner = getattr(base, _OWNER)
    if type(owner) is not vt_cls or not arr.flags.c_contiguous:
        return None
    view = np.asarray(owner)
    same = (view.dtype == arr.dtype and view.shape == arr.shape
            and view.__array_interface__["data"][0] == arr.__array_interface__["data"][0])
    return owner if same else None


def vt_from_numpy(vt_cls, arr: np.ndarray):
    """``vt_cls.FromNumpy(arr)`` for a C-contiguous ``arr`` whose dtype is the element scalar of
    ``vt_cls`` (float32 (N, 3) for ``Vt.Vec3fArray``, (N, 4) x, y, z, w for ``Vt.QuatfArray``...).

    ``FromNumpy`` converts element by element (about 10x slower than a copy); this allocates a
    fresh ``vt_cls(N)``, which no other array shares, and copies the bytes into its storage
    through a writable view of its buffer. Falls back to ``FromNumpy`` when the shapes, dtypes or
    buffer layout do not line up, so the result is the same in every case. For an array of
    :func:`vt_backed_empty` storage it is the Vt array that storage belongs to (no copy).
    """
    arr = np.ascontiguousarray(arr)
    if arr.nbytes < _SMALL or arr.ndim == 0:
        return vt_cls.FromNumpy(arr)
    owner = _vt_owner(vt_cls, arr)
    if owner is not None:
        return owner
    fresh = vt_writable(vt_cls, len(arr), arr.dtype)
    if fresh is None or fresh[1].shape != arr.shape:
        return vt_cls.FromNumpy(arr)
    np.copyto(fresh[1], arr)
    return fresh[0]


def vt_writable(vt_cls, count: int, dtype) -> tuple | None:
    """``(vt_cls(count), a writable numpy view of its storage)``: the view's element scalar is
    ``dtype`` (a ``Vt.QuatfArray`` is (count, 4) float32 x, y, z, w), its values 0. What is
    written into the view is the Vt array's value; the contract of :func:`vt_backed_empty`
    applies (not modified once handed to USD). None when the buffer layout does not line up
    or ``count`` is 0 (use ``FromNumpy``)."""
    out = vt_cls(int(count))
    view = np.asarray(out)
    if view.dtype != np.dtype(dtype) or not view.flags.c_contiguous or view.nbytes == 0:
        return None
    raw = (ctypes.c_char * view.nbytes).from_address(view.__array_interface__["data"][0])
    setattr(raw, _OWNER, out)  # keeps the Vt array alive as long as the view
    return out, np.frombuffer(raw, view.dtype).reshape(view.shape)


class VtBackedPool:
    """:func:`vt_backed_empty` arrays allocated by :meth:`fill` in the calling thread, handed out
    by calling the pool with a shape (the next array of that shape; ``np.zeros`` once they are
    used up) without calling USD. A call waits until :meth:`fill` has run (``shapes`` given
    here: at once). For a reader running in another thread while this one imports pxr modules
    (which must not happen in two threads at once): the reader can start before the arrays exist.
    """

    def __init__(self, shapes=None):
        import threading

        self._free: dict[tuple, list[np.ndarray]] = {}
        self._ready = threading.Event()
        if shapes is not None:
            self.fill(shapes)

    def fill(self, shapes, made=()) -> None:
        """Allocate one array per shape of ``shapes``; then the calls stop waiting. ``made``:
        ``(shape, Vt array)`` pairs allocated earlier (``usd_gs.usd.vt_alloc.new_vt_array``),
        used for shapes they match instead of new arrays."""
        spare = [(tuple(int(d) for d in s), vt) for s, vt in made]
        try:
            for shape in shapes:
                shape = tuple(int(d) for d in shape)
                vt = next((pair for pair in spare if pair[0] == shape), None)
                if vt is not None:
                    spare.remove(vt)
                self._free.setdefault(shape, []).append(vt_backed_empty(shape, vt=None if vt is None else vt[1]))
        finally:
            self._ready.set()  # on an error (MemoryError) the reader gets numpy arrays instead

    def __call__(self, shape) -> np.ndarray:
        self._ready.wait()
        free = self._free.get(tuple(int(d) for d in shape))
        return free.pop(0) if free else np.zeros(shape, np.float32)
