"""Authoring the main job's results into the output layer (the contract downstream reads).

Per receiving prim (scene, and avatars/objects that receive shadows):
  ``primvars:usdgs:transmittance``  float[]  one per particle, vertex interpolation
  ``radiance:sphericalHarmonicsCoefficients``  float3[] shadow-attenuated (and relit) SH
Per relit prim (avatars, objects):
  ``primvars:usdgs:lightScale``  color3f[]  per particle, the s_c(n) of eq. 10
Per probe: ``/UsdGs/Probes/<prim name>`` (Xform, translate time-sampled) with
  ``usdgs:probe:shCoefficients`` float3[] (3DGS basis) and ``usdgs:probe:texture`` asset.

Everything is time-sampled at the processed frames where it is affected. A value that does
not change from one processed frame to the next is not authored again. USD interpolates
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
PROBES_ROOT = "/UsdGs/Probes"
PROBE_SH = "usdgs:probe:shCoefficients"
PROBE_TEXTURE = "usdgs:probe:texture"


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

    def __init__(self, stage, frames):
        """``frames``: the processed frames in order (time codes); results must be passed in
        that order."""
        self.stage = stage
        frames = [float(f) for f in frames]
        self.first_frame = frames[0]
        self._previous = dict(zip(frames[1:], frames[:-1], strict=True))
        self._tracks: dict[tuple[str, str], _Track] = {}
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

    def _put(self, prim_path, name, type_name, vt_cls, value, unaffected, frame, primvar, element_size=1):
        """Author ``value`` at ``frame`` if it changed; ``unaffected`` is the value that holds
        where nothing happened (None: the prim is always authored)."""
        key = (prim_path, name)
        track = self._tracks.setdefault(key, _Track())
        value = np.ascontiguousarray(value)
        track.clean = unaffected is not None and np.array_equal(value, unaffected)
        if track.last is not None and np.array_equal(track.last, value):
            return False
        if not track.started and unaffected is not None and np.array_equal(value, unaffected):
            return False  # still unaffected: nothing to author yet
        from pxr import Sdf

        attr = self._attr(prim_path, name, type_name, primvar, element_size)
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
        """True if the prim's transmittance, as last authored (or never), is all ones."""
        track = self._tracks.get((prim_path, TRANSMITTANCE))
        return track is None or track.clean

    def receiver(self, prim_path: str, frame: float, transmittance: np.ndarray, sh_out: np.ndarray,
                 sh_in: np.ndarray) -> bool:
        """Transmittance (N,) and attenuated SH (N, K, 3) of a receiving prim at ``frame``.
        ``sh_in`` is the unshadowed SH (what holds before the prim is first affected)."""
        from pxr import Sdf, Vt

        n = transmittance.shape[0]
        ones = np.ones(n, np.float32)
        changed = self._put(prim_path, TRANSMITTANCE, Sdf.ValueTypeNames.FloatArray, Vt.FloatArray,
                            transmittance.astype(np.float32), ones, frame, True)
        k = sh_out.shape[1]
        changed |= self._put(prim_path, SH_COEFFS, Sdf.ValueTypeNames.Float3Array, Vt.Vec3fArray,
                             sh_out.astype(np.float32).reshape(n * k, 3), sh_in.astype(np.float32).reshape(n * k, 3),
                             frame, False)
        return changed

    def light_scale(self, prim_path: str, frame: float, scale: np.ndarray) -> None:
        from pxr import Sdf, Vt

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
