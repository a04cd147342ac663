"""Opening stages and resolving user-given prim paths and time codes, with user errors
instead of USD exceptions. No numba here (it is on the start-up path of every command)."""

from __future__ import annotations

import os

from usd_gs.errors import InputFormatError, UserError

USD_EXTENSIONS = (".usd", ".usda", ".usdc")


def _capture_hint(path: str) -> str | None:
    """The advice for a 3DGS capture (a file or SOG folder that ``usd_gs.io.formats`` reads) given
    where a USD stage is expected, else None (asked only once the path failed to open as a stage)."""
    from usd_gs.io.formats import capture_kind

    try:
        capture_kind(path)
    except UserError:
        return None
    stem = os.path.basename(os.path.normpath(path)).split(".")[0] or "capture"
    return (f"{path}: is a 3DGS capture, not a USD stage; convert it first: usdgs import {path} -o {stem}.usdc "
            f"(add --role avatar or --role object for a character or a prop), then sublayer or reference it "
            f"from your shot stage")


_ALLOW_MISSING = [False]

#: Composition errors that mean part of the stage is absent (a layer or prim that cannot be found).
MISSING_ERRORS = ("ErrorInvalidSublayerPath", "ErrorInvalidAssetPath", "ErrorUnresolvedPrimPath")


def set_allow_missing(value: bool) -> None:
    """The process-wide default of ``open_stage(..., allow_missing=None)`` (the CLI's ``--allow-missing``)."""
    _ALLOW_MISSING[0] = bool(value)


def missing_layers(stage) -> list[str]:
    """One line per missing sublayer, reference, payload or referenced prim of ``stage``
    (``Usd.Stage.GetCompositionErrors``), in USD's wording."""
    return [" ".join(str(e).split()) for e in stage.GetCompositionErrors() if type(e).__name__ in MISSING_ERRORS]


def open_stage(path: str, allow_missing: bool | None = None):
    """Open a USD stage read-only in intent (nothing here ever saves it).

    Raises ``InputFormatError`` naming the file when it is missing or unreadable, and, unless
    ``allow_missing`` (None: the :func:`set_allow_missing` default), when a sublayer, reference
    or payload it composes cannot be found (USD itself only warns and composes the rest).
    """
    from pxr import Tf, Usd

    if not os.path.exists(path):
        raise InputFormatError(f"{path}: no such file")
    if os.path.isdir(path):
        raise InputFormatError(_capture_hint(path) or f"{path}: is a directory, not a USD stage")
    try:
        stage = Usd.Stage.Open(path)
    except Tf.ErrorException as exc:
        msg = " ".join(str(exc).split())
        raise InputFormatError(_capture_hint(path) or f"{path}: cannot be opened as a USD stage ({msg[:300]})") \
            from None
    if stage is None:
        raise InputFormatError(_capture_hint(path) or f"{path}: cannot be opened as a USD stage")
    if not (_ALLOW_MISSING[0] if allow_missing is None else allow_missing):
        missing = missing_layers(stage)
        if missing:
            more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
            raise InputFormatError(f"{path}: part of the stage is missing: {missing[0]}{more}; "
                                   "fix the path or pass --allow-missing to use the stage without it")
    return stage


def check_usd_output_path(path: str) -> str:
    """Return the lower-case extension of a USD output path, or raise ``UserError``."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in USD_EXTENSIONS:
        raise UserError(f"{path}: output must end in {', '.join(USD_EXTENSIONS)} (got '{ext or 'no extension'}')")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise UserError(f"{path}: output directory {parent} does not exist")
    return ext


def prim_path(text: str):
    """Parse an absolute prim path given on the command line (``Sdf.Path``)."""
    from pxr import Sdf

    if not text or not Sdf.Path.IsValidPathString(text):
        raise UserError(f"'{text}' is not a valid USD prim path")
    p = Sdf.Path(text)
    if not p.IsAbsolutePath() or not p.IsPrimPath() or p == Sdf.Path.absoluteRootPath:
        raise UserError(f"'{text}' is not an absolute prim path such as /World/Gaussians")
    return p


def gaussian_prim(stage, path_text: str, stage_path: str):
    """The ``ParticleField3DGaussianSplat`` prim at ``path_text`` or a ``UserError``."""
    from usd_gs.usd.gaussian_prim import find_gaussian_prims

    p = prim_path(path_text)
    prim = stage.GetPrimAtPath(p)
    if not prim or not prim.IsValid():
        found = ", ".join(str(x.GetPath()) for x in find_gaussian_prims(stage)[:10]) or "none"
        raise UserError(f"{stage_path}: no prim at {p} (Gaussian prims in the stage: {found})")
    if prim.GetTypeName() != "ParticleField3DGaussianSplat":
        raise UserError(f"{stage_path}: prim {p} is a '{prim.GetTypeName() or 'typeless'}' prim, "
                        "not a ParticleField3DGaussianSplat")
    return prim


def time_code(text: str | None):
    """'default' -> Default time; ``None``/'earliest' -> EarliestTime; else a float time code.

    EarliestTime is the default because it gives the default value of unanimated
    attributes and the first sample of animated ones (Default time ignores samples)."""
    from pxr import Usd

    if text is not None and text.lower() == "default":
        return Usd.TimeCode.Default()
    if text is None or text.lower() == "earliest":
        return Usd.TimeCode.EarliestTime()
    try:
        value = float(text)
    except ValueError:
        raise UserError(f"--time '{text}' is not a number, 'default' or 'earliest'") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise UserError(f"--time '{text}' must be finite")
    return Usd.TimeCode(value)


#: stage metadata that USD reads from the root layer only, with its fallback's meaning
_ROOT_ONLY = {"metersPerUnit": "centimetres", "upAxis": None}


def root_metadata_warnings(stage, name: str | None = None) -> list[str]:
    """One line per stage metadatum (``metersPerUnit``, ``upAxis``) that the root layer of ``stage``
    does not author while a layer it uses (a sublayer, a reference) authors another value than the
    one the stage resolves to: USD reads these from the root layer only, so the stage falls back
    to USD's default (metersPerUnit 0.01: centimetres) and every distance the tool derives (shadow
    reach, probe radii, light estimation) is off by that factor. ``name``: how to call the stage
    (default: its root layer's path)."""
    root = stage.GetRootLayer()
    name = name or root.identifier
    out = []
    layers = None
    for key, meaning in _ROOT_ONLY.items():
        if root.pseudoRoot.HasInfo(key):
            continue
        value = stage.GetMetadata(key)
        if layers is None:  # its own sublayers first (in strength order), then the layers it references
            layers = list(stage.GetLayerStack(includeSessionLayers=False))
            stack = set(layers)
            layers += [lay for lay in stage.GetUsedLayers() if lay not in stack]
        for layer in layers:
            if layer == root or layer.anonymous or not layer.pseudoRoot.HasInfo(key):
                continue
            other = layer.pseudoRoot.GetInfo(key)
            if other != value:
                fallback = f"{value:g}" if isinstance(value, float) else str(value)
                said = f"{other:g}" if isinstance(other, float) else str(other)
                out.append(f"{name}: {key} is not authored on the root layer, so the stage is read with USD's "
                           f"default {fallback}{f' ({meaning})' if meaning else ''}, but {layer.identifier} says "
                           f"{said}: author {key} = {said} in the root layer's header (USD reads it from the root "
                           f"layer only)")
                break
    return out
