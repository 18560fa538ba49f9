#!/usr/bin/env python3
"""How far the unseen side's true colour is from the seen side's next to it (issue 22).

    python3 benches/unseen_rim_mean.py SCANTEX SCENE [SCENE...]

For a one-sided scene (`scantex sample --from-mesh ... --unseen-sector 200 --heldout 8`),
scores the fill an oracle would make if it knew the seen surface exactly and painted the
unseen side in the mean colour of the seen surface within a band of the rim: per held-out
view with at least 500 unseen pixels, the CIE76 ΔE between the truth's mean colour over the
unseen pixels and over the seen pixels at most 5, 20 and 40 pixels (8-neighbour steps) from
the rim (the object's pixels from the held-out masks), averaged with the unseen pixels as
weights, as `scantex eval` averages its unseen ΔE. Two truths: the held-out photographs (shaded, what `scantex eval` compares with) and
the true mesh rendered as flat albedo with `SCANTEX render`.

A method that continues the rim's colour scores about this; `scantex eval`'s unseen ΔE below
it means the fill follows how the colour changes away from the rim, above it that the fill
does worse than the rim's mean. Needs numpy and Pillow.
"""
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rim_profile import distance  # noqa: E402

BANDS = (5, 20, 40)


def lab(c):
    """sRGB in [0, 1] to CIELAB (D65), as src/eval.rs converts."""
    c = np.clip(c, 0.0, 1.0)
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    x = (0.4124 * lin[0] + 0.3576 * lin[1] + 0.1805 * lin[2]) / 0.95047
    y = 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]
    z = (0.0193 * lin[0] + 0.1192 * lin[1] + 0.9505 * lin[2]) / 1.08883

    def f(t):
        return np.cbrt(t) if t > 0.008856 else 7.787 * t + 16.0 / 116.0

    fx, fy, fz = f(x), f(y), f(z)
    return np.array([116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)])


def load(path):
    return np.asarray(Image.open(path).convert("RGB"), dtype=float) / 255.0


def scene_scores(scantex, scene, tmp):
    heldout = os.path.join(scene, "heldout")
    albedo_dir = os.path.join(tmp, os.path.basename(os.path.normpath(scene)))
    subprocess.run(
        [scantex, "render", heldout, "--mesh", os.path.join(scene, "truth", "model.glb"), "-o", albedo_dir],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    photos = {os.path.splitext(p)[0]: p for p in os.listdir(os.path.join(heldout, "images"))}
    sums = {(truth, band): 0.0 for truth in ("photo", "albedo") for band in BANDS}
    weight = 0
    for name in sorted(os.listdir(os.path.join(heldout, "unseen"))):
        stem = os.path.splitext(name)[0]
        unseen = np.asarray(Image.open(os.path.join(heldout, "unseen", name)).convert("L")) > 0
        if unseen.sum() < 500:
            continue
        albedo = load(os.path.join(albedo_dir, stem + ".png"))
        # The object's pixels from the held-out mask: black trim renders as black albedo.
        masks = [m for m in os.listdir(os.path.join(heldout, "masks")) if m.startswith(stem)]
        surface = np.asarray(Image.open(os.path.join(heldout, "masks", masks[0])).convert("L")) > 127
        dist = distance(~unseen)
        truths = {"photo": load(os.path.join(heldout, "images", photos[stem])), "albedo": albedo}
        n = int(unseen.sum())
        for truth, img in truths.items():
            inside = img[unseen].mean(0)
            for band in BANDS:
                near = surface & ~unseen & (dist <= band)
                sums[(truth, band)] += n * np.linalg.norm(lab(inside) - lab(img[near].mean(0)))
        weight += n
    return {k: v / max(weight, 1) for k, v in sums.items()}


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    scantex, scenes = sys.argv[1], sys.argv[2:]
    print("scene        truth   ΔE: seen band <= " + " / ".join(f"{b} px" for b in BANDS))
    with tempfile.TemporaryDirectory() as tmp:
        for scene in scenes:
            s = scene_scores(scantex, scene, tmp)
            for truth in ("photo", "albedo"):
                vals = " / ".join(f"{s[(truth, b)]:.2f}" for b in BANDS)
                print(f"{os.path.basename(os.path.normpath(scene)):12s} {truth:7s} {vals}")


if __name__ == "__main__":
    main()
