"""The outdoor demo shot: the estimated sun, the avatars' new shadow against the capture's own, the relit avatars.

    .venv/bin/usdgs demo make --outdoor -o /tmp/od/outdoor.usda
    .venv/bin/usdgs process /tmp/od/outdoor.usda -o /tmp/od/o2.lit.usdc --frames 1-3 --aovs transmittance,lightScale
    .venv/bin/python benchmarks/bench_outdoor_shot.py /tmp/od/outdoor.usda /tmp/od/o2.lit.usdc --frame 2

Reads the estimated ``/UsdGs/Lights/Sun`` of the output and measures, at one frame, in median
display luminance (Rec.709 weights on the sRGB-encoded DC colours):

- the pavement (``/World/Seal`` Gaussians within 6 cm of y = 0 with a horizontal smallest axis):
  lit (the sun's transmittance through the capture's own casters > 0.9, the predicted shadow
  of the estimate) and in the capture's own shadow (< 0.1), before processing;
- the avatars' new shadow: pavement Gaussians that were lit and whose written
  ``primvars:usdgs:transmittance`` is < 0.2 (the avatars block the sun there), after
  processing; its ratio to the capture's own shadow is the figure (1 = as dark);
- each relit avatar's sun side and shade side: its Gaussians whose outward normal
  (``numba_kernels.normals.gaussian_normals``) faces the sun (``n.s > 0.3``) or away
  (``n.s < -0.3``), output colours, against the lit and shadowed pavement.
"""

from __future__ import annotations

import argparse

import numpy as np

SH_C0 = 0.28209479177387814
LUMA = np.array([0.2126, 0.7152, 0.0722])


def display_lum(sh_dc: np.ndarray) -> np.ndarray:
    return np.clip(0.5 + SH_C0 * np.asarray(sh_dc, np.float64), 0.0, 1.0) @ LUMA


def main() -> None:
    from pxr import Usd, UsdGeom

    from numba_kernels.normals import gaussian_normals
    from numba_kernels.sun_shadow import transmittance_directions
    from usd_gs.relight import sun_estimation as se
    from usd_gs.shadows.dgsm import DGSMConfig, prepare_occluders
    from usd_gs.usd.gaussian_prim import read_gaussian_prim

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--frame", type=float, default=1.0)
    args = ap.parse_args()
    src = Usd.Stage.Open(args.input)
    out = Usd.Stage.Open(args.output)
    sun = out.GetPrimAtPath("/UsdGs/Lights/Sun")
    if not sun:
        raise SystemExit(f"{args.output}: no /UsdGs/Lights/Sun (no confident sun was estimated)")
    m = np.array(UsdGeom.Xformable(sun).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    s = m[2, :3] / np.linalg.norm(m[2, :3])  # towards the sun: the light's +Z
    el, az = se.elevation_azimuth(s, "Y")
    score = sun.GetCustomDataByKey("usdgs:score")
    share = sun.GetCustomDataByKey("usdgs:directShare")
    print(f"sun: towards ({s[0]:.3f}, {s[1]:.3f}, {s[2]:.3f}), elevation {el:.1f} deg, azimuth {az:.1f} deg, "
          f"score {score:.2f}, display darkening of a full shadow {share:.2f}")
    t = Usd.TimeCode(args.frame)
    seal_in = read_gaussian_prim(src.GetPrimAtPath("/World/Seal"), t)
    seal_out = read_gaussian_prim(out.GetPrimAtPath("/World/Seal"), t)
    up = np.array([0.0, 1.0, 0.0])
    p = seal_in.positions.astype(np.float64)
    flat = np.abs(se.smallest_axes(seal_in) @ up) >= 0.85
    ground = np.flatnonzero(flat & (np.abs(p[:, 1]) < 0.06) & (seal_in.opacities > 0.3))
    casters = np.flatnonzero((p[:, 1] > 0.06) & (seal_in.opacities > 1 / 255))
    occ, dep, cov6 = prepare_occluders(seal_in.subset(casters), DGSMConfig())
    t_own = transmittance_directions(-s[None], occ, dep, cov6, p[ground], 3.0, 0.02)[:, 0]
    y_in = display_lum(seal_in.sh[ground, 0])
    y_out = display_lum(seal_out.sh[ground, 0])
    attr = out.GetPrimAtPath("/World/Seal").GetAttribute("primvars:usdgs:transmittance")
    tr = np.asarray(attr.Get(t) if attr and attr.HasAuthoredValue() else np.ones(seal_in.count), np.float64)[ground]
    lit, own = t_own > 0.9, t_own < 0.1
    new = lit & (tr < 0.2)
    y_lit, y_own = float(np.median(y_in[lit])), float(np.median(y_in[own]))
    print(f"pavement: {ground.size} Gaussians, lit {int(lit.sum())} median {y_lit:.3f}, the capture's own shadow "
          f"{int(own.sum())} median {y_own:.3f} (own/lit {y_own / y_lit:.2f})")
    if new.any():
        y_new = float(np.median(y_out[new]))
        k = float(np.median(y_out[new] / y_in[new]))
        print(f"avatars' new shadow on lit pavement: {int(new.sum())} Gaussians, median {y_new:.3f} (the same "
              f"Gaussians before: {np.median(y_in[new]):.3f}, median output/input {k:.2f}); new / own shadow "
              f"{y_new / y_own:.2f}, new / lit {y_new / y_lit:.2f}; output/input against own/lit: "
              f"{k / (y_own / y_lit):.2f}")
    else:
        print("avatars' new shadow on lit pavement: none at this frame")
    for path in ("/World/Biker", "/World/CesiumMan"):
        gi = read_gaussian_prim(src.GetPrimAtPath(path), t)
        go = read_gaussian_prim(out.GetPrimAtPath(path), t)
        n = gaussian_normals(gi.positions, gi.orientations, gi.scales, gi.opacities)
        ns = n @ s
        yo = display_lum(go.sh[:, 0])
        yi = display_lum(gi.sh[:, 0])
        sunny, shade = ns > 0.3, ns < -0.3
        print(f"{path}: sun side {int(sunny.sum())} median {np.median(yo[sunny]):.3f} (input "
              f"{np.median(yi[sunny]):.3f}), shade side {int(shade.sum())} median {np.median(yo[shade]):.3f} (input "
              f"{np.median(yi[shade]):.3f}); sun side / lit pavement {np.median(yo[sunny]) / y_lit:.2f}, shade side "
              f"/ shadowed pavement {np.median(yo[shade]) / y_own:.2f}")


if __name__ == "__main__":
    main()
