"""Lights of a shot as UsdLux prims: reading the ones a stage has, writing estimated ones.

The pipeline works with :class:`ShotLight` values in world space:

- ``kind='point'``: a point/sphere light at ``position`` (metres, world), for UsdLux
  ``SphereLight`` (``treatAsPoint`` or not), and for ``RectLight`` / ``DiskLight`` /
  ``CylinderLight``, which are approximated by a sphere light at their centre (with a warning).
- ``kind='directional'``: parallel light travelling along the unit ``direction`` (world),
  for ``DistantLight`` (UsdLux lights emit along their local -Z axis).

``intensity`` is UsdLux ``intensity * 2^exposure``; ``color`` linear RGB. Estimated lights
carry the estimator's ``score``; they are written as ``SphereLight`` prims under
``/UsdGs/Lights`` with ``customData`` ``usdgs:score`` and ``usdgs:estimated = true`` so an
artist can edit them in a DCC and re-run with ``--lights stage``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

LIGHTS_ROOT = "/UsdGs/Lights"
SPHERE_LIKE = ("RectLight", "DiskLight", "CylinderLight")


@dataclass
class ShotLight:
    """One light in world space; see the module docstring for units and conventions."""

    name: str
    kind: str  # 'point' | 'directional'
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    intensity: float = 1.0
    radius: float = 0.0
    score: float | None = None
    source: str = "estimated"

    @property
    def luminous_weight(self) -> float:
        """Relative strength used to weight lights against each other: intensity times the
        Rec.709 luminance of the colour."""
        return float(self.intensity * (0.2126 * self.color[0] + 0.7152 * self.color[1] + 0.0722 * self.color[2]))


def read_stage_lights(stage, time) -> tuple[list[ShotLight], list[str]]:
    """All supported UsdLux lights of ``stage`` at ``time`` (world space) and warnings.

    DomeLight, GeometryLight and PortalLight are skipped with a warning (the SH probe
    covers environment light). Inactive and invisible lights are skipped.
    """
    from pxr import UsdGeom, UsdLux

    lights, warnings = [], []
    for prim in stage.Traverse():
        if not prim.HasAPI(UsdLux.LightAPI):
            continue
        type_name = prim.GetTypeName()
        path = str(prim.GetPath())
        img = UsdGeom.Imageable(prim)
        if img and img.ComputeVisibility(time) == UsdGeom.Tokens.invisible:
            continue
        api = UsdLux.LightAPI(prim)
        exposure = float(api.GetExposureAttr().Get(time) or 0.0)
        intensity = float(api.GetIntensityAttr().Get(time) or 0.0) * 2.0**exposure
        color = np.array(api.GetColorAttr().Get(time) or (1.0, 1.0, 1.0), dtype=np.float64)
        m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time))
        position = m[3, :3].copy()
        if type_name == "DistantLight":
            d = -m[2, :3]
            n = np.linalg.norm(d)
            if not n > 0:
                warnings.append(f"{path}: DistantLight has a degenerate transform; skipped")
                continue
            lights.append(ShotLight(path, "directional", position, d / n, color, intensity, source=path))
        elif type_name == "SphereLight":
            sl = UsdLux.SphereLight(prim)
            point = bool(sl.GetTreatAsPointAttr().Get(time))
            radius = 0.0 if point else float(sl.GetRadiusAttr().Get(time) or 0.0)
            lights.append(ShotLight(path, "point", position, color=color, intensity=intensity, radius=radius,
                                    source=path))
        elif type_name in SPHERE_LIKE:
            warnings.append(f"{path}: {type_name} is approximated by a sphere light at its centre")
            lights.append(ShotLight(path, "point", position, color=color, intensity=intensity, source=path))
        else:
            warnings.append(f"{path}: {type_name or 'light'} is not used for shadows (only Sphere, Distant, "
                            f"Rect, Disk and Cylinder lights are)")
    return lights, warnings


def write_estimated_lights(stage, lights: list[ShotLight], radius: float = 0.05, root: str = LIGHTS_ROOT) -> list[str]:
    """Author ``lights`` as ``SphereLight`` prims ``<root>/Light_<i>``; returns their paths.

    Values are static (one set of lights per shot); ``customData`` keeps the estimator's
    score. Positions go into a ``translate`` op in world space, so ``root`` and its parent
    must not carry transforms (they are defined here as plain ``Scope`` prims). A handful of
    prims: plain stage API calls (``Define`` is not allowed inside ``Sdf.ChangeBlock``).
    """
    from pxr import Gf, UsdGeom, UsdLux

    parts = root.strip("/").split("/")
    for i in range(len(parts)):
        UsdGeom.Scope.Define(stage, "/" + "/".join(parts[: i + 1]))
    paths = []
    for i, light in enumerate(lights):
        path = f"{root}/Light_{i}"
        sl = UsdLux.SphereLight.Define(stage, path)
        UsdGeom.Xformable(sl.GetPrim()).AddTranslateOp().Set(Gf.Vec3d(*map(float, light.position)))
        sl.CreateIntensityAttr(float(light.intensity))
        sl.CreateColorAttr(Gf.Vec3f(*map(float, light.color)))
        sl.CreateRadiusAttr(float(light.radius or radius))
        sl.CreateTreatAsPointAttr(False)
        prim = sl.GetPrim()
        prim.SetCustomDataByKey("usdgs:estimated", True)
        if light.score is not None:
            prim.SetCustomDataByKey("usdgs:score", float(light.score))
        paths.append(path)
    return paths
