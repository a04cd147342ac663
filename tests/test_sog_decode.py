"""SOG decode paths against straightforward references, bit for bit: libwebp through ctypes
against Pillow's decoder, and the vectorised quaternion / scale / SH decode against the
formulas of the format (usd_gs/io/sog.py module docstring) written the plain way."""

from __future__ import annotations

import io
import json
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

from usd_gs.gaussians import scales_from_log
from usd_gs.io import sog, sog_files

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SOGS = sorted(DATA.rglob("*.sog"))[:12] if DATA.is_dir() else []
needs_data = pytest.mark.skipif(not SOGS, reason=f"shared SOG captures not found under {DATA}")


def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as zf:
        return {n: zf.read(n) for n in zf.namelist()}


def _pillow(data: bytes) -> np.ndarray:
    from PIL import Image

    with Image.open(io.BytesIO(data)) as im:
        return np.asarray(im.convert("RGBA")).reshape(-1, 4)


@needs_data
def test_libwebp_and_pillow_decode_the_same_pixels():
    if sog_files.libwebp() is None:
        pytest.skip("libwebp not found beside Pillow nor on the system: the Pillow path is the only one")
    n = 0
    for path in SOGS[:6]:
        for name, data in _members(path).items():
            if name.endswith(".webp"):
                px, w, h = sog._decode_webp(str(path), name, data, 0)
                ref = _pillow(data)
                assert px.shape == (w * h, 4) and np.array_equal(px, ref), f"{path}:{name}"
                n += 1
    assert n >= 30


@pytest.mark.parametrize("mode", ["RGB", "RGBA"])
def test_webp_without_alpha_decodes_opaque(mode):
    from PIL import Image

    rgb = np.random.default_rng(1).integers(0, 256, (37, 53, 3), dtype=np.uint8)
    arr = rgb if mode == "RGB" else np.dstack([rgb, rgb[..., :1]])
    buf = io.BytesIO()
    Image.fromarray(arr, mode).save(buf, "WEBP", lossless=True, exact=True)
    px, w, h = sog._decode_webp("x", "y.webp", buf.getvalue(), 0)
    assert (w, h) == (53, 37)
    assert np.array_equal(px[:, :3], rgb.reshape(-1, 3))
    alpha = np.full(w * h, 255, np.uint8) if mode == "RGB" else rgb[..., 0].reshape(-1)
    assert np.array_equal(px[:, 3], alpha)


def _reference_quats(qpx: np.ndarray) -> np.ndarray:
    """The docstring's rule: r, g, b are (b/255*2 - 1)/sqrt(2) of the three smaller components in
    (w, x, y, z) order, alpha 252 + index of the largest (rebuilt positive); float64, normalised."""
    out = np.empty((len(qpx), 4), np.float32)
    for i, (r, g, b, a) in enumerate(qpx.astype(np.int64)):
        small = [(v / 255.0 * 2.0 - 1.0) / np.sqrt(2.0) for v in (r, g, b)]
        s2 = small[0] * small[0] + small[1] * small[1] + small[2] * small[2]
        big = np.sqrt(max(0.0, 1.0 - s2))
        q = small[:]
        q.insert(int(a) - 252, big)
        out[i] = np.asarray(q) * (1.0 / np.sqrt(s2 + big * big))
    return out


