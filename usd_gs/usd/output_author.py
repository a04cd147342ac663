"""Authoring the main job's results into the output layer (the contract downstream reads).

Per receiving prim (scene, and avatars/objects that receive shadows) and per relit prim:
  the shadow-attenuated (and relit) SH, in the prim's own frame like the input attribute:
  ``radiance:sphericalHarmonicsCoefficientsh`` half3[] with the float attribute
  ``radiance:sphericalHarmonicsCoefficients`` blocked in the output layer (``precision='half'``,
  so readers following the float/half rule of shared/DESIGN.md read the half one), or the float
  attribute itself (``precision='float'``); ``interpolation`` vertex, ``elementSize`` (d+1)^2.
Diagnostic AOVs, only when asked for (``aovs``):
  ``primvars:usdgs:transmittance``  float[]  one per particle, vertex interpolation
  ``primvars:usdgs:lightScale``  color3f[]  per particle (relit prims), the s_c(n) of eq. 10
Per probe: ``/UsdGs/Probes/<prim name>`` (Xform, translate time-sampled) with
  ``usdgs:probe:shCoefficients`` float3[] (3DGS basis) and ``usdgs:probe:texture`` asset.

Everything is time-sampled at the processed frames where it is affected. A value that does
not change from one processed frame to the next, compared in the precision it is written in,
is not authored again. An SH whose display colour, in every direction, is within
``sh_tolerance`` of the unaffected (input) SH (:func:`sh_display_change`, an upper bound over
all view directions) is written as the unaffected SH: a barely shadowed prim gets no sample.
Both rules depend on each frame's own values only, so a farm chunk authors the same values at
its frames as the whole-shot run. USD interpolates
float arrays *linearly* between two time samples, so when a value changes after being held
over skipped frames, the held value is authored once more at the previous processed frame:
every processed frame then reads back exactly the value computed for it (before the first
sample and after the last one USD holds the end values). A prim is touched only once it is
affected; its first sample is then preceded by the unaffected value at the previous
processed frame. Bulk values go through ``Vt.*Array.FromNumpy`` inside ``Sdf.ChangeBlock``.
"""

from __future__ import annotations

import numpy as np

TRANSMITTANCE = "primvars:usdgs:transmittance"
LIGHT_SCALE = "primvars:usdgs:lightScale"
SH_COEFFS = "radiance:sphericalHarmonicsCoefficients"
SH_COEFFS_HALF = SH_COEFFS + "h"
#: the diagnostic primvars ``aovs`` may name
AOVS = {"transmittance": TRANSMITTANCE, "lightScale": LIGHT_SCALE}
PRECISIONS = ("half", "float")
#: default SH change threshold in display colour (0..1): half of one 8-bit step
SH_TOLERANCE = 1.0 / 512.0
PROBES_ROOT = "/UsdGs/Probes"
PROBE_SH = "usdgs:probe:shCoefficients"
PROBE_TEXTURE = "usdgs:probe:texture"


