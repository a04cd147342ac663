"""Moving prims merged per cell for the other prims' probes: ``numba_kernels.gaussian_merge`` against
its numpy reference and hand-computed mixtures, its hard cases, and the main job's use of it
(``usd_gs.relight.probe_merge``; the bikers' speed and error figures are in docs/benchmarks.md)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from farm_compare import stage_differences

import numba_kernels.gaussian_merge as gm
from numba_kernels.reference import gaussian_merge as ref
from usd_gs.cli import main
from usd_gs.relight.probe_merge import MergedPrim, merge_capacity, merged_distance
from usd_gs.synthetic import random_gaussians


def _cov(quats, scales) -> np.ndarray:
    r = ref._rotations(quats)
    return np.einsum("nij,nj,nkj->nik", r, np.asarray(scales, np.float64) ** 2, r)


def _set(n, degree, seed, spread, offset=0.0):
    g = random_gaussians(n, degree, seed=seed)
    g.positions[:] = (g.positions * np.float32(spread / 5.0) + np.float32(offset)).astype(np.float32)
    g.scales[:] = np.minimum(g.scales, np.float32(0.02))
    g.log_scales = g.logit_opacities = None  # (the raw fields no longer match)
    return g


@pytest.mark.parametrize("n, degree, seed, spread, offset, cell", [
    (3000, 0, 1, 0.3, 0.0, 0.03),
    (5000, 3, 2, 1.0, 0.0, 0.05),
    (2000, 1, 3, 0.2, 1.0e4, 0.03),  # far from the origin: members summed about the cell's first one
    (400, 2, 4, 0.05, -3.0, 0.5),  # one cell
])
def test_kernel_matches_the_numpy_reference(n, degree, seed, spread, offset, cell):
    g = _set(n, degree, seed, spread, offset)
    g.opacities[: n // 10] = 0.0  # some transparent members
    labels, pos, quat, scales, opac, sh = gm.merge_cells(g.positions, g.orientations, g.scales, g.opacities, g.sh,
                                                         cell)
    r_labels, r_mu, r_cov, r_opac, r_sh = ref.merge_cells(g.positions, g.orientations, g.scales, g.opacities, g.sh,
                                                          cell)
    assert np.array_equal(labels, r_labels)
    assert np.abs(pos - r_mu).max() <= 1e-6 * max(1.0, abs(offset)) + 1e-7
    cov = _cov(quat, scales)
    assert np.abs(cov - r_cov).max() <= 1e-5 * np.abs(r_cov).max(axis=(1, 2)).max()
    assert np.abs(np.linalg.norm(quat, axis=1) - 1.0).max() < 1e-6 and (quat[:, 0] >= 0.0).all()
    assert np.allclose(opac, r_opac, rtol=1e-5, atol=1e-7)
    assert np.abs(sh - r_sh).max() <= 1e-5 * max(1.0, np.abs(r_sh).max())


def test_two_gaussians_merge_into_their_mixture():
    """Two isotropic Gaussians (sigma 1 cm, opacity 0.5) 2 cm either side of a point along x: centre
    the point, covariance sigma^2 + d^2 along x and sigma^2 across, opacity 2 x 0.5 x sigma^2 over
    the merged area (s_x s_y + s_y s_z + s_x s_z) / 3; SH the weights' mean."""
    s, d = 0.01, 0.02
    pos = np.array([[0.5 - d, 0.5, 0.5], [0.5 + d, 0.5, 0.5]], np.float32)
    quat = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], np.float32)  # (a turn of an isotropic Gaussian changes nothing)
    scales = np.full((2, 3), s, np.float32)
    sh = np.array([[[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]], np.float32)
    labels, p, q, sc, op, out_sh = gm.merge_cells(pos, quat, scales, np.array([0.5, 0.5], np.float32), sh, 1.0)
    assert labels.tolist() == [0, 0]
    assert np.allclose(p[0], [0.5, 0.5, 0.5], atol=1e-7)
    assert np.allclose(np.sort(sc[0].astype(np.float64) ** 2), np.sort([s * s + d * d, s * s, s * s]), rtol=1e-5)
    sx, sy = math.sqrt(s * s + d * d), s
    assert op[0] == pytest.approx(min(1.0, 2 * 0.5 * s * s / ((sx * sy + sy * sy + sx * sy) / 3.0)), rel=1e-5)
    assert np.allclose(out_sh[0, 0], [0.5, 0.5, 0.0], atol=1e-7)


def test_a_gaussian_alone_in_its_cell_is_itself():
    g = _set(50, 2, 7, 50.0)  # 10 m apart on average: every cell holds one
    labels, p, q, sc, op, sh = gm.merge_cells(g.positions, g.orientations, g.scales, g.opacities, g.sh, 0.01)
    assert len(np.unique(labels)) == 50
    order = np.argsort(labels)
    assert np.array_equal(p, g.positions[order])
    assert np.abs(_cov(q, sc) - _cov(g.orientations[order], g.scales[order])).max() < 1e-6 * float(g.scales.max()) ** 2
    assert np.allclose(op, g.opacities[order], rtol=1e-5)
    assert np.allclose(sh, g.sh[order], atol=1e-7)


def test_hard_cases_stay_finite():
    n = 600
    g = _set(n, 1, 5, 0.05)
    g.opacities[:] = 0.0  # every member transparent: plain means, opacity 0
    g.scales[:200] = np.float32(1e-30)  # tiny sigmas (covariance below float32's normal range)
    g.scales[200:400] = np.float32(5.0)  # huge ones: opacity x area spread over a larger merged area
    g.opacities[300:] = 1.0
    g.orientations[:50] = 0.0  # a zero quaternion: the identity
    out = gm.merge_cells(g.positions, g.orientations, g.scales, g.opacities, g.sh, 0.02)
    for a in out[1:]:
        assert np.isfinite(a).all()
    assert (out[3] > 0).all() and (out[4] >= 0).all() and (out[4] <= 1).all()
    only_transparent = np.bincount(out[0], g.opacities > 0) == 0
    assert (out[4][only_transparent] == 0).all()


@pytest.mark.parametrize("a", [np.diag([4.0, 4.0, 4.0]), np.diag([1.0, 1.0, 1e-12]), np.diag([3.0, 1.0, 2.0]),
                               np.array([[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 1e-8]]),
                               np.array([[1.0, 1 - 1e-9, 0.0], [1 - 1e-9, 1.0, 0.0], [0.0, 0.0, 1.0]])])
def test_jacobi_eigen_decomposition_of_hard_matrices(a):
    """Equal, tiny and nearly equal eigenvalues: V diag(l) V^T gives the matrix back, V a rotation."""
    v = np.empty((3, 3))
    lam = np.array(gm._jacobi3(a.copy(), v))
    assert np.abs(v @ np.diag(lam) @ v.T - a).max() <= 1e-12 * np.abs(a).max()
    assert np.allclose(v.T @ v, np.eye(3), atol=1e-12) and np.linalg.det(v) == pytest.approx(1.0)
    assert np.allclose(np.sort(lam), np.linalg.eigvalsh(a), atol=1e-12 * np.abs(a).max())


def test_sorted_grouping_of_a_sparse_grid_matches_the_counted_one(monkeypatch):
    g = _set(2000, 1, 6, 0.15)  # a 0.3 m cube of 1 cm cells: 27,000 cells, under DENSE_CELLS
    counted = []
    plain = gm._counting_groups
    monkeypatch.setattr(gm, "_counting_groups", lambda *a: counted.append(1) or plain(*a))
    dense = gm.merge_cells(g.positions, g.orientations, g.scales, g.opacities, g.sh, 0.01)
    assert counted == [1]
    monkeypatch.setattr(gm, "DENSE_CELLS", 0)  # and 27,000 > 8 N cells: the sort
    sparse = gm.merge_cells(g.positions, g.orientations, g.scales, g.opacities, g.sh, 0.01)
    assert counted == [1] and len(np.unique(dense[0])) > 1000
    for a, b in zip(dense, sparse, strict=True):
        assert np.array_equal(a, b)


def test_bad_cell_and_empty_set():
    g = _set(10, 0, 1, 1.0)
    for cell in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="cell"):
            gm.merge_cells(g.positions, g.orientations, g.scales, g.opacities, g.sh, cell)
    e = random_gaussians(0, 2)
    out = gm.merge_cells(e.positions, e.orientations, e.scales, e.opacities, e.sh, 0.03)
    assert [a.shape[0] for a in out] == [0] * 6 and out[5].shape == (0, 9, 3)