@needs_data
def test_decode_matches_the_plain_formulas():
    path = max(SOGS[:12], key=lambda p: p.stat().st_size)
    members = _members(path)
    prefix = min((n for n in members if n.endswith("meta.json")), key=len)[: -len("meta.json")]
    g = sog.read_sog(path)
    src = sog_files.SogSource(str(path), archive=zipfile.ZipFile(path), prefix=prefix.rstrip("/"))
    plan = sog._Plan(src)
    raw = plan.load()
    n = plan.count
    rng = np.random.default_rng(0)
    idx = np.concatenate([np.arange(min(n, 200)), rng.integers(0, n, 800)])
    qpx = sog._decode_webp("x", "quats", raw["quats"], n)[0][:n]
    ref = _reference_quats(qpx[idx])
    assert np.array_equal(g.orientations[idx].view(np.uint32), ref.view(np.uint32))
    # scales: exp of the log-scale codebook entry, bit for bit what scales_from_log gives
    assert np.array_equal(g.scales.view(np.uint32), scales_from_log(g.log_scales).view(np.uint32))
    spx = sog._decode_webp("x", "scales", raw["scales"], n)[0][:n]
    assert np.array_equal(g.log_scales, plan.scb[spx[:, :3]])
    # SH: DC from the sh0 codebook, bands from the palette entry of each label
    c0 = sog._decode_webp("x", "sh0", raw["sh0"], n)[0][:n]
    assert np.array_equal(g.sh[:, 0, :], plan.ccb[c0[:, :3]])
    assert np.array_equal(g.opacities, c0[:, 3].astype(np.float32) / np.float32(255.0))
    if plan.bands:
        rest = sog._SH_REST[plan.bands]
        cen = sog._decode_webp("x", "centroids", raw["centroids"], 0)[0]
        lab = sog._decode_webp("x", "labels", raw["labels"], n)[0][:n]
        for i in idx[:100]:
            label = int(lab[i, 0]) | int(lab[i, 1]) << 8
            row, col = divmod(label, 64)
            for j in range(rest):
                pix = cen[row * 64 * rest + col * rest + j]
                assert np.array_equal(g.sh[i, j + 1], plan.hcb[pix[:3]]), (i, j)
        assert not g.sh[:, rest + 1:].any()


@needs_data
def test_open_sog_counts_before_decoding():
    lod = DATA / "scenes" / "flowers" / "lod-meta.json"
    opened = sog.open_sog(lod, lod=1)
    g = opened.decode()
    assert (opened.count, opened.sh_degree) == (g.count, g.sh_degree)
    small = SOGS[0]
    opened = sog.open_sog(small)
    assert opened.count == sog.read_sog(small).count


def test_vt_backed_pool_hands_out_preallocated_arrays():
    from usd_gs.usd.bulk import VtBackedPool

    pool = VtBackedPool([(50_000, 3), (50_000, 3), (50_000,)])
    a, b, c = pool((50_000, 3)), pool((50_000, 3)), pool((50_000,))
    assert a is not b and a.shape == (50_000, 3) and c.shape == (50_000,)
    assert all(hasattr(x.base, "_usdgs_vt_array") or hasattr(x.base.base, "_usdgs_vt_array") for x in (a, b, c))
    extra = pool((50_000, 3))  # used up: plain zeros
    assert extra.shape == (50_000, 3) and not extra.any() and not hasattr(extra.base, "_usdgs_vt_array")


@needs_data
def test_cli_import_of_a_lod_set_equals_the_serial_write(tmp_path):
    """The threaded, Vt-backed import writes the same stage as reading then writing plainly."""
    from pxr import Usd

    from usd_gs.cli import main
    from usd_gs.usd.gaussian_prim import new_stage, save_stage_atomic, write_gaussian_prim

    lod = DATA / "scenes" / "flowers" / "lod-meta.json"
    assert main(["import", str(lod), "--lod", "2", "-o", str(tmp_path / "cli.usdc"), "-q"]) == 0
    stage = new_stage(default_prim="flowers")
    write_gaussian_prim(stage, "/flowers", sog.read_sog(lod, lod=2))
    save_stage_atomic(stage, tmp_path / "plain.usdc")
    stages = [Usd.Stage.Open(str(tmp_path / n)) for n in ("cli.usdc", "plain.usdc")]
    a, b = (st.GetPrimAtPath("/flowers") for st in stages)
    names = [x.GetName() for x in b.GetAuthoredAttributes()]
    assert names == [x.GetName() for x in a.GetAuthoredAttributes()] and len(names) >= 7
    for name in names:
        va, vb = a.GetAttribute(name).Get(), b.GetAttribute(name).Get()
        if hasattr(vb, "__len__") and not isinstance(vb, str):
            assert np.asarray(va).tobytes() == np.asarray(vb).tobytes(), name
        else:
            assert va == vb, name


