#!/usr/bin/env python3
"""Brightness against the truth by distance from the unseen rim, in held-out views (issue 22).

    python3 benches/rim_profile.py SCANTEX SCENE MESH [--truth TRUTH_MESH]

Renders MESH (a textured output) and the scene's true mesh (SCENE/truth/model.glb unless
--truth is given) as flat albedo through every held-out camera of SCENE/heldout with
`SCANTEX render`, then, over the held-out views with at least 500 unseen pixels
(SCENE/heldout/unseen/), bands the pixels by their distance in pixels (8-neighbour steps)
from the rim between the surface the inputs saw and the surface they did not, and prints
per band the mean rendered and true colour and their ratio per channel. The rendered colours
first take the per-channel gain that fits them to the truth over the seen pixels, as
`scantex eval --gain-fit` does.

A ratio below 1 near the rim on the seen side says the photographs' colours there (seen at
grazing angles) came out too dark; the unseen side inherits whatever its rim holds.
Needs numpy and Pillow.
"""
import argparse
import os
import subprocess
import tempfile

import numpy as np
from PIL import Image

BANDS = [
    ("seen, over 40 px", "seen", 40, None),
    ("seen, 21-40 px", "seen", 20, 40),
    ("seen, 6-20 px", "seen", 5, 20),
    ("seen, 0-5 px", "seen", None, 5),
    ("unseen, 0-5 px", "unseen", None, 5),
    ("unseen, 6-20 px", "unseen", 5, 20),
    ("unseen, over 20 px", "unseen", 20, None),
]
MAX_DIST = 41


def distance(region):
    """Steps (8-neighbour) from each pixel of `region` to the nearest pixel outside it,
    counted up to MAX_DIST."""
    d = np.full(region.shape, MAX_DIST, dtype=np.int32)
    outside = ~region
    d[outside] = 0
    reach = outside.copy()
    for step in range(1, MAX_DIST):
        grown = reach.copy()
        grown[1:, :] |= reach[:-1, :]
        grown[:-1, :] |= reach[1:, :]
        grown[:, 1:] |= reach[:, :-1]
        grown[:, :-1] |= reach[:, 1:]
        grown[1:, 1:] |= reach[:-1, :-1]
        grown[:-1, :-1] |= reach[1:, 1:]
        grown[1:, :-1] |= reach[:-1, 1:]
        grown[:-1, 1:] |= reach[1:, :-1]
        new = grown & ~reach
        d[new] = step
        reach = grown
    return d


def render(scantex, heldout, mesh, out):
    subprocess.run(
        [scantex, "render", heldout, "--mesh", mesh, "-o", out],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scantex")
    ap.add_argument("scene")
    ap.add_argument("mesh")
    ap.add_argument("--truth")
    a = ap.parse_args()
    heldout = os.path.join(a.scene, "heldout")
    truth = a.truth or os.path.join(a.scene, "truth", "model.glb")
    acc = {name: [np.zeros(3), np.zeros(3), 0] for name, *_ in BANDS}
    with tempfile.TemporaryDirectory() as tmp:
        out_dir, truth_dir = os.path.join(tmp, "out"), os.path.join(tmp, "truth")
        render(a.scantex, heldout, a.mesh, out_dir)
        render(a.scantex, heldout, truth, truth_dir)
        for name in sorted(os.listdir(os.path.join(heldout, "unseen"))):
            stem = os.path.splitext(name)[0]
            load = lambda d: np.asarray(
                Image.open(os.path.join(d, stem + ".png")).convert("RGB"), dtype=float
            )
            out, true = load(out_dir), load(truth_dir)
            unseen = np.asarray(Image.open(os.path.join(heldout, "unseen", name)).convert("L")) > 0
            if unseen.sum() < 500:
                continue
            surface = (out.sum(2) > 0) & (true.sum(2) > 0)
            seen = surface & ~unseen
            gain = np.array(
                [(true[..., k][seen] * out[..., k][seen]).sum() / (out[..., k][seen] ** 2).sum() for k in range(3)]
            )
            dist = {"seen": distance(~unseen), "unseen": distance(unseen)}
            side = {"seen": seen, "unseen": surface & unseen}
            for band, which, lo, hi in BANDS:
                d = dist[which]
                sel = side[which].copy()
                if lo is not None:
                    sel &= d > lo
                if hi is not None:
                    sel &= d <= hi
                acc[band][0] += (out[sel] * gain).sum(0)
                acc[band][1] += true[sel].sum(0)
                acc[band][2] += int(sel.sum())
    print(f"{'band':20s} {'pixels':>8s}  {'rendered':>17s}  {'true':>17s}  ratio")
    for band, (o, t, n) in acc.items():
        if n == 0:
            continue
        fmt = lambda v: " ".join(f"{x:5.1f}" for x in v)
        ratio = " ".join(f"{x:.3f}" for x in o / np.maximum(t, 1e-9))
        print(f"{band:20s} {n:8d}  {fmt(o / n)}  {fmt(t / n)}  {ratio}")


if __name__ == "__main__":
    main()
