"""Options of the main job (``usdgs process``) and their JSON ``--config`` file.

``ProcessOptions`` is a plain value: nothing in the pipeline mutates it (the shot's up axis
lives in ``ShotProcessor.dgsm``). Config files hold a JSON object whose keys are the long
option names with '_' (``direct_fraction``, ``atlas_size``, ...): DGSM keys are the fields of
``usd_gs.shadows.dgsm.DGSMConfig`` that a user may set (:data:`DGSM_KEYS`), the others those of
:class:`ProcessOptions` (:data:`PROCESS_KEYS`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields, is_dataclass

from usd_gs.errors import UserError
from usd_gs.relight.probe import PROBE_SUPERSAMPLE
from usd_gs.shadows.dgsm import DGSMConfig
from usd_gs.usd.output_author import AOVS, PRECISIONS, SH_TOLERANCE


@dataclass
class ProcessOptions:
    """Options of ``usdgs process`` (see ``usdgs process --help`` for each)."""

    frames: str | None = None
    lights: str = "auto"  # 'auto' | 'indoor' | 'outdoor' | 'stage' | a number of lights to estimate
    lights_per_frame: bool = False
    scene_paths: tuple[str, ...] = ()
    avatar_paths: tuple[str, ...] = ()
    object_paths: tuple[str, ...] = ()
    direct_fraction: float | None = None  # None: measured from the capture's lights (capture_lights.direct_fraction)
    default_light_count: int = 2
    dgsm: DGSMConfig = field(default_factory=DGSMConfig)
    contact_bias: float = 0.03
    emitter_radius: float = 0.25
    roi: str = "cone"  # receiver ROI per caster: 'cone' | 'box' (the paper's) | 'all'
    probe_size: int = 32
    probe_degree: int = 3
    transfer_degree: int = 4
    probe_points: int = 8
    probe_supersample: int = PROBE_SUPERSAMPLE  # usd_gs.relight.probe: 1, drawn at the probe size
    # usd_gs.relight.far_field: static Gaussians beyond this many metres of a relit prim's probe come
    # from a cached render (0: every probe draws everything), redrawn when the probe moves to another
    # cell of a grid of this fraction of the radius
    probe_far_radius: float = 15.0
    probe_far_tolerance: float = 0.05
    # usd_gs.relight.probe_merge: moving prims drawn in the other prims' probes merged per cell of
    # this many metres where a cell is at most one probe texel across (0: every Gaussian drawn)
    probe_merge_cell: float = 0.03
    probe_texture: tuple[int, int] = (32, 64)
    relight_q: float = 1.0
    relight_gamma: float = 1.0
    relight_t_max: float = 8.0
    # a shot without any light keeps each relit prim's captured mean brightness (usd_gs.relight.avatar,
    # "A shot without any light"); False: the probe's absolute level, however dark
    keep_level_without_lights: bool = True
    color_space: str = "srgb"  # of the Gaussians' colours for relighting: 'srgb' (display-referred) | 'linear'
    self_shadow: bool = True  # a relit prim's own Gaussians shadow its direct light (DGSM, with the bias below)
    self_shadow_bias: float = 0.05  # metres toward the light for a relit prim's own shadow lookups
    self_shadow_normal: float = 0.75  # and this many median Gaussian sigmas (largest axis) along the normal
    self_shadow_kappa: float = 0.25  # DGSM absorption knob (eq. 5 kappa) of a prim's own shadow on itself
    self_shadow_lights: str = "distant"  # self-shadow from 'distant' lights only (the sun) or from 'all'
    self_shadow_samples: int = 4096  # Gaussians per relit prim that sample its self-shadow (nearest for the rest)
    # Gaussians per moving receiver that sample the shadows other moving casters put on it (the
    # rest take their nearest sample's; 0: every Gaussian looks up)
    moving_receiver_samples: int = 4096
    aovs: tuple[str, ...] = ()  # diagnostic primvars to write too: names of usd_gs.usd.output_author.AOVS
    precision: str = "half"  # of the SH written: 'half' | 'float'
    sh_tolerance: float = SH_TOLERANCE  # display-colour change below which an SH sample is held
    allow_missing: bool = False  # open an input whose sublayers/references are partly missing
    bake_skinning: bool = False  # also author skinned prims' Gaussians as time samples (viewers without UsdSkel)

    def check(self) -> ProcessOptions:
        if self.direct_fraction is not None and not 0.0 <= self.direct_fraction <= 1.0:
            raise UserError(f"--direct-fraction must be in [0, 1], got {self.direct_fraction}")
        if self.roi not in ("cone", "box", "all"):
            raise UserError(f"roi must be 'cone', 'box' or 'all', got '{self.roi}'")
        from usd_gs.resources import check_limit

        check_limit("probe_size", self.probe_size, "probe_size")
        if self.probe_size < 4 or self.probe_degree < 0 or self.probe_degree > 3:
            raise UserError("probe size must be >= 4 and probe degree 0..3")
        if not 0 <= self.transfer_degree <= 8:
            raise UserError(f"transfer degree must be 0..8, got {self.transfer_degree}")
        if not 1 <= self.probe_points <= 64:
            raise UserError(f"probe points must be 1..64, got {self.probe_points}")
        if not 1 <= self.probe_supersample <= 4:
            raise UserError(f"probe supersampling must be 1..4, got {self.probe_supersample}")
        if not self.probe_far_radius >= 0.0:
            raise UserError(f"probe_far_radius must be >= 0 metres (0: off), got {self.probe_far_radius}")
        if not 0.0 <= self.probe_merge_cell <= 1.0:
            raise UserError(f"probe_merge_cell must be in [0, 1] metres (0: off), got {self.probe_merge_cell}")
        if not 0.0 < self.probe_far_tolerance <= 0.5:
            raise UserError(f"probe_far_tolerance must be in (0, 0.5], got {self.probe_far_tolerance}")
        if self.lights not in ("auto", "stage", "indoor", "outdoor"):
            try:
                k = int(self.lights)
            except ValueError:
                raise UserError(f"--lights must be 'auto', 'indoor', 'outdoor', 'stage' or a number, "
                                f"got '{self.lights}'") from None
            if not 1 <= k <= 16:
                raise UserError(f"--lights {k}: estimate between 1 and 16 lights")
        unknown = [a for a in self.aovs if a not in AOVS]
        if isinstance(self.aovs, str) or unknown:
            raise UserError(f"--aovs: unknown AOV '{unknown[0] if unknown else self.aovs}' "
                            f"(choose from {', '.join(AOVS)})")
        if self.precision not in PRECISIONS:
            raise UserError(f"--precision must be 'half' or 'float', got '{self.precision}'")
        if not 0.0 <= self.sh_tolerance <= 0.1:
            raise UserError(f"sh_tolerance must be in [0, 0.1] (display colour), got {self.sh_tolerance}")
        if self.color_space not in ("srgb", "linear"):
            raise UserError(f"--color-space must be 'srgb' or 'linear', got '{self.color_space}'")
        if self.self_shadow_lights not in ("distant", "all"):
            raise UserError(f"self_shadow_lights must be 'distant' or 'all', got '{self.self_shadow_lights}'")
        if not self.self_shadow_kappa > 0.0:
            raise UserError(f"self_shadow_kappa must be > 0, got {self.self_shadow_kappa}")
        m = self.moving_receiver_samples
        if isinstance(m, bool) or not (isinstance(m, int) and m >= 0):
            raise UserError(f"moving_receiver_samples must be an integer >= 0 (0: every Gaussian), "
                            f"got {self.moving_receiver_samples!r}")
        if not self.self_shadow_bias >= 0.0:
            raise UserError(f"self_shadow_bias must be >= 0 metres, got {self.self_shadow_bias}")
        self.dgsm.validate()
        return self


#: DGSMConfig fields a config file may set (the rest are derived from the shot or internal).
DGSM_KEYS = tuple(f.name for f in fields(DGSMConfig)
                  if f.name not in ("t_max", "roi_percentiles", "roi_margin", "up_axis", "bin_skip"))
#: ProcessOptions fields a config file may set (prim roles come from the stage or the command line).
PROCESS_KEYS = tuple(f.name for f in fields(ProcessOptions)
                     if f.name not in ("scene_paths", "avatar_paths", "object_paths", "dgsm", "default_light_count",
                                       "probe_texture", "allow_missing"))


def load_config(path: str) -> dict:
    """The JSON object of a ``--config`` file (keys checked against :data:`DGSM_KEYS` and
    :data:`PROCESS_KEYS`); ``UserError`` naming the file for a missing file, invalid JSON, a
    non-object or an unknown key."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise UserError(f"--config {path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"--config {path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"--config {path}: cannot be read ({getattr(exc, 'strerror', None) or exc})") from None
    if not isinstance(data, dict):
        raise UserError(f"--config {path}: must hold a JSON object")
    unknown = set(data) - set(DGSM_KEYS) - set(PROCESS_KEYS)
    if unknown:
        raise UserError(f"--config {path}: unknown option(s) {', '.join(sorted(unknown))}")
    for key, value in data.items():
        _check_type(path, key, value)
    return data


def _field_types() -> dict:
    """option name -> its annotation text (``'int'``, ``'float | None'``, ``'tuple[str, ...]'``)."""
    out = {f.name: str(f.type) for f in fields(DGSMConfig)}
    out.update({f.name: str(f.type) for f in fields(ProcessOptions)})
    return out


def _check_type(path: str, key: str, value) -> None:
    """``UserError`` naming the file and key when a config value has the wrong JSON type for its
    option (an int where an integer is expected, a finite number for a float, ...)."""
    import math

    ann = _field_types().get(key, "")
    if key == "lights" and isinstance(value, int) and not isinstance(value, bool):
        return  # a number of lights to estimate
    kinds = [a.strip() for a in ann.split("|")]
    if value is None and "None" in kinds:
        return
    ok = True
    for kind in kinds:
        if kind == "None":
            continue
        if kind == "int":
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif kind == "float":
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        elif kind == "bool":
            ok = isinstance(value, bool)
        elif kind == "str":
            ok = isinstance(value, str)
        elif kind.startswith("tuple"):
            ok = isinstance(value, list)
        else:
            return  # a type this check does not know: the option's own validation decides
        if ok:
            return
    want = " or ".join({"int": "an integer", "float": "a finite number", "bool": "true or false", "str": "a string",
                        "None": "null"}.get(k, "a list") for k in kinds)
    raise UserError(f"--config {path}: '{key}' must be {want}, got {json.dumps(value)[:60]}")


def dgsm_config(cfg: dict) -> DGSMConfig:
    """The ``DGSMConfig`` of a loaded config dict (defaults for keys it does not set)."""
    return DGSMConfig(**{k: cfg[k] for k in DGSM_KEYS if k in cfg})


def process_kwargs(cfg: dict) -> dict:
    """The ``ProcessOptions`` keyword arguments a loaded config dict sets."""
    return {k: cfg[k] for k in PROCESS_KEYS if k in cfg}


def canonical(value):
    """JSON-able, exact form of options and lights (floats as hex, arrays as lists): two values with
    the same form are the same values (the farm run's key, a frame's lights against the last one's)."""
    import numpy as np

    if is_dataclass(value):
        return {f.name: canonical(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, dict):
        return {str(k): canonical(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [canonical(v) for v in value]
    if isinstance(value, np.ndarray):
        return [canonical(v) for v in value.tolist()]
    if isinstance(value, (float, np.floating)):
        return float(value).hex()
    if isinstance(value, np.integer):
        return int(value)
    return value
