"""Farm runs: resume after SIGKILL, stale chunks (options, input), mixed chunks refused,
``usdgs lights`` + per-task ``usdgs process`` + ``usdgs assemble``."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import time

import pytest
from farm_compare import stage_differences
from package_process import child_env, python
from pxr import Sdf

from usd_gs.cli import main
from usd_gs.farm.chunks import Chunk, plan_chunks

FRAMES = [1.0, 2.0, 3.0, 4.0]


def test_plan_and_names():
    chunks = plan_chunks([1.0, 2.0, 3.0, 5.0, 7.5], 2)
    assert [c.frames for c in chunks] == [(1.0, 2.0), (3.0, 5.0), (7.5,)]
    assert [c.name for c in chunks] == ["chunk_0001_0002", "chunk_0003_0005", "chunk_0007p5_0007p5"]
    assert chunks[1].label == "frames 3-5" and Chunk(0, (-2.0,)).name == "chunk_m0002_m0002"
    assert chunks[1].frames_spec() == "3.0,5.0"


@pytest.fixture(scope="module")
def copied(quick_demo, tmp_path_factory):
    """A private copy of the quick demo (these tests change the input) and its single run."""
    d = tmp_path_factory.mktemp("resume")
    shutil.copytree(quick_demo.parent, d / "stages")
    stage = d / "stages" / quick_demo.name
    single = d / "single.usdc"
    assert main(["process", str(stage), "-o", str(single), "--frames", "1-4", "-q"]) == 0
    return stage, single


def _run(args, **kw):
    return subprocess.Popen(python("-m", "usd_gs.cli", *args), env=child_env(NUMBA_NUM_THREADS="1"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def test_sigkill_then_resume(copied, tmp_path):
    stage, single = copied
    clips = tmp_path / "clips"
    out = tmp_path / "out.usdc"
    args = ["process", str(stage), "-o", str(out), "--frames", "1-4", "--chunk-size", "1", "--clips-dir", str(clips),
            "--json"]
    proc = _run(args)
    deadline = time.time() + 120
    while not (clips / "chunk_0001_0001.json").exists():
        assert proc.poll() is None and time.time() < deadline, proc.stderr.read() if proc.poll() else "timeout"
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not out.exists()
    finished = sorted(p.stem for p in clips.glob("chunk_*.json"))
    assert finished and len(finished) < 4
    # every visible file is complete: each layer opens, each finished chunk's bytes match its entry
    for layer in clips.glob("chunk_*.usdc"):
        assert Sdf.Layer.OpenAsAnonymous(str(layer)) is not None
    for name in finished:
        entry = json.loads((clips / f"{name}.json").read_text())
        assert entry["frames"] and (clips / entry["layer"]).is_file()
    # a killed write leaves at most hidden temp files; fake one more, and a truncated chunk layer
    (clips / ".chunk_0004_0004.x1y2.tmp.usdc").write_bytes(b"PXR-USDC partial")
    (clips / "chunk_0004_0004.usdc").write_bytes(b"PXR-USDC truncated")
    proc = _run(args)
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 0, stderr
    summary = json.loads(stdout)
    assert sorted(summary["chunks"]["skipped"]) == finished
    assert sorted(summary["chunks"]["computed"] + finished) == [f"chunk_000{i}_000{i}" for i in range(1, 5)]
    assert not list(clips.glob(".chunk_*"))
    assert stage_differences(single, out, FRAMES) == []


def test_stale_chunks_are_recomputed(copied, tmp_path, capsys):
    stage, _ = copied
    clips = tmp_path / "clips"
    base = ["process", str(stage), "-o", str(tmp_path / "o.usdc"), "--frames", "1-2", "--chunk-size", "1",
            "--clips-dir", str(clips), "--json"]

    def run(*extra):
        capsys.readouterr()
        assert main(base + list(extra)) == 0
        return json.loads(capsys.readouterr().out)["chunks"]

    assert len(run()["computed"]) == 2
    assert run()["skipped"] == ["chunk_0001_0001", "chunk_0002_0002"]
    c = run("--direct-fraction", "0.5")  # other options: nothing reused
    assert len(c["computed"]) == 2 and c["skipped"] == [] and len(c["removed_stale"]) == 2
    # another chunk size over the same frames replaces the overlapping chunks
    c = run("--direct-fraction", "0.5", "--chunk-size", "2")
    assert c["computed"] == ["chunk_0001_0002"] and sorted(c["removed_stale"]) == ["chunk_0001_0001",
                                                                                  "chunk_0002_0002"]
    # a changed input layer (one more byte in a referenced layer) invalidates everything
    assert run("--direct-fraction", "0.5", "--chunk-size", "2")["skipped"] == ["chunk_0001_0002"]
    with open(stage, "a", encoding="utf-8") as fh:
        fh.write("\n")
    try:
        assert run("--direct-fraction", "0.5", "--chunk-size", "2")["computed"] == ["chunk_0001_0002"]
    finally:
        stage.write_text(stage.read_text()[:-1])


def test_lights_tasks_assemble(copied, tmp_path, capsys):
    """The farm recipe: lights once, one process per task, assemble; mixing is refused."""
    stage, _ = copied
    lights = tmp_path / "lights.usda"
    assert main(["lights", str(stage), "-o", str(lights), "--frames", "1-4", "-q"]) == 0
    clips = tmp_path / "clips"
    for frames in ("1-2", "3-4"):  # what two farm tasks run
        assert main(["process", str(lights), "--lights", "stage", "--frames", frames, "--chunk-size", "2",
                     "--clips-dir", str(clips), "-o", str(tmp_path / f"task{frames}.usdc"), "-q"]) == 0
    assert sorted(p.name for p in clips.glob("*.json")) == ["chunk_0001_0002.json", "chunk_0003_0004.json"]
    single = tmp_path / "single.usdc"
    assert main(["process", str(lights), "--lights", "stage", "--frames", "1-4", "-o", str(single), "-q"]) == 0
    out = tmp_path / "assembled.usdc"
    assert main(["assemble", str(clips), "-o", str(out), "-q"]) == 0
    assert stage_differences(single, out, FRAMES) == []
    # a chunk of other options in the same folder: refused, not mixed
    other = tmp_path / "other"
    assert main(["process", str(lights), "--lights", "stage", "--frames", "5", "--chunk-size", "1",
                 "--direct-fraction", "0.5", "--clips-dir", str(other), "-o", str(tmp_path / "t5.usdc"), "-q"]) == 0
    for p in other.iterdir():
        (shutil.copytree if p.is_dir() else shutil.copy)(p, clips / p.name)
    capsys.readouterr()
    assert main(["assemble", str(clips), "-o", str(tmp_path / "mixed.usdc")]) == 2
    assert "chunks of 2 different runs" in capsys.readouterr().err
    assert not (tmp_path / "mixed.usdc").exists()