def test_merged_distance_is_one_texel_and_far_clusters_use_it():
    """A 3 cm cell at merged_distance subtends one texel of a 32-texel face (pi/2 / 32 rad)."""
    d = merged_distance(0.03, 32, 1)
    assert 0.03 / d == pytest.approx(math.pi / 2 / 32)
    assert merged_distance(0.03, 32, 2) == pytest.approx(2 * d)
    g = _set(2000, 0, 3, 0.3, offset=2.0)
    m = MergedPrim.of(g, 0.03)
    centre = np.array([2.0, 2.0, 1.0])
    far = m.far_clusters(centre, 1.0)
    assert np.array_equal(far, np.linalg.norm(m.centres - centre, axis=1) >= 1.0) and far.any() and not far.all()


def _two_avatar_shot(path: Path, second_spread: float = 0.12) -> Path:
    """tiny_shot's room and lamp with two dense moving avatars 1.5 m apart (each 4,000 Gaussians in a
    12 cm ball: a few hundred 3 cm cells, far enough from the other's probe to draw merged; the
    second spread over ``second_spread`` metres instead)."""
    from pxr import Gf, Usd, UsdGeom

    from usd_gs.usd.gaussian_prim import save_stage_atomic, write_gaussian_prim

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from hardening_util import tiny_shot

    tiny_shot(path, n_scene=3000, n_avatar=4000, frames=3)
    stage = Usd.Stage.Open(str(path))
    stage.RemovePrim("/World/Avatar")  # (written again below, without tiny_shot's raw fields)
    for name, seed, x, spread in (("/World/Avatar", 11, -0.75, 0.12), ("/World/Second", 12, 0.75, second_spread)):
        g = _set(4000, 1, seed, spread)
        g.positions[:, 1] += np.float32(1.0)
        g.opacities[:] = np.maximum(g.opacities, np.float32(0.3))
        write_gaussian_prim(stage, name, g)
        xf = UsdGeom.Xformable(stage.GetPrimAtPath(name))
        xf.ClearXformOpOrder()
        op = xf.AddTranslateOp()
        for f in (1, 2, 3):
            op.Set(Gf.Vec3d(x, 0, 0.05 * f), Usd.TimeCode(f))
    save_stage_atomic(stage, path)
    return path