def _row_display_changes(a: np.ndarray, b: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """(N,) float32 per particle: the bound of :func:`sh_display_change` over its channels
    (``numba_kernels.sh_output.row_display_changes``; ``rows``: only those rows, 0 for the others)."""
    from numba_kernels.sh_output import row_display_changes

    return row_display_changes(a, b, rows, threads=False)


def sh_display_change(a: np.ndarray, b: np.ndarray) -> float:
    """Upper bound of the largest display-colour difference, over particles, channels and view
    directions, between two SH sets ``a``, ``b`` (N, K, 3) in the 3DGS basis (colour =
    0.5 + sum_k c_k Y_k(d)): ``max sum_k |a_k - b_k| max_d |Y_k(d)|`` with
    ``max_d |Y_lm(d)| <= sqrt((2l + 1) / (4 pi))``."""
    return float(np.max(_row_display_changes(a, b), initial=0.0))


#: elements compared at a time by :func:`same_values` and :func:`sh_display_within` (a change is
#: usually found in the first block)
_SAME_BLOCK = 1 << 18


def sh_display_within(a: np.ndarray, b: np.ndarray, tolerance: float) -> bool:
    """``sh_display_change(a, b) < tolerance``, block by block of rows: SH that changed (the usual
    case for a moving or relit prim) are told apart in their first block that moved."""
    step = max(1, _SAME_BLOCK // max(1, a[0].size if len(a) else 1))
    return all(sh_display_change(a[i:i + step], b[i:i + step]) < tolerance for i in range(0, len(a), step))


def sh_display_changes(a: np.ndarray, b: np.ndarray, offsets: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """(P,) float64: :func:`sh_display_change` of each prim's rows ``offsets[i]:offsets[i + 1]`` of
    ``a``, ``b`` (M, K, 3), in one pass (0 for a prim without rows). ``rows`` (M,) bool: the rows
    that may differ (the others are taken as equal: no work)."""
    offsets = np.asarray(offsets, np.int64)
    rows = _row_display_changes(a, b, rows)
    counts = np.diff(offsets)
    out = np.zeros(len(counts), np.float64)
    full = counts > 0
    if full.any():
        out[full] = np.maximum.reduceat(rows, offsets[:-1][full])
    return out


def same_values(a: np.ndarray, b: np.ndarray) -> bool:
    """``np.array_equal(a, b)``, block by block: an array that changed (the usual case for a moving
    prim's SH) is told apart in its first differing block, not after a pass over the whole array."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return False
    fa, fb = a.reshape(-1), b.reshape(-1)
    return all(np.array_equal(fa[i:i + _SAME_BLOCK], fb[i:i + _SAME_BLOCK]) for i in range(0, fa.size, _SAME_BLOCK))


_HALF_MAX = float(np.finfo(np.float16).max)


def within_half(value: np.ndarray) -> bool:
    """True when every element of the (non-empty) ``value`` is within +/- the half maximum
    (False for a NaN, whose check the caller then makes element by element)."""
    return bool(value.max() <= _HALF_MAX and value.min() >= -_HALF_MAX)


def _segment_all(flags: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(P,) bool: ``flags[starts[i]:starts[i] + counts[i]].all()`` for each segment (True when empty);
    the segments are consecutive and cover ``flags``."""
    out = np.ones(len(starts), bool)
    full = counts > 0
    if full.any():
        out[full] = np.logical_and.reduceat(flags, starts[full])
    return out


def segments_equal(a: np.ndarray, b: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(P,) bool: ``(a_flat[s:s + n] == b_flat[s:s + n]).all()`` for each ``starts``, ``lengths``
    (consecutive segments covering the arrays; True when empty): float16 arrays in one pass in the
    calling thread that stops at each segment's first difference
    (``numba_kernels.sh_output.half_segments_equal``), others through numpy."""
    if a.dtype == np.float16 and b.dtype == np.float16 and a.shape == b.shape:
        from numba_kernels.sh_output import half_segments_equal

        return half_segments_equal(a, b, starts, np.asarray(starts) + np.asarray(lengths), threads=False)
    return _segment_all((a == b).reshape(-1), starts, lengths)


def _changed_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """(M,) bool: the rows of ``a`` whose bits differ from ``b``'s (both (M, K, 3)); None unless
    both are float32 and ``b`` is finite (a row equal to a NaN row still has a NaN difference)."""
    if a.dtype != np.float32 or b.dtype != np.float32 or a.shape != b.shape or not np.isfinite(b).all():
        return None
    m = a.shape[0]
    if not a.size:
        return np.zeros(m, bool)
    ua = np.ascontiguousarray(a).view(np.uint32).reshape(m, -1)
    ub = np.ascontiguousarray(b).view(np.uint32).reshape(m, -1)
    return (ua != ub).any(axis=1)


def half_of(value: np.ndarray) -> np.ndarray:
    """``value.astype(np.float16)`` (float32 through ``numba_kernels.sh_output.half_bits``: the same
    bits, one pass in the calling thread)."""
    if value.dtype != np.float32:
        return value.astype(np.float16)
    from numba_kernels.sh_output import half_bits

    return half_bits(value, threads=False)


def segment_rows(offsets: np.ndarray, segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, sub)``: the rows of the segments ``segments`` (increasing indices; segment ``i`` is
    rows ``offsets[i]:offsets[i + 1]``) in increasing order, and where each segment starts among
    them (``sub`` (len(segments) + 1,) from 0)."""
    counts = offsets[segments + 1] - offsets[segments]
    sub = np.concatenate([[0], np.cumsum(counts)])
    return np.repeat(offsets[segments] - sub[:-1], counts) + np.arange(sub[-1]), sub


class SegmentHalves:
    """The float16 values (:func:`half_of`) of a float32 block that does not change, e.g. a shot's
    static SH (M, K, 3), whose rows form consecutive segments (``offsets`` (P + 1,) from 0 to M: a
    prim each), converted one segment at a time when it is first asked for: a frame authors only
    the few prims it shadows, so a large static scene costs what its shadowed prims hold. The
    block must stay unchanged while this object is used."""

    def __init__(self, block: np.ndarray, offsets: np.ndarray):
        self.block = block
        self.offsets = np.asarray(offsets, np.int64)
        self._values = np.empty(block.shape, np.float16)  # (pages touched where converted only)
        self._done = np.zeros(len(self.offsets) - 1, bool)
        self._usable = True

    def rows(self, segments: np.ndarray, rows: np.ndarray | None) -> np.ndarray | None:
        """float16 of the rows ``rows`` (increasing; None: every row, when ``segments`` holds every
        segment) of the segments ``segments`` (increasing indices). None when a value lies beyond
        the half range or is NaN (the caller converts, and names the element)."""
        if not self._usable:
            return None
        new = segments[~self._done[segments]]
        if new.size:
            fresh, _ = segment_rows(self.offsets, new)
            part = self.block[fresh]
            if part.size and not within_half(part):
                self._usable = False
                return None
            self._values[fresh] = half_of(part)
            self._done[new] = True
        return self._values if rows is None else self._values[rows]


def _to_half(value: np.ndarray, prim_path: str) -> np.ndarray:
    """``value`` as float16; ``UserError`` naming the prim and element where it overflows."""
    if not value.size or within_half(value):  # fast path: two reductions, no temporaries
        return half_of(value)
    big = np.flatnonzero(np.abs(value).max(axis=-1) > _HALF_MAX)
    if len(big):
        from usd_gs.errors import UserError

        raise UserError(f"{prim_path}.{SH_COEFFS_HALF}[{int(big[0])}]: SH coefficient beyond the half-precision "
                        f"range (|x| > {_HALF_MAX:g}); run with --precision float")
    return value.astype(np.float16)


class _Track:
    """Last authored value of one attribute, for change detection."""

    __slots__ = ("last", "last_frame", "started", "clean")

    def __init__(self):
        self.last = None
        self.last_frame = None  # frame of the last authored sample
        self.started = False
        self.clean = True  # the last value (or the input's, before anything) is the unaffected one


class OutputAuthor:
    """Writes per-frame results as time samples into ``stage`` (the output layer's stage)."""

    def __init__(self, stage, frames, aovs=tuple(AOVS), precision: str = "float", sh_tolerance: float = 0.0):
        """``frames``: the processed frames in order (time codes); results must be passed in
        that order. ``aovs``: names of :data:`AOVS` to write; ``precision``: of the SH written
        ('half' | 'float'); ``sh_tolerance``: display-colour change below which an SH is held
        (0: any change is written). The defaults write everything exactly; the main job passes
        its options (``usd_gs.pipeline.options.ProcessOptions``)."""
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        self.stage = stage
        self.aovs = frozenset(aovs)
        self.precision = precision
        self.sh_tolerance = float(sh_tolerance)
        frames = [float(f) for f in frames]
        self.first_frame = frames[0]
        self._previous = dict(zip(frames[1:], frames[:-1], strict=True))
        self._tracks: dict[tuple[str, str], _Track] = {}
        self._sh_attrs: dict[str, tuple] = {}  # prim path -> (K, the SH attribute _sh_attr made)
        self._halves: dict[str, tuple] = {}  # prim path -> (float32 bits, half) of receiver()'s unaffected SH
        self.samples_written = 0

    # ------------------------------------------------------------------ attributes
    def _attr(self, prim_path: str, name: str, type_name, primvar: bool, element_size: int = 1):
        from pxr import Sdf, UsdGeom

        prim = self.stage.GetPrimAtPath(prim_path) or self.stage.OverridePrim(prim_path)
        if primvar:
            pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(name.removeprefix("primvars:"), type_name,
                                                         UsdGeom.Tokens.vertex, element_size)
            return pv.GetAttr()
        attr = prim.GetAttribute(name)
        return attr if attr else prim.CreateAttribute(name, type_name, False, Sdf.VariabilityVarying)

    def _put(self, prim_path, name, type_name, vt_cls, value, unaffected, frame, primvar, element_size=1,
             make_attr=None):
        """Author ``value`` at ``frame`` if it changed; ``unaffected`` is the value that holds
        where nothing happened (None: the prim is always authored). ``make_attr()`` returns the
        attribute to author (default: created from the name and type)."""
        key = (prim_path, name)
        track = self._tracks.setdefault(key, _Track())
        value = np.ascontiguousarray(value)
        reference = track.last if track.started else unaffected
        if reference is not None and same_values(value, reference):
            return False  # unchanged, or still unaffected: nothing to author
        track.clean = unaffected is not None and same_values(value, unaffected)
        from pxr import Sdf

        attr = make_attr() if make_attr else self._attr(prim_path, name, type_name, primvar, element_size)
        prev = self._previous.get(float(frame))
        held = track.last if track.started else (None if unaffected is None else np.ascontiguousarray(unaffected))
        with Sdf.ChangeBlock():
            if held is not None and prev is not None and track.last_frame != prev:
                attr.Set(vt_cls.FromNumpy(held), prev)  # end of the hold: no interpolation into it
                self.samples_written += 1
            attr.Set(vt_cls.FromNumpy(value), frame)
        track.started = True
        track.last = value.copy()
        track.last_frame = float(frame)
        self.samples_written += 1
        return True

    def is_clean(self, prim_path: str) -> bool:
        """True if the prim's SH, as last authored (or never), is its unaffected (input) SH."""
        track = self._tracks.get((prim_path, SH_COEFFS))
        return track is None or track.clean

    def _sh_attr(self, prim_path: str, k: int):
        """The SH attribute this author writes on ``prim_path`` (created on first use, with
        ``interpolation`` vertex and ``elementSize`` k; in half precision the float attribute is
        blocked in the output layer)."""
        from pxr import Sdf, UsdGeom

        got = self._sh_attrs.get(prim_path)
        if got is not None and got[0] == k and got[1].IsValid():
            return got[1]
        prim = self.stage.GetPrimAtPath(prim_path) or self.stage.OverridePrim(prim_path)
        half = self.precision == "half"
        name = SH_COEFFS_HALF if half else SH_COEFFS
        attr = prim.GetAttribute(name)
        if not attr or not attr.HasAuthoredMetadata("elementSize") or attr.GetMetadata("elementSize") != k:
            attr = prim.CreateAttribute(name, Sdf.ValueTypeNames.Half3Array if half else Sdf.ValueTypeNames.Float3Array,
                                        False, Sdf.VariabilityVarying)
            attr.SetMetadata("interpolation", UsdGeom.Tokens.vertex)
            attr.SetMetadata("elementSize", k)
        if half:
            flt = prim.GetAttribute(SH_COEFFS) or prim.CreateAttribute(SH_COEFFS, Sdf.ValueTypeNames.Float3Array,
                                                                        False, Sdf.VariabilityVarying)
            if not flt.GetResolveInfo().ValueIsBlocked():
                flt.Block()
        self._sh_attrs[prim_path] = (k, attr)
        return attr

    def receiver(self, prim_path: str, frame: float, transmittance: np.ndarray, sh_out: np.ndarray,
                 sh_in: np.ndarray) -> bool:
        """Transmittance (N,) and attenuated SH (N, K, 3) of a receiving prim at ``frame``.
        ``sh_in`` is the unshadowed SH (what holds before the prim is first affected). Returns
        whether anything was authored."""
        from pxr import Sdf, Vt

        n, k = sh_out.shape[0], sh_out.shape[1]
        changed = False
        if "transmittance" in self.aovs:
            changed = self._put(prim_path, TRANSMITTANCE, Sdf.ValueTypeNames.FloatArray, Vt.FloatArray,
                                transmittance.astype(np.float32), np.ones(n, np.float32), frame, True)
        if self.sh_tolerance > 0.0 and sh_display_within(sh_out, sh_in, self.sh_tolerance):
            sh_out = sh_in  # within the tolerance of the unaffected SH: written as unaffected
        half = self.precision == "half"
        shape = (n * k, 3)
        if half:
            value = _to_half(sh_out.reshape(shape), prim_path)
            unaffected = self._half_unaffected(prim_path, sh_in, shape)
        else:
            value, unaffected = sh_out.astype(np.float32).reshape(shape), sh_in.astype(np.float32).reshape(shape)
        changed |= self._put(prim_path, SH_COEFFS, None, Vt.Vec3hArray if half else Vt.Vec3fArray, value,
                             unaffected, frame, False, make_attr=lambda: self._sh_attr(prim_path, k))
        return changed

    def _half_unaffected(self, prim_path: str, sh_in: np.ndarray, shape) -> np.ndarray:
        """``_to_half(sh_in.reshape(shape))``, kept per prim: the unaffected SH of a moving prim is
        mostly the same from frame to frame, and comparing its float32 bits costs less than the
        conversion."""
        if sh_in.dtype != np.float32:
            return _to_half(sh_in.reshape(shape), prim_path)
        bits = np.ascontiguousarray(sh_in).reshape(shape).view(np.uint32)
        got = self._halves.get(prim_path)
        if got is not None and same_values(got[0], bits):
            return got[1]
        half = _to_half(sh_in.reshape(shape), prim_path)
        self._halves[prim_path] = (bits.copy(), half)
        return half

    def receivers(self, frame: float, paths, offsets, transmittance: np.ndarray, sh_out: np.ndarray,
                  sh_in: np.ndarray, sh_in_half: np.ndarray | None = None) -> np.ndarray:
        """:meth:`receiver` for many prims at once, with the same results and time samples: prim
        ``paths[i]`` takes rows ``offsets[i]:offsets[i + 1]`` ((P + 1,) ints from 0) of
        ``transmittance`` (M,) and of ``sh_out``, ``sh_in`` (M, K, 3), one K for all. Returns (P,)
        bool, whether anything was authored on each prim. The tolerance rule, the half conversion
        and the comparison with the held values run once over all rows; the writes go into one
        ``Sdf.ChangeBlock``. A value beyond the half range (or NaN) takes :meth:`receiver`, prim by
        prim, so that the error names the same prim and element. ``sh_in_half``: ``sh_in`` as
        float16 where the caller keeps it (a shot's static SH does not change), else converted here."""
        from pxr import Sdf, Vt

        paths = list(paths)
        offsets = np.asarray(offsets, np.int64)
        if len(offsets) != len(paths) + 1 or (len(paths) and (offsets[0] != 0 or offsets[-1] != sh_out.shape[0])):
            raise ValueError(f"offsets must be ({len(paths) + 1},) from 0 to {sh_out.shape[0]}, got {offsets}")
        if not paths:
            return np.zeros(0, bool)
        m, k = sh_out.shape[0], sh_out.shape[1]
        counts = np.diff(offsets)
        # the rows whose SH differ from the unaffected one, bit for bit (float32 and finite: the
        # other rows change nothing, their display change is 0 and their half values are the same)
        moved = _changed_rows(sh_out, sh_in)
        half = self.precision == "half"
        held = None
        if self.sh_tolerance > 0.0:
            hold = sh_display_changes(sh_out, sh_in, offsets, rows=moved) < self.sh_tolerance
            if hold.any():  # within the tolerance of the unaffected SH: written as unaffected
                held = np.repeat(hold, counts)
                if moved is not None:
                    moved = moved & ~held
        fast_half = half and (not m or (within_half(sh_out) and within_half(sh_in)))
        if held is not None and not (fast_half and moved is not None):
            sh_out = np.where(held[:, None, None], sh_in, sh_out)
        shape = (m * k, 3)
        if half:
            if not fast_half:
                return np.array([self.receiver(p, frame, transmittance[a:b], sh_out[a:b], sh_in[a:b])
                                 for p, a, b in zip(paths, offsets[:-1], offsets[1:], strict=True)], bool)
            unaffected = half_of(sh_in) if sh_in_half is None else np.asarray(sh_in_half).reshape(sh_in.shape)
            if moved is None:
                value = half_of(sh_out).reshape(shape)
            else:  # converted where the SH moved (and is not held) only
                from numba_kernels.sh_output import half_bits_where

                value = half_bits_where(moved, sh_out, unaffected, threads=False).reshape(shape)
            unaffected = unaffected.reshape(shape)
        else:
            value, unaffected = sh_out.astype(np.float32).reshape(shape), sh_in.astype(np.float32).reshape(shape)
        changed = np.zeros(len(paths), bool)
        if "transmittance" in self.aovs:
            changed |= self._put_many(paths, offsets, TRANSMITTANCE, Vt.FloatArray,
                                      np.asarray(transmittance).astype(np.float32), np.ones(m, np.float32), frame,
                                      lambda p: self._attr(p, TRANSMITTANCE, Sdf.ValueTypeNames.FloatArray, True))
        changed |= self._put_many(paths, offsets * k, SH_COEFFS, Vt.Vec3hArray if half else Vt.Vec3fArray, value,
                                  unaffected, frame, lambda p: self._sh_attr(p, k), owned=True)  # (a new array)
        return changed

    def _put_many(self, paths, rows, name, vt_cls, value, unaffected, frame, make_attr,
                  owned: bool = False) -> np.ndarray:
        """:meth:`_put` of attribute ``name`` on every prim of ``paths`` (rows ``rows[i]:rows[i + 1]``
        of ``value``, ``unaffected``), with one comparison over all rows; ``make_attr(path)`` returns
        the attribute to author. ``owned``: ``value`` is a fresh array no one else holds or changes.
        Returns (P,) bool, authored."""
        from pxr import Sdf

        counts = np.diff(rows)
        tail = value.shape[1:]
        width = int(np.prod(tail, dtype=np.int64))
        tracks = [self._tracks.setdefault((p, name), _Track()) for p in paths]
        refs, same_shape = [], np.ones(len(paths), bool)
        for i, track in enumerate(tracks):
            ref = track.last if track.started else None
            if ref is not None and ref.shape != (int(counts[i]), *tail):
                same_shape[i] = False  # np.array_equal: arrays of other shapes differ
                ref = None
            refs.append(unaffected[rows[i]:rows[i + 1]] if ref is None else ref)
        reference = np.concatenate(refs) if len(refs) > 1 else refs[0]
        starts = rows[:-1] * width
        equal = segments_equal(value, reference, starts, counts * width) & same_shape
        todo = np.flatnonzero(~equal)
        if not todo.size:
            return ~equal
        clean = segments_equal(value, unaffected, starts, counts * width)
        attrs = [make_attr(paths[i]) for i in todo]  # created before the change block
        # the tracks keep views of a fresh ``value`` when every prim takes its rows (no other track
        # then keeps an older array alive), else copies
        keep_views = owned and todo.size == len(paths)
        prev = self._previous.get(float(frame))
        with Sdf.ChangeBlock():
            for i, attr in zip(todo, attrs, strict=True):
                track = tracks[i]
                a, b = rows[i], rows[i + 1]
                v = np.ascontiguousarray(value[a:b])
                held = track.last if track.started else np.ascontiguousarray(unaffected[a:b])
                if prev is not None and track.last_frame != prev:
                    attr.Set(vt_cls.FromNumpy(held), prev)  # end of the hold: no interpolation into it
                    self.samples_written += 1
                attr.Set(vt_cls.FromNumpy(v), frame)
                track.clean = bool(clean[i])
                track.started = True
                track.last = v if keep_views else v.copy()
                track.last_frame = float(frame)
                self.samples_written += 1
        return ~equal

    def light_scale(self, prim_path: str, frame: float, scale: np.ndarray) -> None:
        """The relighting factor s_c(n) (N, 3) of a relit prim (an AOV: written only when asked for)."""
        from pxr import Sdf, Vt

        if "lightScale" not in self.aovs:
            return
        self._put(prim_path, LIGHT_SCALE, Sdf.ValueTypeNames.Color3fArray, Vt.Vec3fArray,
                  scale.astype(np.float32), None, frame, True)

    # ------------------------------------------------------------------ probes
    def probe(self, name: str, frame: float, position: np.ndarray, sh_3dgs: np.ndarray, texture: str | None):
        """Probe prim ``/UsdGs/Probes/<name>``: position, SH (K, 3) 3DGS basis, texture path."""
        from pxr import Gf, Sdf, UsdGeom, Vt

        path = f"{PROBES_ROOT}/{name}"
        prim = self.stage.GetPrimAtPath(path)
        if not prim:
            UsdGeom.Scope.Define(self.stage, "/UsdGs")
            UsdGeom.Scope.Define(self.stage, PROBES_ROOT)
            xf = UsdGeom.Xform.Define(self.stage, path)
            xf.AddTranslateOp()
            prim = xf.GetPrim()
            prim.CreateAttribute(PROBE_SH, Sdf.ValueTypeNames.Float3Array, False)
            prim.CreateAttribute(PROBE_TEXTURE, Sdf.ValueTypeNames.Asset, False)
        op = UsdGeom.Xformable(prim).GetOrderedXformOps()[0]
        op.Set(Gf.Vec3d(*map(float, position)), frame)
        prim.GetAttribute(PROBE_SH).Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(sh_3dgs, np.float32)), frame)
        if texture:
            prim.GetAttribute(PROBE_TEXTURE).Set(Sdf.AssetPath(texture), frame)
        self.samples_written += 3
