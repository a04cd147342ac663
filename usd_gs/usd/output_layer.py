"""The output layer: a new root layer over the input stage (shared/DESIGN.md section 2).

The output file holds only ``over``s of the input's prims plus new prims; its first
sublayer is the input (relative to the output's directory where possible), and it copies
the stage metadata that is read from the root layer only (``upAxis``, ``metersPerUnit``,
``defaultPrim``, ``timeCodesPerSecond``, ``framesPerSecond``, ``startTimeCode``,
``endTimeCode``, ``documentation``). The input file is never written.

Usage::

    with OutputLayer.create("scene.usd", "scene_relit.usd") as out:
        prim = out.stage.OverridePrim("/World/avatar")      # over
        write_gaussian_prim(out.stage, "/World/avatar", relit)  # authors into the output
    # saved atomically on success; nothing is written if the block raises
"""

from __future__ import annotations

import os
from pathlib import Path

from pxr import Sdf, Usd

from usd_gs.errors import InputFormatError, UserError
from usd_gs.usd.gaussian_prim import file_format_args, save_stage_atomic

_COPIED_FIELDS = ("upAxis", "metersPerUnit", "timeCodesPerSecond", "framesPerSecond", "startTimeCode",
                  "endTimeCode", "documentation")


def topology_layer_path(output) -> Path:
    """``<stem>.topology.usdc`` beside a chunked run's stitched output ``output`` (``usd_gs.farm.clips``)."""
    output = Path(output)
    return output.with_name(output.stem + ".topology.usdc")


def _same_file(a: Path, b: Path) -> bool:
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _relative_asset_path(target: Path, out_dir: Path) -> str:
    """``target`` relative to ``out_dir`` (``./x.usd`` or ``../x.usd``), absolute if impossible."""
    try:
        rel = Path(os.path.relpath(target, out_dir)).as_posix()
    except ValueError:  # different drives on Windows
        return target.as_posix()
    return rel if rel.startswith("../") else "./" + rel


class OutputLayer:
    """An in-memory root layer whose first sublayer is the input; see the module docstring.

    Attributes: ``input_path``/``output_path`` (absolute ``Path``), ``layer`` (the anonymous
    root ``Sdf.Layer``; in memory its sublayer path is absolute so composition does not
    depend on the working directory), ``stage`` (``Usd.Stage`` on ``layer``, edit target
    ``layer``). Asset paths authored into ``layer`` by callers should be absolute.
    """

    def __init__(self, input_path: Path, output_path: Path, layer: Sdf.Layer, stage: Usd.Stage):
        self.input_path = input_path
        self.output_path = output_path
        self.layer = layer
        self.stage = stage
        self.saved = False

    @classmethod
    def create(cls, input_path, output_path) -> OutputLayer:
        """New output layer over ``input_path`` that :meth:`save` writes to ``output_path``.

        Raises ``UserError`` when the input is missing/unreadable, the output has no
        ``.usd``/``.usdc``/``.usda`` extension, or the output is the input or any layer the
        input stage uses (it would overwrite an input).
        """
        inp = Path(os.path.abspath(os.fspath(input_path)))
        out = Path(os.path.abspath(os.fspath(output_path)))
        file_format_args(out)
        if not inp.is_file():
            raise UserError(f"{inp}: input file does not exist")
        if _same_file(inp, out):
            raise UserError(f"{out}: the output must not be the input file")
        try:
            in_layer = Sdf.Layer.FindOrOpen(str(inp))
        except Exception as exc:  # Tf.ErrorException on parse errors
            raise InputFormatError(f"{inp}: cannot be read as USD ({str(exc).strip().splitlines()[-1]})") from None
        if in_layer is None:
            raise InputFormatError(f"{inp}: cannot be read as USD")

        layer = Sdf.Layer.CreateAnonymous("usdgs-output" + out.suffix.lower())
        with Sdf.ChangeBlock():
            layer.subLayerPaths.append(inp.as_posix())
            src, dst = in_layer.pseudoRoot, layer.pseudoRoot
            for key in _COPIED_FIELDS:
                if src.HasInfo(key):
                    dst.SetInfo(key, src.GetInfo(key))
            if in_layer.HasDefaultPrim():
                layer.defaultPrim = in_layer.defaultPrim
        stage = Usd.Stage.Open(layer)
        stage.SetEditTarget(Usd.EditTarget(layer))
        for used in stage.GetUsedLayers():
            real = used.realPath
            if real and _same_file(Path(real), out):
                raise UserError(f"{out}: the output is a layer used by the input stage ({used.identifier}); "
                                "choose another output path")
        return cls(inp, out, layer, stage)

    def export_layer(self) -> Sdf.Layer:
        """A copy of the root layer as it will be written (sublayer made relative)."""
        copy = Sdf.Layer.CreateAnonymous("usdgs-export" + self.output_path.suffix.lower())
        copy.TransferContent(self.layer)  # shares array storage, no bulk copy
        subs = list(copy.subLayerPaths)
        subs = [_relative_asset_path(self.input_path, self.output_path.parent) if s == self.input_path.as_posix()
                else s for s in subs]
        copy.subLayerPaths = subs
        return copy

    def save(self, _export=None) -> Path:
        """Write the output atomically (temp file in the output directory + ``os.replace``).

        The input file is never touched; a failure leaves no partial output and keeps an
        existing output file intact. Returns the output path. (``_export`` is a test hook.)
        """
        if _same_file(self.input_path, self.output_path):
            raise UserError(f"{self.output_path}: the output must not be the input file")
        path = save_stage_atomic(self.export_layer(), self.output_path, _export=_export)
        self.saved = True
        return path

    def __enter__(self) -> OutputLayer:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.save()
        return False
