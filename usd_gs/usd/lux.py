"""Lights of a shot as UsdLux prims: reading the ones a stage has, writing estimated ones.

The pipeline works with :class:`ShotLight` values in world space (metres):

- ``kind='point'``: a light at ``position`` for shadows (one DGSM from that point): UsdLux
  ``SphereLight`` (``shape`` 'sphere', or 'point' with ``treatAsPoint`` or radius 0) and the area
  lights ``RectLight`` / ``DiskLight`` / ``CylinderLight`` (``shape`` 'rect' / 'disk' /
  'cylinder'), which shadow from their centre (with a warning) and light by area samples
  (``usd_gs.relight.direct``).
- ``kind='directional'``: parallel light travelling along the unit ``direction`` (world), for
  ``DistantLight`` (UsdLux lights emit along their local -Z axis); ``angle`` its angular diameter
  in degrees (a finite sun disc; UsdLux fallback 0.53).
- ``kind='dome'``: ``DomeLight`` / ``DomeLight_1`` (only with ``read_stage_lights(...,
  include_domes=True)``): environment light at infinity, the lat-long image ``env`` (linear RGB,
  ``usd_gs.io.envmap`` convention, Y-up) of ``inputs:texture:file`` or None (uniform colour);
  ``axes`` maps the texture's frame to world (the prim's rotation, then ``poleAxis`` 'Z' turns
  the texture's +Y pole to +Z). No shadows from a dome: it enters the relighting only.

``intensity`` is UsdLux ``intensity * 2^exposure``; ``color`` linear Rec.709 RGB, times the
blackbody colour of ``colorTemperature`` when ``enableColorTemperature`` is set
(:func:`blackbody_rgb`). ``axes`` (3, 3): the light's world rotation (columns: local x, y, z,
unit). ``width`` / ``height`` (rect) and ``radius`` (sphere, disk, cylinder) in metres, world
scale applied. ``normalize``: UsdLux ``inputs:normalize``.

Units (the relighting's contract, ``usd_gs.relight.direct``): radiance in the linear units of the
decoded Gaussian colours (a white Lambertian surface under a uniform environment of radiance 1 has
colour 1). :meth:`ShotLight.radiant_intensity` is the irradiance a light gives at 1 m at normal
incidence (point-like lights); :meth:`ShotLight.radiance` the emitted radiance of area and sun
lights.

Estimated lights carry the estimator's ``score``; they are written as ``SphereLight`` prims
(point lights) and ``RectLight`` prims (planar emitters of a closed capture, ``shape='rect'``)
under ``/UsdGs/Lights`` with ``customData`` ``usdgs:score``, ``usdgs:estimated = true`` and
the estimate's evidence, so an artist can edit them in a DCC and re-run with ``--lights stage``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from usd_gs.errors import UserError

LIGHTS_ROOT = "/UsdGs/Lights"
SPHERE_LIKE = ("RectLight", "DiskLight", "CylinderLight")
DOME_TYPES = ("DomeLight", "DomeLight_1")
DEFAULT_SUN_ANGLE = 0.53  # degrees, the UsdLux DistantLight fallback


def blackbody_rgb(kelvin: float) -> np.ndarray:
    """Linear Rec.709 RGB (3,) of a blackbody at ``kelvin`` (clamped to [1000, 15000] K),
    scaled to luminance 1 (CIE Y of the Rec.709 primaries).

    Chromaticity of the Planckian locus by Krystek's rational approximation of the CIE 1960 UCS
    (u, v) (M. Krystek, "An algorithm to calculate correlated colour temperature", Color Research
    & Application 10(1), 1985; |error| < 8e-5 in u, v over 1000-15000 K), then CIE xy, XYZ with
    Y = 1 and the IEC 61966-2-1 XYZ -> linear sRGB matrix. 6500 K gives (1.04, 0.98, 1.04)
    (within 0.01 of ``UsdLux.BlackbodyTemperatureAsRgb``); negative components (deep red
    temperatures fall outside the Rec.709 gamut) are clipped to 0.
    """
    t = float(np.clip(kelvin, 1000.0, 15000.0))
    u = (0.860117757 + 1.54118254e-4 * t + 1.28641212e-7 * t * t) / (1.0 + 8.42420235e-4 * t + 7.08145163e-7 * t * t)
    v = (0.317398726 + 4.22806245e-5 * t + 4.20481691e-8 * t * t) / (1.0 - 2.89741816e-5 * t + 1.61456053e-7 * t * t)
    den = 2.0 * u - 8.0 * v + 4.0
    x, y = 3.0 * u / den, 2.0 * v / den
    xyz = np.array([x / y, 1.0, (1.0 - x - y) / y])
    m = np.array([[3.2404542, -1.5371385, -0.4985314],
                  [-0.9692660, 1.8760108, 0.0415560],
                  [0.0556434, -0.2040259, 1.0572252]])
    rgb = np.maximum(m @ xyz, 0.0)
    return rgb / float(0.2126729 * rgb[0] + 0.7151522 * rgb[1] + 0.0721750 * rgb[2])


@dataclass
class ShotLight:
    """One light in world space; see the module docstring for units and conventions."""

    name: str
    kind: str  # 'point' | 'directional' | 'dome'
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    intensity: float = 1.0
    radius: float = 0.0
    score: float | None = None
    source: str = "estimated"
    shape: str = ""  # 'point' | 'sphere' | 'rect' | 'disk' | 'cylinder' | 'distant' | 'dome' ('' = from kind)
    angle: float = 0.0  # DistantLight angular diameter, degrees
    width: float = 0.0
    height: float = 0.0
    axes: np.ndarray = field(default_factory=lambda: np.eye(3))
    normalize: bool = False
    env: np.ndarray | None = None  # dome: (h, w, 3) linear lat-long texture, None = uniform
    texture: str = ""  # dome: resolved path of inputs:texture:file ('' = none)
    direct_share: float | None = None  # measured darkening of its full shadow (customData usdgs:directShare)
    # dome: (D, V, L) of the sky the moving casters hide (customData usdgs:skyOcclusion;
    # usd_gs.shadows.sky_occlusion): the sun's linear share of a lit receiver's light, a lit
    # receiver's sky visibility, the lit receivers' linear luminance
    sky_occlusion: tuple | None = None

    @property
    def luminous_weight(self) -> float:
        """Relative strength used to weight lights against each other: intensity times the
        Rec.709 luminance of the colour."""
        return float(self.intensity * (0.2126 * self.color[0] + 0.7152 * self.color[1] + 0.0722 * self.color[2]))

    @property
    def form(self) -> str:
        """``shape``, or the one ``kind`` implies ('point' with radius 0, else 'sphere';
        'distant'; 'dome')."""
        if self.shape:
            return self.shape
        if self.kind == "directional":
            return "distant"
        if self.kind == "dome":
            return "dome"
        return "sphere" if self.radius > 0 else "point"

    def area(self) -> float:
        """Emitting area (m^2) of an area light (sphere 4 pi r^2, rect w h, disk pi r^2); 0 else."""
        f = self.form
        if f == "sphere":
            return 4.0 * math.pi * self.radius ** 2
        if f == "rect":
            return self.width * self.height
        if f == "disk":
            return math.pi * self.radius ** 2
        return 0.0

    def radiance(self) -> np.ndarray:
        """(3,) emitted radiance of an area light or of the sun disc: ``color * intensity``,
        divided by the area (:meth:`area`) when ``normalize`` is set; for a normalized (or
        zero-angle) DistantLight the value is its irradiance at normal incidence instead."""
        lum = np.asarray(self.color, np.float64) * float(self.intensity)
        a = self.area()
        if self.normalize and a > 0:
            return lum / a
        return lum

    def radiant_intensity(self) -> np.ndarray:
        """(3,) irradiance at 1 m, normal incidence, of a point-like light (``E = I cos / r^2``):
        a sphere light of radius R > 0 gives ``L pi R^2`` (L its :meth:`radiance`: a uniform
        sphere's exact far field, ``intensity / 4`` with ``normalize``); a point light
        (``treatAsPoint``, or radius 0) its ``color * intensity`` as it is: the project's
        point-light convention, also that of the estimated lights."""
        if self.radius > 0 and self.form in ("sphere", "point"):
            return self.radiance() * math.pi * self.radius ** 2
        return np.asarray(self.color, np.float64) * float(self.intensity)

    def sun_irradiance(self) -> np.ndarray:
        """(3,) irradiance at normal incidence of a DistantLight: ``L pi sin^2(angle / 2)`` (a
        uniform disc of radiance ``L = color * intensity``; ~ L times its solid angle); with
        ``normalize`` or ``angle`` 0 the colour times the intensity itself (UsdLux: a normalized
        distant light's intensity is its illuminance)."""
        lum = np.asarray(self.color, np.float64) * float(self.intensity)
        if self.normalize or self.angle <= 0:
            return lum
        return lum * math.pi * math.sin(math.radians(self.angle) / 2.0) ** 2


def _get(attr, time, default):
    v = attr.Get(time) if attr else None
    return default if v is None else v


def _finite_or_raise(path: str, what: str, value) -> None:
    a = np.asarray(value, dtype=np.float64)
    if not np.isfinite(a).all():
        raise UserError(f"{path}: {what} is not finite (first bad element {int(np.flatnonzero(~np.isfinite(a))[0])})")


def _world_axes(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit axes (3, 3) columns x, y, z; their lengths (3,)) of a row-vector 4x4 matrix."""
    lin = m[:3, :3].T.copy()  # columns = images of the local axes
    lengths = np.linalg.norm(lin, axis=0)
    return lin / np.where(lengths > 0, lengths, 1.0), lengths


def _dome_texture(prim, path: str, time):
    """(image (h, w, 3) float32 | None, resolved path) of a dome's ``inputs:texture:file``."""
    from pxr import UsdLux

    from usd_gs.errors import InputFormatError
    from usd_gs.io import envmap

    attr = UsdLux.DomeLight(prim).GetTextureFileAttr() if prim.GetTypeName() == "DomeLight" else \
        UsdLux.DomeLight_1(prim).GetTextureFileAttr()
    asset = attr.Get(time) if attr else None
    if asset is None or not asset.path:
        return None, ""
    resolved = asset.resolvedPath
    if not resolved:
        raise UserError(f"{path}: inputs:texture:file '{asset.path}' cannot be found")
    try:
        img = envmap.read_envmap(resolved)
    except (InputFormatError, OSError, ValueError) as exc:
        raise UserError(f"{path}: inputs:texture:file '{asset.path}' cannot be read ({exc})") from None
    if img.ndim != 3 or img.shape[2] < 3 or img.shape[1] < 2 or img.shape[0] < 1:
        raise UserError(f"{path}: inputs:texture:file '{asset.path}' is not a lat-long RGB image ({img.shape})")
    if (img[..., :3] < 0).any():
        raise UserError(f"{path}: inputs:texture:file '{asset.path}' has negative radiance")
    return np.ascontiguousarray(img[..., :3], np.float32), resolved


def read_stage_lights(stage, time, include_domes: bool = False) -> tuple[list[ShotLight], list[str]]:
    """All supported UsdLux lights of ``stage`` at ``time`` (world space) and warnings.

    ``include_domes``: also return ``DomeLight`` / ``DomeLight_1`` prims (``kind='dome'``, for the
    relighting; their textures are read here); without it they are skipped with a warning (shadow
    and evaluation callers). GeometryLight and PortalLight are skipped with a warning. Inactive
    and invisible lights are skipped. ``UserError`` naming the prim and attribute for a negative
    intensity or radius, a non-finite attribute or transform, and (with ``include_domes``) a
    dome texture that is missing or cannot be read.
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
        if type_name in DOME_TYPES and not include_domes:
            warnings.append(f"{path}: {type_name} is used for relighting only, not for shadows")
            continue
        if type_name not in ("DistantLight", "SphereLight") + SPHERE_LIKE + DOME_TYPES:
            warnings.append(f"{path}: {type_name or 'light'} is not used (only Sphere, Distant, Rect, Disk, "
                            f"Cylinder and Dome lights are)")
            continue
        api = UsdLux.LightAPI(prim)
        exposure = float(_get(api.GetExposureAttr(), time, 0.0))
        raw = float(_get(api.GetIntensityAttr(), time, 0.0))
        _finite_or_raise(path, "inputs:intensity", raw)
        _finite_or_raise(path, "inputs:exposure", exposure)
        if raw < 0:
            raise UserError(f"{path}: inputs:intensity is negative ({raw:g})")
        intensity = raw * 2.0 ** exposure
        color = np.array(_get(api.GetColorAttr(), time, (1.0, 1.0, 1.0)), dtype=np.float64)
        _finite_or_raise(path, "inputs:color", color)
        if (color < 0).any():
            raise UserError(f"{path}: inputs:color has a negative component {tuple(color)}")
        if bool(_get(api.GetEnableColorTemperatureAttr(), time, False)):
            kelvin = float(_get(api.GetColorTemperatureAttr(), time, 6500.0))
            _finite_or_raise(path, "inputs:colorTemperature", kelvin)
            if kelvin <= 0:
                raise UserError(f"{path}: inputs:colorTemperature must be > 0 K, got {kelvin:g}")
            color = color * blackbody_rgb(kelvin)
        normalize = bool(_get(api.GetNormalizeAttr(), time, False))
        m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time))
        if not np.isfinite(m).all():
            raise UserError(f"{path}: its transform (xformOp) is not finite")
        position = m[3, :3].copy()
        axes, lengths = _world_axes(m)
        scale = float(np.cbrt(max(abs(np.linalg.det(m[:3, :3])), 0.0)))
        common = dict(color=color, intensity=intensity, source=path, axes=axes, normalize=normalize)
        if type_name == "DistantLight":
            d = -m[2, :3]
            n = np.linalg.norm(d)
            if not n > 0:
                warnings.append(f"{path}: DistantLight has a degenerate transform; skipped")
                continue
            angle = float(_get(UsdLux.DistantLight(prim).GetAngleAttr(), time, DEFAULT_SUN_ANGLE))
            _finite_or_raise(path, "inputs:angle", angle)
            if not 0.0 <= angle < 180.0:
                raise UserError(f"{path}: inputs:angle must be in [0, 180) degrees, got {angle:g}")
            lights.append(ShotLight(path, "directional", position, d / n, shape="distant", angle=angle, **common))
        elif type_name == "SphereLight":
            sl = UsdLux.SphereLight(prim)
            point = bool(_get(sl.GetTreatAsPointAttr(), time, False))
            r = float(_get(sl.GetRadiusAttr(), time, 0.5))
            _finite_or_raise(path, "inputs:radius", r)
            if r < 0:
                raise UserError(f"{path}: inputs:radius is negative ({r:g})")
            radius = 0.0 if point else r * scale
            shape = "point" if point or radius == 0 else "sphere"
            lights.append(ShotLight(path, "point", position, radius=radius, shape=shape, **common))
        elif type_name in SPHERE_LIKE:
            warnings.append(f"{path}: {type_name} is approximated by a sphere light at its centre for shadows "
                            "(area samples for the relighting)")
            lt = ShotLight(path, "point", position, shape=type_name[:-5].lower(), **common)
            if type_name == "RectLight":
                rl = UsdLux.RectLight(prim)
                lt.width = float(_get(rl.GetWidthAttr(), time, 1.0)) * float(lengths[0])
                lt.height = float(_get(rl.GetHeightAttr(), time, 1.0)) * float(lengths[1])
                for name, v in (("inputs:width", lt.width), ("inputs:height", lt.height)):
                    _finite_or_raise(path, name, v)
                    if v < 0:
                        raise UserError(f"{path}: {name} is negative ({v:g})")
            elif type_name == "DiskLight":
                lt.radius = float(_get(UsdLux.DiskLight(prim).GetRadiusAttr(), time, 0.5)) * float(
                    np.sqrt(lengths[0] * lengths[1]))
                _finite_or_raise(path, "inputs:radius", lt.radius)
                if lt.radius < 0:
                    raise UserError(f"{path}: inputs:radius is negative ({lt.radius:g})")
            else:  # CylinderLight: a point light at its centre (its length and radius are not modelled)
                lt.shape = "point"
            lights.append(lt)
        else:  # dome
            env, resolved = _dome_texture(prim, path, time)
            dome_axes = axes
            if type_name == "DomeLight_1" and str(_get(UsdLux.DomeLight_1(prim).GetPoleAxisAttr(), time,
                                                       "scene")) == "Z":
                # the texture's +Y pole follows world +Z: texture (x, y, z) -> world (x, -z, y) ... then the prim
                dome_axes = axes @ np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
            elif type_name == "DomeLight_1" and str(_get(UsdLux.DomeLight_1(prim).GetPoleAxisAttr(), time,
                                                         "scene")) == "scene":
                from pxr import UsdGeom as _G

                if _G.GetStageUpAxis(stage) == _G.Tokens.z:
                    dome_axes = axes @ np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
            common["axes"] = dome_axes
            lights.append(ShotLight(path, "dome", position, shape="dome", env=env, texture=resolved, **common))
    return lights, warnings


def write_estimated_lights(stage, lights: list[ShotLight], radius: float = 0.05, root: str = LIGHTS_ROOT,
                           evidence: dict | None = None) -> list[str]:
    """Author ``lights`` (``kind='point'``) as ``SphereLight`` prims ``<root>/Light_<i>``, and
    the ones with ``shape='rect'`` (estimated planar emitters) as ``RectLight`` prims
    ``<root>/<name>``; returns their paths.

    Values are static (one set of lights per shot); ``customData`` keeps the estimator's
    score (``usdgs:score``, ``usdgs:estimated = true``) and ``evidence[name]`` as
    ``usdgs:<key>``. Positions go into a ``translate`` op in world space (a RectLight also gets an
    ``orient`` op: its local x, y, z = the columns of ``axes``, emitting along local -Z, with
    ``inputs:width`` / ``inputs:height`` along x / y and ``inputs:normalize = false``, so that
    ``color * intensity`` is its emitted radiance), so ``root`` and its parent must not carry
    transforms (they are defined here as plain ``Scope`` prims). A handful of prims: plain stage
    API calls (``Define`` is not allowed inside ``Sdf.ChangeBlock``).
    """
    from pxr import Gf, UsdGeom, UsdLux

    evidence = evidence or {}
    parts = root.strip("/").split("/")
    for i in range(len(parts)):
        UsdGeom.Scope.Define(stage, "/" + "/".join(parts[: i + 1]))
    paths = []
    n_sphere = 0
    for light in lights:
        if light.form == "rect":
            path = f"{root}/{light.name}"
            sl = UsdLux.RectLight.Define(stage, path)
            xf = UsdGeom.Xformable(sl.GetPrim())
            xf.AddTranslateOp().Set(Gf.Vec3d(*map(float, light.position)))
            w, x, y, z = matrix_orient(light.axes)
            xf.AddOrientOp().Set(Gf.Quatf(float(w), float(x), float(y), float(z)))
            sl.CreateWidthAttr(float(light.width))
            sl.CreateHeightAttr(float(light.height))
            sl.CreateNormalizeAttr(False)
        else:
            path = f"{root}/Light_{n_sphere}"
            n_sphere += 1
            sl = UsdLux.SphereLight.Define(stage, path)
            UsdGeom.Xformable(sl.GetPrim()).AddTranslateOp().Set(Gf.Vec3d(*map(float, light.position)))
            sl.CreateRadiusAttr(float(light.radius or radius))
            sl.CreateTreatAsPointAttr(False)
        sl.CreateIntensityAttr(float(light.intensity))
        sl.CreateColorAttr(Gf.Vec3f(*map(float, light.color)))
        prim = sl.GetPrim()
        prim.SetCustomDataByKey("usdgs:estimated", True)
        if light.score is not None:
            prim.SetCustomDataByKey("usdgs:score", float(light.score))
        for key, v in (evidence.get(light.name) or {}).items():
            prim.SetCustomDataByKey(f"usdgs:{key}", _custom_value(v))
        paths.append(path)
    return paths


def _custom_value(v):
    """A customData-safe value: numbers, strings, bools, flat lists of numbers; None -> ''."""
    if v is None:
        return ""
    if isinstance(v, (bool, str)):
        return v
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    a = np.asarray(v, np.float64).ravel()
    from pxr import Vt

    return Vt.DoubleArray([float(x) for x in a])


def direction_orient(direction) -> tuple:
    """(w, x, y, z) unit quaternion of a rotation whose local -Z axis maps to unit ``direction``."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    z = -d
    h = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(h, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return matrix_orient(np.stack([x, y, z], axis=1))


def matrix_orient(axes) -> tuple:
    """(w, x, y, z) unit quaternion of the rotation ``axes`` (3, 3) (columns: world images of the
    local x, y, z axes; orthonormal, determinant +1), for a UsdGeom ``orient`` op."""
    r = np.asarray(axes, np.float64)
    w = math.sqrt(max(1.0 + r[0, 0] + r[1, 1] + r[2, 2], 1e-12)) / 2.0
    if w > 1e-3:
        return (w, (r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w))
    k = int(np.argmax(np.diag(r)))
    i, j = (k + 1) % 3, (k + 2) % 3
    s = math.sqrt(max(1.0 + r[k, k] - r[i, i] - r[j, j], 1e-12)) * 2.0
    q = np.zeros(4)
    q[0] = (r[j, i] - r[i, j]) / s
    q[1 + k] = s / 4.0
    q[1 + i] = (r[i, k] + r[k, i]) / s
    q[1 + j] = (r[j, k] + r[k, j]) / s
    return tuple(q / np.linalg.norm(q))


def write_capture_lights(stage, lights: list[ShotLight], evidence: dict | None = None, textures: dict | None = None,
                         root: str = LIGHTS_ROOT, up_axis: str = "Y") -> list[str]:
    """Author the lights estimated from a capture (``usd_gs.pipeline.capture_lights``) under ``root``:

    - ``kind='directional'``: a ``DistantLight`` ``<root>/<name>`` oriented by an ``orient`` op
      (local -Z along the light's propagation direction), ``inputs:angle``, ``inputs:normalize =
      true`` with ``intensity * color`` the irradiance at normal incidence;
    - ``kind='dome'``: a ``DomeLight`` ``<root>/<name>`` with ``inputs:texture:file`` =
      ``textures[name]`` (a lat-long EXR, ``inputs:texture:format = latlong``), rotated +90 deg
      about X on a Z-up stage (the texture's pole is its +Y);
    - point lights: as :func:`write_estimated_lights` (``<root>/Light_<i>`` SphereLights, and
      ``<root>/<name>`` RectLights for the estimated planar emitters, ``shape='rect'``).

    ``evidence``: ``{light name: {key: value}}`` written as ``customData`` ``usdgs:<key>`` (score,
    direct share, the estimate's figures; a ``sh`` entry of a dome is its real-SH radiance,
    flattened), plus ``usdgs:estimated = true`` and ``usdgs:score``. ``evidence['']`` goes on
    ``root``. Returns the light prims' paths.
    """
    from pxr import Gf, Sdf, UsdGeom, UsdLux

    evidence = evidence or {}
    textures = textures or {}
    points = [lt for lt in lights if lt.kind == "point"]
    paths = write_estimated_lights(stage, points, root=root, evidence=evidence) if points else []
    parts = root.strip("/").split("/")
    for i in range(len(parts)):
        UsdGeom.Scope.Define(stage, "/" + "/".join(parts[: i + 1]))
    for key, v in (evidence.get("") or {}).items():
        stage.GetPrimAtPath(root).SetCustomDataByKey(f"usdgs:{key}", _custom_value(v))
    for lt in lights:
        if lt.kind == "point":
            continue
        path = f"{root}/{lt.name}"
        if lt.kind == "directional":
            light = UsdLux.DistantLight.Define(stage, path)
            w, x, y, z = direction_orient(lt.direction)
            UsdGeom.Xformable(light.GetPrim()).AddOrientOp().Set(Gf.Quatf(float(w), float(x), float(y), float(z)))
            light.CreateAngleAttr(float(lt.angle or DEFAULT_SUN_ANGLE))
            light.CreateNormalizeAttr(True)
        elif lt.kind == "dome":
            light = UsdLux.DomeLight.Define(stage, path)
            if up_axis.upper() == "Z":
                UsdGeom.Xformable(light.GetPrim()).AddRotateXOp().Set(90.0)
            if lt.name in textures:
                light.CreateTextureFileAttr(Sdf.AssetPath(textures[lt.name]))
                light.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
        else:
            continue
        light.CreateIntensityAttr(float(lt.intensity))
        light.CreateColorAttr(Gf.Vec3f(*map(float, lt.color)))
        prim = light.GetPrim()
        prim.SetCustomDataByKey("usdgs:estimated", True)
        if lt.score is not None:
            prim.SetCustomDataByKey("usdgs:score", float(lt.score))
        for key, v in (evidence.get(lt.name) or {}).items():
            prim.SetCustomDataByKey(f"usdgs:{key}", _custom_value(v))
        paths.append(path)
    return paths