def test_main_job_draws_the_other_avatar_merged_in_each_probe(tmp_path, monkeypatch):
    """Each avatar's probe draws the other one merged (its clusters selected, its Gaussians not):
    the shadows are those of the run that draws every Gaussian (probe_merge_cell 0), the relit
    colours stay within 2/255 of its (0.25/255 on average over the output's SH), and one thread
    gives the output of two."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_far_field import dc_difference

    import usd_gs.pipeline.shot as shot

    drawn = []
    plain = shot.ShotProcessor._merged_mask

    def spy(self, mask, path, centre, spans):
        plain(self, mask, path, centre, spans)
        if not self.opts.probe_merge_cell:
            return
        other = "/World/Second" if path == "/World/Avatar" else "/World/Avatar"
        a, b = spans[other]
        slot = self._buffer[3][other][0]
        drawn.append((int(mask[a:b].sum()), int(mask[slot:slot + self._merged[other].count].sum())))

    monkeypatch.setattr(shot.ShotProcessor, "_merged_mask", spy)
    s = _two_avatar_shot(tmp_path / "shot.usda")
    argv = ["process", str(s), "--avatar", "/World/Avatar", "--avatar", "/World/Second", "--aovs", "transmittance",
            "-q"]
    cfg = tmp_path / "off.json"
    cfg.write_text(json.dumps({"probe_merge_cell": 0}))
    assert main([*argv, "-o", str(tmp_path / "merged.usdc")]) == 0
    assert len(drawn) == 6 and all(full == 0 and 0 < merged < 1000 for full, merged in drawn), drawn
    assert main([*argv, "-o", str(tmp_path / "every.usdc"), "--config", str(cfg)]) == 0
    diffs = stage_differences(tmp_path / "every.usdc", tmp_path / "merged.usdc", [1, 2, 3])
    assert diffs and all("Avatar" in d or "Second" in d for d in diffs), diffs  # (the room's values are equal)
    d = dc_difference(tmp_path / "every.usdc", tmp_path / "merged.usdc")
    assert 0.0 < d.max() <= 2.0 / 255 and d.mean() <= 0.25 / 255, (d.max() * 255, d.mean() * 255)
    # the merges run in whichever probe task needs them first: one thread gives the same output
    import numba

    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        assert main([*argv, "-o", str(tmp_path / "one.usdc")]) == 0
    finally:
        numba.set_num_threads(before)
    assert stage_differences(tmp_path / "merged.usdc", tmp_path / "one.usdc", [1, 2, 3]) == []


def test_probe_merge_cell_out_of_range_exits_2(tmp_path, capsys):
    cfg = tmp_path / "bad.json"
    cfg.write_text(json.dumps({"probe_merge_cell": -0.5}))
    assert main(["process", str(tmp_path / "missing.usda"), "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "probe_merge_cell" in err and "-0.5" in err


def test_a_prim_that_merges_into_more_clusters_than_its_rows_is_drawn_as_it_is(tmp_path, monkeypatch):
    """The second avatar spread over 2 m: nearly every Gaussian in a cell of its own, more clusters
    than its merge_capacity rows (a quarter of its count): the first avatar's probe draws every one
    of its Gaussians, while the second's probe still draws the first merged."""
    import usd_gs.pipeline.shot as shot

    drawn = {}
    plain = shot.ShotProcessor._merged_mask

    def spy(self, mask, path, centre, spans):
        plain(self, mask, path, centre, spans)
        other = "/World/Second" if path == "/World/Avatar" else "/World/Avatar"
        a, b = spans[other]
        slot, room = self._buffer[3][other]
        drawn.setdefault(path, []).append((int(mask[a:b].sum()), int(mask[slot:slot + room].sum()), b - a, room))

    monkeypatch.setattr(shot.ShotProcessor, "_merged_mask", spy)
    s = _two_avatar_shot(tmp_path / "shot.usda", second_spread=2.0)
    assert main(["process", str(s), "--avatar", "/World/Avatar", "--avatar", "/World/Second", "-q", "-o",
                 str(tmp_path / "o.usdc")]) == 0
    assert all(full == n and merged == 0 and room == merge_capacity(n)
               for full, merged, n, room in drawn["/World/Avatar"]), drawn
    assert all(full == 0 and merged > 0 for full, merged, _, _ in drawn["/World/Second"]), drawn
