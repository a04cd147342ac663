"""The farm run's shared shot cache (usd_gs.pipeline.shot_cache): exact round trip, files of
another run or broken files ignored, merging writers, and chunks that read it writing what the
single run writes."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from farm_compare import stage_differences
from pxr import Sdf

from usd_gs.cli import main
from usd_gs.farm.chunks import clean_folder, plan_chunks, shot_cache_path
from usd_gs.farm.run import run_farm
from usd_gs.pipeline.shot import ProcessOptions
from usd_gs.pipeline.shot_cache import ShotCache


def _arrays(seed: int):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(17, 3)).astype(np.float32), rng.integers(0, 9, 17), rng.normal(size=3))


def test_round_trip_is_exact_and_counts(tmp_path):
    path = tmp_path / "c.npz"
    a = ShotCache(path, "k1")
    assert a.get("normals", "/World/Biker") is None
    vals = _arrays(0)
    a.put(("normals", "/World/Biker"), vals)
    a.put(("calibrated", 0.5, -1.25, 2.0), (vals[2],))
    a.put(("normals", "/World/Biker"), _arrays(1))  # the first value stays
    assert a.computed == 2 and a.loaded == 0
    assert a.save() and not a.save()  # nothing new: no second write
    b = ShotCache(path, "k1")
    got = b.get("normals", "/World/Biker")
    assert len(got) == 3
    for x, y in zip(got, vals, strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y)
    assert np.array_equal(b.get("calibrated", 0.5, -1.25, 2.0)[0], vals[2])
    assert b.get("calibrated", 0.5, -1.25, 2.0000001) is None
    assert b.loaded == 2 and b.computed == 0 and b.problem is None
    # another run's key: nothing from the file
    c = ShotCache(path, "k2")
    assert c.get("normals", "/World/Biker") is None and c.problem is None


def test_writers_merge(tmp_path):
    path = tmp_path / "c.npz"
    a, b = ShotCache(path, "k"), ShotCache(path, "k")  # two chunks started side by side
    a.put(("normals", "/A"), _arrays(2))
    b.put(("normals", "/B"), _arrays(3))
    assert a.save() and b.save()
    c = ShotCache(path, "k")
    assert np.array_equal(c.get("normals", "/A")[0], _arrays(2)[0])
    assert np.array_equal(c.get("normals", "/B")[0], _arrays(3)[0])
    # b's copy of /A came from the file: it counts as loaded
    assert np.array_equal(b.get("normals", "/A")[1], _arrays(2)[1]) and b.loaded == 1


def test_threads_put_once(tmp_path):
    cache = ShotCache(tmp_path / "c.npz", "k")
    threads = [threading.Thread(target=cache.put, args=(("samples", "/A", 4096), _arrays(i))) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert cache.computed == 1


@pytest.mark.parametrize("content", [b"", b"not a zip file at all", None])
def test_broken_file_is_ignored_and_replaced(tmp_path, content):
    path = tmp_path / "c.npz"
    if content is None:  # a zip without the index member
        np.savez(path, other=np.zeros(3))
    else:
        path.write_bytes(content)
    cache = ShotCache(path, "k")
    assert cache.get("normals", "/A") is None
    assert cache.problem is not None and str(path) in cache.problem and "computed again" in cache.problem
    cache.put(("normals", "/A"), _arrays(4))
    assert cache.save()
    again = ShotCache(path, "k")
    assert again.problem is None and np.array_equal(again.get("normals", "/A")[0], _arrays(4)[0])


def test_clean_folder_removes_other_runs_caches(tmp_path):
    mine = shot_cache_path(tmp_path, "o1", "i1")
    other = shot_cache_path(tmp_path, "o2", "i1")
    for p in (mine, other):
        p.write_bytes(b"x")
    (tmp_path / "notes.npz").write_bytes(b"x")  # not a name this module makes: left alone
    clean_folder(tmp_path, plan_chunks([1.0, 2.0], 1), set(), "o1", "i1")
    assert mine.exists() and not other.exists() and (tmp_path / "notes.npz").exists()
    assert mine.name.startswith("shot_cache_") and mine != other


@pytest.fixture(scope="module")
def single(quick_demo, tmp_path_factory):
    d = tmp_path_factory.mktemp("cache_single")
    out = d / "single.usdc"
    assert main(["process", str(quick_demo), "-o", str(out), "--frames", "1-3", "-q"]) == 0
    return out


def test_chunks_reading_the_cache_write_the_single_runs_values(quick_demo, single, tmp_path):
    """Chunk 1 computes the anchor-frame values and writes the cache, chunks 2 and 3 read every
    one of them back: the stitched output equals the whole-shot run, value for value."""
    clips = tmp_path / "clips"
    s = run_farm(str(quick_demo), str(tmp_path / "out.usdc"), ProcessOptions(frames="1-3"), 1, str(clips))
    stats = {r.name: r.shot_cache for r in s.results}
    first = stats["chunk_0001_0001"]
    assert first["loaded"] == 0 and first["computed"] > 0
    for name in ("chunk_0002_0002", "chunk_0003_0003"):
        assert stats[name]["loaded"] >= first["computed"] and stats[name]["computed"] == 0
    assert len(list(clips.glob("shot_cache_*.npz"))) == 1
    assert stage_differences(single, tmp_path / "out.usdc", [1.0, 2.0, 3.0]) == []


def test_broken_cache_file_warns_and_changes_nothing(quick_demo, single, tmp_path):
    """A cache file cut short on disk: the chunks compute everything again (a warning names the
    file), replace it, and the values stay the single run's."""
    clips = tmp_path / "clips"
    s = run_farm(str(quick_demo), str(tmp_path / "a.usdc"), ProcessOptions(frames="1-3"), 3, str(clips))
    cache = next(clips.glob("shot_cache_*.npz"))
    cache.write_bytes(cache.read_bytes()[:1000])
    for p in clips.glob("chunk_*.json"):
        p.unlink()  # the chunk is recomputed
    s = run_farm(str(quick_demo), str(tmp_path / "b.usdc"), ProcessOptions(frames="1-3"), 3, str(clips))
    (res,) = s.results
    assert res.shot_cache["loaded"] == 0 and res.shot_cache["computed"] > 0
    assert any(str(cache) in w and "unreadable shot cache" in w for w in res.warnings)
    # the run's summary carries the chunks' warnings (what `usdgs process --chunk-size` prints)
    assert [w for w in s.as_dict()["warnings"] if "unreadable shot cache" in w] == [
        w for w in res.warnings if "unreadable shot cache" in w]
    assert ShotCache(cache, "ignored").problem is None  # rewritten whole
    assert stage_differences(single, tmp_path / "b.usdc", [1.0, 2.0, 3.0]) == []
    assert Sdf.Layer.FindOrOpen(str(tmp_path / "b.usdc")) is not None