def _same_set(a, b) -> bool:
    fields = ("positions", "orientations", "scales", "opacities", "sh", "log_scales")
    return all(np.asarray(getattr(a, f)).tobytes() == np.asarray(getattr(b, f)).tobytes() for f in fields)


@needs_data
def test_row_blocks_decode_what_one_pass_decodes(monkeypatch):
    """The decode in blocks of rows (sog._BLOCK) against one block of everything, bit for bit, on
    units larger than a block (SH palette included)."""
    lod = DATA / "scenes" / "flowers" / "lod-meta.json"
    paths = [(lod, 1), (max(SOGS, key=lambda p: p.stat().st_size), None)]
    blocked = [sog.read_sog(p, lod=level) for p, level in paths]
    assert all(g.count > 2 * sog._BLOCK for g in blocked) and blocked[0].sh_degree > 0
    monkeypatch.setattr(sog, "_BLOCK", 1 << 30)
    for (p, level), g in zip(paths, blocked, strict=True):
        assert _same_set(g, sog.read_sog(p, lod=level)), p


@needs_data
def test_bad_label_in_a_later_block_names_its_pixel(tmp_path):
    import shutil

    from PIL import Image

    from usd_gs.errors import InputFormatError

    unit = tmp_path / "unit"
    shutil.copytree(DATA / "scenes" / "flowers" / "1_0", unit)
    meta = json.loads((unit / "meta.json").read_text())
    labels = unit / meta["shN"]["files"][1]
    assert meta["count"] > sog._BLOCK + 5000
    palette = meta["shN"]["count"] = meta["shN"]["count"] - 1  # the last entry is now past the end
    (unit / "meta.json").write_text(json.dumps(meta))
    with Image.open(labels) as im:
        w, h = im.size
        px = np.asarray(im.convert("RGBA")).reshape(-1, 4).copy()
    i = sog._BLOCK + 4321
    head = px[:i]
    head[(head[:, 0].astype(int) | head[:, 1].astype(int) << 8) >= palette, :2] = 0  # valid before pixel i
    px[i, :2] = (palette & 255, palette >> 8)
    Image.fromarray(px.reshape(h, w, 4), "RGBA").save(labels, "WEBP", lossless=True)
    with pytest.raises(InputFormatError, match=f"pixel {i} has label {palette}, past meta.json 'shN.count' {palette}"):
        sog.read_sog(unit / "meta.json")


@needs_data
@pytest.mark.parametrize("kind", ["lod set", "bundled", "folder"])
def test_prefetch_serves_the_images_and_gives_the_same_set(tmp_path, kind):
    if kind == "lod set":
        path, level = DATA / "scenes" / "flowers" / "lod-meta.json", 1
    elif kind == "bundled":
        path, level = SOGS[0], None
    else:
        path, level = tmp_path / "unit", None
        path.mkdir()
        for name, data in _members(SOGS[0]).items():
            (path / Path(name).name).write_bytes(data)
    pf = sog_files.SogPrefetch(str(path), level)
    g = sog.open_sog(path, level, prefetch=pf).decode()
    assert _same_set(g, sog.read_sog(path, lod=level))
    decoded = [v for v in pf._images.values() if v[1] is not None]
    units = sog.open_sog(path, level)._plans
    assert len(decoded) == sum(len(u.jobs) for u in units)  # every image the reader decodes


@pytest.mark.parametrize("damage", ["truncated zip", "missing image", "not webp", "no such file"])
def test_prefetch_never_raises_and_the_reader_names_the_problem(tmp_path, damage):
    from usd_gs.errors import InputFormatError
    from usd_gs.io.sog import write_sog
    from usd_gs.synthetic import random_gaussians

    folder = tmp_path / "f"
    folder.mkdir()
    write_sog(folder / "meta.json", random_gaussians(3000, 0, seed=2))
    zipped = tmp_path / "x.sog"
    write_sog(zipped, random_gaussians(3000, 0, seed=2))
    path = {"truncated zip": zipped, "no such file": tmp_path / "none.sog"}.get(damage, folder / "meta.json")
    if damage == "truncated zip":
        zipped.write_bytes(zipped.read_bytes()[: 5000])
    elif damage == "missing image":
        (folder / "quats.webp").unlink()
    elif damage == "not webp":
        (folder / "scales.webp").write_bytes(b"RIFF\0\0\0\0WEBPnot really")
    with pytest.raises(InputFormatError) as plain:
        sog.read_sog(path)
    pf = sog_files.SogPrefetch(str(path))
    with pytest.raises(InputFormatError) as fetched:
        sog.open_sog(path, prefetch=pf).decode()
    pf._thread.join(10)
    def message(exc):  # (without the addresses of the objects a Pillow message may show)
        return re.sub(r"0x[0-9a-f]+", "0x", str(exc.value))

    assert not pf._thread.is_alive() and message(fetched) == message(plain)


