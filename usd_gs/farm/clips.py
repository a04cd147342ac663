"""Stitching chunk layers into one stage with USD value clips (``usdgs assemble``).

Given finished chunks (``usd_gs.farm.chunks``: one layer per run of frames, each with its
own start and end time codes), :func:`assemble` writes three layers beside ``OUT``:

- ``OUT`` (root): sublayers ``[<stem>.topology.usdc, INPUT]`` like the single-run output
  (stage metadata copied from the input's root layer), and carries a ``clips`` set on every
  root prim the chunks write (``/World``, ``/UsdGs``, ...): the chunk layers in frame order,
  clip ``k`` active from its first frame, identity clip times.
- ``<stem>.topology.usdc``: every prim and attribute spec of the chunks without their time
  samples (``UsdUtils.StitchClipsTopology``: probe and light prims, their static values,
  primvar interpolation and elementSize), plus for each overridden Gaussian prim its type,
  ``radiance:sphericalHarmonicsDegree`` and the SH primvar's interpolation and elementSize
  copied from the input, so the output reads right without the input's opinions.
- ``<stem>.manifest.usdc``: the clip manifest, one spec per attribute that has samples in
  some chunk.

Values clips do not fall back to weaker layers: where the active clip has no sample for
an attribute of the manifest, USD takes the manifest's default. A chunk leaves an
attribute out exactly when it was unaffected at all of the chunk's frames (the single run
then reads the unaffected value there too), so the manifest default of such an attribute is
that unaffected value: all ones for ``primvars:usdgs:transmittance`` and the input's own
prim-local SH for ``radiance:sphericalHarmonicsCoefficients`` or its half variant (the pipeline
authors SH in the prim's own frame). A moving prim (animated transform or positions) has the same unaffected
values at every frame as long as its Gaussian count (for the transmittance) and its input SH
(for the SH) do not change over time; where they do, a chunk missing the attribute is an error. Inside a
chunk, every value is authored from the chunk's first frame and held values are re-authored
before each change (``usd_gs.usd.output_author``), so whole-frame queries equal the single run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdUtils, Vt

from usd_gs.errors import UserError
from usd_gs.farm.chunks import PREFIX, entry_files_ok, input_hash, read_sidecar
from usd_gs.io.atomic import atomic_output
from usd_gs.usd.gaussian_prim import describe_gaussian_prim, file_format_args, read_gaussian_prim, save_stage_atomic
from usd_gs.usd.output_author import SH_COEFFS, SH_COEFFS_HALF, TRANSMITTANCE
from usd_gs.usd.output_layer import OutputLayer, _relative_asset_path, topology_layer_path
from usd_gs.usd.stage import check_usd_output_path, open_stage

SH_DEGREE = "radiance:sphericalHarmonicsDegree"


@dataclass
class AssembleSummary:
    output: str
    topology: str
    manifest: str
    chunks: list  # chunk layer file names, frame order
    frames: list
    filled: int  # attributes given a manifest default (missing in some chunk)


def _layer_frames(path: Path) -> str:
    """``frames A-B`` of a chunk layer (its start and end time codes), or its name's part."""

    try:
        layer = Sdf.Layer.FindOrOpen(str(path))
    except Exception:  # noqa: BLE001 - a broken layer: fall back to the name
        layer = None
    if layer is not None and layer.HasStartTimeCode() and layer.HasEndTimeCode():
        a, b = layer.startTimeCode, layer.endTimeCode
        return f"frames {a:g}" if a == b else f"frames {a:g}-{b:g}"
    return "frames " + path.stem[len(PREFIX):].replace("_", "-")


