"""SOG decode paths against straightforward references, bit for bit: libwebp through ctypes
against Pillow's decoder, and the vectorised quaternion / scale / SH decode against the
formulas of the format (usd_gs/io/sog.py module docstring) written the plain way."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest

from usd_gs.gaussians import scales_from_log
from usd_gs.io import sog

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
    if sog._libwebp() is None:
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
    src = sog._Source(str(path), archive=zipfile.ZipFile(path), prefix=prefix.rstrip("/"))
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