@needs_data
def test_manifest_size_is_what_the_reader_finds(tmp_path):
    lod = DATA / "scenes" / "flowers" / "lod-meta.json"
    for path, level in ((lod, 0), (lod, None), (lod, 2), (SOGS[0], None), (lod.parent / "1_0" / "meta.json", None)):
        opened = sog.open_sog(path, level)
        assert sog_files.manifest_size(str(path), level) == (opened.count, opened.sh_degree), (path, level)
    bad = tmp_path / "bad.sog"
    bad.write_bytes(b"PK\3\4 not a zip")
    assert sog_files.manifest_size(str(bad)) is None
    assert sog_files.manifest_size(str(lod), 7) is None  # no such level: the reader names it


def test_vt_backed_pool_uses_arrays_allocated_before_numpy_views():
    from pxr import Vt

    from usd_gs.usd.bulk import VtBackedPool, vt_from_numpy
    from usd_gs.usd.vt_alloc import new_vt_array

    made = [((40_000, 3), new_vt_array((40_000, 3))), ((40_000,), new_vt_array((40_000,))),
            ((40_000, 9, 3), new_vt_array((40_000, 9, 3))), ((5, 5), new_vt_array((5, 5)))]
    assert made[3][1] is None and len(made[2][1]) == 360_000
    pool = VtBackedPool()
    pool.fill([(40_000, 3), (40_000, 3), (40_000,), (40_000, 9, 3)], made[:3])
    a, b, c, d = pool((40_000, 3)), pool((40_000, 3)), pool((40_000,)), pool((40_000, 9, 3))
    assert vt_from_numpy(Vt.Vec3fArray, a) is made[0][1]  # the early array, no copy
    assert vt_from_numpy(Vt.Vec3fArray, b) is not made[0][1]  # the second (40000, 3): a fresh one
    assert vt_from_numpy(Vt.FloatArray, c) is made[1][1]
    d[7, 2] = (1.0, 2.0, 3.0)
    assert tuple(made[2][1][7 * 9 + 2]) == (1.0, 2.0, 3.0)


@needs_data
def test_decode_hands_every_units_rows_to_on_rows_and_their_extents_make_the_whole():
    from usd_gs.extent import ExtentOfParts

    lod = DATA / "scenes" / "flowers" / "lod-meta.json"
    seen, parts = [], ExtentOfParts(3.0)

    def on_rows(rows):
        seen.append(rows)
        parts.add(rows)

    g = sog.open_sog(lod, 1).decode(threads=2, on_rows=on_rows)
    assert len(seen) == len(sog.open_sog(lod, 1)._plans) > 1
    starts = sorted(int((r.positions.__array_interface__["data"][0] - g.positions.__array_interface__["data"][0])
                        // 12) for r in seen)
    counts = {int((r.positions.__array_interface__["data"][0] - g.positions.__array_interface__["data"][0]) // 12):
              r.count for r in seen}
    assert starts[0] == 0 and all(a + counts[a] == b for a, b in zip(starts, starts[1:] + [g.count], strict=True))
    for r in seen:
        for name in ("positions", "orientations", "scales", "opacities", "sh"):
            assert np.shares_memory(getattr(r, name), getattr(g, name)), name
    box = g.extent(3.0)
    assert np.array_equal(parts.box(g.count).view(np.uint32), box.view(np.uint32))