def collect_chunks(folder, allow_gaps: bool = False) -> list[dict]:
    """Finished chunk entries of ``folder`` in frame order (each entry gets ``path``).

    Raises ``UserError`` when there are none, when a chunk's files do not match its entry,
    when chunks of different options or inputs are mixed, when frame ranges overlap, or,
    unless ``allow_gaps``, when a chunk layer has no finished entry (its frames would be
    absent from the stitched stage)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: no such chunk folder")
    entries = []
    for side in sorted(folder.glob(f"{PREFIX}*.json")):
        e = read_sidecar(side)
        if e is None:
            raise UserError(f"{side}: not a usdgs chunk entry (unreadable or wrong format)")
        if not entry_files_ok(e, folder):
            raise UserError(f"{side}: chunk layer {e.get('layer')} or its probes are missing or were changed; "
                            "re-run the chunk")
        e["path"] = str(folder / e["layer"])
        entries.append(e)
    if not entries:
        raise UserError(f"{folder}: holds no finished chunk ({PREFIX}*.json)")
    if not allow_gaps:
        listed = {e["layer"] for e in entries}
        orphans = sorted(p for p in folder.glob(f"{PREFIX}*.usdc") if p.name not in listed)
        if orphans:
            what = ", ".join(f"{p.name} ({_layer_frames(p)})" for p in orphans[:4])
            more = f" and {len(orphans) - 4} more" if len(orphans) > 4 else ""
            raise UserError(f"{folder}: chunk {what}{more} has no finished manifest entry ({PREFIX}*.json), so "
                            "its frames would be missing from the output; re-run that chunk (or pass --allow-gaps)")
    groups = {(e["input"], e["input_hash"], e["options_hash"]) for e in entries}
    if len(groups) > 1:
        raise UserError(f"{folder}: chunks of {len(groups)} different runs (input, input bytes or options differ) "
                        "are mixed; remove the stale ones or re-run with the same command")
    entries.sort(key=lambda e: e["frames"][0])
    for a, b in zip(entries, entries[1:], strict=False):
        if b["frames"][0] <= a["frames"][-1]:
            raise UserError(f"{folder}: chunks {a['layer']} (frames {a['frames'][0]:g}-{a['frames'][-1]:g}) and "
                            f"{b['layer']} (frames {b['frames'][0]:g}-{b['frames'][-1]:g}) overlap")
    return entries


def _sampled_attributes(layers) -> dict:
    """attribute path -> (type name, set of clip indices with time samples)."""

    found: dict = {}
    for k, layer in enumerate(layers):
        paths = []
        layer.Traverse(Sdf.Path.absoluteRootPath, lambda p, out=paths: out.append(p) if p.IsPropertyPath() else None)
        for p in paths:
            spec = layer.GetAttributeAtPath(p)
            if spec and layer.GetNumTimeSamplesForPath(p):
                entry = found.setdefault(p, [spec.typeName, set()])
                entry[1].add(k)
    return found


def _unaffected_value(stage, attr_path, missing_in: str):
    """The value the single run holds where nothing affected the attribute (module docstring)."""

    prim = stage.GetPrimAtPath(attr_path.GetPrimPath())
    name = attr_path.name
    why = f"{attr_path} has no samples in chunk {missing_in}"
    if not prim or name not in (TRANSMITTANCE, SH_COEFFS, SH_COEFFS_HALF):
        raise UserError(f"{why} and no unaffected value is defined for it; re-run with a larger --chunk-size")
    info = describe_gaussian_prim(prim, Usd.TimeCode.EarliestTime())
    varying = [a for a in ("positions", "positionsh", SH_COEFFS, SH_COEFFS + "h")
               if prim.HasAttribute(a) and prim.GetAttribute(a).GetNumTimeSamples() > 1]
    counts = {len(prim.GetAttribute(a).Get(t) or []) for a in varying if a.startswith("positions")
              for t in prim.GetAttribute(a).GetTimeSamples()}
    if counts - {info.count} or (name != TRANSMITTANCE and any(a.startswith(SH_COEFFS) for a in varying)):
        raise UserError(f"{why}, and the prim's Gaussian count or input SH change over time, so its unaffected "
                        "value differs per frame: re-run with a larger --chunk-size or one chunk for this shot")
    if name == TRANSMITTANCE:
        return Vt.FloatArray.FromNumpy(np.ones(info.count, np.float32))
    g = read_gaussian_prim(prim, Usd.TimeCode.EarliestTime(), world=False)
    if name == SH_COEFFS_HALF:
        return Vt.Vec3hArray.FromNumpy(np.ascontiguousarray(g.sh.astype(np.float16).reshape(-1, 3)))
    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(g.sh.astype(np.float32).reshape(-1, 3)))


def _relative(target: Path, out_dir: Path) -> str:
    return _relative_asset_path(Path(os.path.abspath(target)), out_dir)


def _reanchor_assets(topo, layers, out_dir: Path) -> None:
    """Relative asset paths that the stitching copied from a chunk layer into ``topo`` (static
    values such as an estimated sky's ``inputs:texture:file``, relative to the chunk's folder)
    rewritten relative to ``out_dir``, where the topology layer lives."""
    specs = []

    def visit(path):
        if path.IsPropertyPath():
            spec = topo.GetAttributeAtPath(path)
            if spec and spec.typeName == Sdf.ValueTypeNames.Asset and spec.HasDefaultValue():
                specs.append(spec)

    topo.Traverse(Sdf.Path.absoluteRootPath, visit)
    for spec in specs:
        value = spec.default
        if not value.path or os.path.isabs(value.path) or not value.path.startswith("."):
            continue
        for layer in layers:
            src = layer.GetAttributeAtPath(spec.path) if layer else None
            if src and src.HasDefaultValue() and src.default.path == value.path:
                target = Sdf.ComputeAssetPathRelativeToLayer(layer, value.path)
                spec.default = Sdf.AssetPath(_relative(Path(target), out_dir))
                break


def _topology(topo_path: Path, layer_paths: list[str], input_stage) -> None:
    """Write the topology layer (module docstring) atomically."""

    _, args = file_format_args(topo_path)
    with atomic_output(topo_path) as tmp:
        tmp.unlink()
        topo = Sdf.Layer.CreateNew(str(tmp))
        if not UsdUtils.StitchClipsTopology(topo, layer_paths):
            raise UserError(f"{topo_path}: USD could not stitch the chunk topology")
        topo.subLayerPaths.clear()  # the chunks' input sublayer; the root sublayers the input itself
        _reanchor_assets(topo, [Sdf.Layer.FindOrOpen(p) for p in layer_paths], topo_path.parent)
        with Sdf.ChangeBlock():
            for prim in input_stage.Traverse():
                spec = topo.GetPrimAtPath(prim.GetPath())
                if not spec or not prim.HasAttribute(SH_DEGREE):
                    continue
                spec.typeName = prim.GetTypeName()
                deg = prim.GetAttribute(SH_DEGREE)
                if not topo.GetAttributeAtPath(deg.GetPath()):
                    a = Sdf.AttributeSpec(spec, SH_DEGREE, deg.GetTypeName(), Sdf.VariabilityUniform)
                    a.default = deg.Get()
                sh_spec = topo.GetAttributeAtPath(prim.GetPath().AppendProperty(SH_COEFFS))
                sh = prim.GetAttribute(SH_COEFFS)
                if sh_spec and sh:
                    for key in ("interpolation", "elementSize"):
                        if sh.HasMetadata(key):
                            sh_spec.SetInfo(key, sh.GetMetadata(key))
        topo.Save()


def _manifest(man_path: Path, layers, names, input_stage) -> int:
    """Write the clip manifest atomically; returns how many attributes got an unaffected default."""

    found = _sampled_attributes(layers)
    man = Sdf.Layer.CreateAnonymous("manifest" + man_path.suffix)
    filled = 0
    with Sdf.ChangeBlock():
        for path, (type_name, have) in sorted(found.items(), key=lambda kv: str(kv[0])):
            prim_spec = Sdf.CreatePrimInLayer(man, path.GetPrimPath())
            spec = Sdf.AttributeSpec(prim_spec, path.name, type_name)
            if len(have) < len(layers):
                missing = names[min(set(range(len(layers))) - have)]
                spec.default = _unaffected_value(input_stage, path, missing)
                filled += 1
    save_stage_atomic(man, man_path)
    return filled


def assemble(folder, output, entries: list[dict] | None = None, allow_gaps: bool = False) -> AssembleSummary:
    """Stitch the finished chunks of ``folder`` (or the given ``entries``, frame order) into
    ``output``; see the module docstring. Checks that the input has not changed since, and
    (:func:`collect_chunks`) that no chunk layer lacks its entry unless ``allow_gaps``."""

    entries = entries if entries is not None else collect_chunks(folder, allow_gaps=allow_gaps)
    out = Path(os.path.abspath(output))
    check_usd_output_path(str(out))
    input_path = entries[0]["input"]
    if not os.path.isfile(input_path):
        raise UserError(f"{input_path}: the chunks' input stage no longer exists")
    input_stage = open_stage(input_path)
    if input_hash(input_stage) != entries[0]["input_hash"]:
        raise UserError(f"{input_path}: the input changed after the chunks in {folder} were computed; re-run them")
    layer_paths = [e["path"] for e in entries]
    layers = [Sdf.Layer.FindOrOpen(p) for p in layer_paths]
    names = [Path(p).name for p in layer_paths]
    topo_path = topology_layer_path(out)
    man_path = out.with_name(out.stem + ".manifest.usdc")
    _topology(topo_path, layer_paths, input_stage)
    filled = _manifest(man_path, layers, names, input_stage)

    roots = sorted({spec.path for layer in layers for spec in layer.rootPrims})
    starts = [e["frames"][0] for e in entries]
    times = sorted({t for e in entries for t in (e["frames"][0], e["frames"][-1])})
    root = OutputLayer.create(input_path, out)
    root.layer.subLayerPaths.insert(0, topo_path.as_posix())
    with Sdf.ChangeBlock():
        for path in roots:
            spec = Sdf.CreatePrimInLayer(root.layer, path)
            spec.SetInfo("clips", {"default": {
                "assetPaths": Sdf.AssetPathArray([_relative(Path(p), out.parent) for p in layer_paths]),
                "primPath": str(path),
                "active": Vt.Vec2dArray([(float(s), float(k)) for k, s in enumerate(starts)]),
                "times": Vt.Vec2dArray([(float(t), float(t)) for t in times]),
                "manifestAssetPath": Sdf.AssetPath(_relative(man_path, out.parent)),
            }})
    exported = root.export_layer()
    exported.subLayerPaths = [_relative(topo_path, out.parent) if s == topo_path.as_posix() else s
                              for s in exported.subLayerPaths]
    save_stage_atomic(exported, out)
    check = Usd.Stage.Open(str(out))
    if not check:
        raise UserError(f"{out}: the stitched stage does not open")
    frames = [f for e in entries for f in e["frames"]]
    return AssembleSummary(str(out), str(topo_path), str(man_path), names, frames, filled)
