#!/usr/bin/env python3
"""Tone and detail of a texture beside and inside the surface no input photograph saw (issue
22): per held-out view, truth / (gain x render) per channel on the seen pixels within 12
pixels of the unseen region and on the unseen pixels (1 = the right brightness; above 1 = too
dark), and the detail ratio (RMS of luma minus its Gaussian blur, sigma 1.5, output over
truth, as `scantex eval` measures it) on the seen pixels (4 in from their border) and on the
unseen ones (2 in). Gains are fitted per channel on the seen pixels, least squares.

Usage: python3 benches/unseen_tone.py SCENE TEXTURED_MESH [SCANTEX_BINARY] [--views 1,8]

SCENE is made by `scantex sample --from-mesh ... --unseen-sector 200 --heldout 8` (or
`--object jar`); TEXTURED_MESH is `model.obj` of `scantex texture SCENE -o out`. Renders it
from the held-out cameras with `scantex render`. Needs numpy and Pillow.
"""
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image


def grow(m, steps):
    m = m.copy()
    for _ in range(steps):
        n = m.copy()
        n[1:] |= m[:-1]
        n[:-1] |= m[1:]
        n[:, 1:] |= m[:, :-1]
        n[:, :-1] |= m[:, 1:]
        m = n
    return m


def shrink(m, steps):
    return ~grow(~m, steps)


def blur(a, sigma=1.5):
    r = int(3 * sigma)
    k = np.exp(-np.arange(-r, r + 1) ** 2 / (2 * sigma * sigma))
    k /= k.sum()
    a = np.apply_along_axis(lambda v: np.convolve(v, k, "same"), 0, a)
    return np.apply_along_axis(lambda v: np.convolve(v, k, "same"), 1, a)


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--views")]
    views = [1, 8]
    for i, a in enumerate(sys.argv):
        if a.startswith("--views"):
            v = a.split("=", 1)[1] if "=" in a else sys.argv[i + 1]
            views = [int(x) for x in v.split(",")]
            if "=" not in a:
                args.remove(v)
    if len(args) < 2:
        sys.exit(__doc__)
    scene, mesh = args[0], args[1]
    binary = args[2] if len(args) > 2 else "target/release/scantex"
    with tempfile.TemporaryDirectory() as out:
        subprocess.run(
            [binary, "render", os.path.join(scene, "heldout"), "--mesh", mesh, "--out", out],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        luma = np.array([0.299, 0.587, 0.114])
        for v in views:
            name = f"heldout_{v:02d}"
            r = np.asarray(Image.open(f"{out}/{name}.png").convert("RGB")) / 255.0
            t = np.asarray(Image.open(f"{scene}/heldout/images/{name}.jpg").convert("RGB")) / 255.0
            unseen = np.asarray(Image.open(f"{scene}/heldout/unseen/{name}.png")) > 127
            cov = np.asarray(Image.open(f"{out}/masks/{name}.png")) > 0
            obj = np.asarray(Image.open(f"{scene}/heldout/masks/{name}.png")) > 127
            seen = cov & obj & ~unseen
            un = cov & unseen
            near = grow(unseen, 12) & seen
            g = np.array([(t[..., c][seen] * r[..., c][seen]).sum() / (r[..., c][seen] ** 2).sum()
                          for c in range(3)])
            rg = r * g

            def tone(m):
                return " ".join(f"{x:.3f}" for x in t[m].mean(0) / rg[m].mean(0))

            lt, lr = t @ luma, rg @ luma
            dt, dr = lt - blur(lt), lr - blur(lr)

            def detail(m):
                return np.sqrt((dr[m] ** 2).mean() / (dt[m] ** 2).mean()) if m.any() else float("nan")

            print(f"{name}: truth/(gain x render) seen beside the unseen [{tone(near)}], "
                  f"unseen [{tone(un)}]; detail seen {detail(shrink(seen, 4)):.3f}, "
                  f"unseen {detail(shrink(un, 2)):.3f}")


if __name__ == "__main__":
    main()
