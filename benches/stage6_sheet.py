#!/usr/bin/env python3
"""Contact sheet of stage 6 on a one-sided scene (issue 22): per held-out view, truth |
vertex-colour fill | restoration alone | stage 6, the unseen region outlined in cyan.

Usage: python3 benches/stage6_sheet.py SCENE OUT.png [SCANTEX_BINARY] [--views N]

SCENE is made by `scantex sample --from-mesh ... --unseen-sector 200 --heldout 8`. Each fill is
textured and rendered from the held-out cameras; each render gets one gain per channel,
least squares against the truth over the pixels some input photograph saw (as `scantex eval
--gain-fit` does), so that exposure does not hide the fill's colour. The N views (default 2)
with the most unseen pixels are shown. Needs numpy and Pillow.
"""
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

FILLS = [
    ("vertex", ["--exemplar", "off", "--min-depth", "inf"]),
    ("restore", ["--exemplar", "off", "--min-depth", "inf", "--max-hole", "0"]),
    ("stage6", []),
]


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--views")]
    views_n = 2
    for a in sys.argv[1:]:
        if a.startswith("--views"):
            views_n = int(a.split("=", 1)[1]) if "=" in a else views_n
    if len(args) < 2:
        sys.exit(__doc__)
    scene, out = args[0], args[1]
    binary = args[2] if len(args) > 2 else "target/release/scantex"
    held = os.path.join(scene, "heldout")
    unseen_dir = os.path.join(held, "unseen")
    names = sorted(os.listdir(unseen_dir))
    counts = {n: int((np.array(Image.open(os.path.join(unseen_dir, n))) > 0).sum()) for n in names}
    views = sorted(names, key=lambda n: -counts[n])[:views_n]
    images = os.path.join(held, "images")
    truth_of = {os.path.splitext(f)[0]: os.path.join(images, f) for f in os.listdir(images)}
    with tempfile.TemporaryDirectory() as tmp:
        renders = {}
        for name, extra in FILLS:
            d = os.path.join(tmp, name)
            subprocess.run([binary, "texture", scene, "-o", d, "-q", *extra], check=True)
            subprocess.run(
                [binary, "render", held, "--mesh", os.path.join(d, "model.obj"), "-o",
                 os.path.join(d, "render")],
                check=True, stdout=subprocess.DEVNULL)
            renders[name] = os.path.join(d, "render")
        rows = []
        for v in views:
            stem = os.path.splitext(v)[0]
            truth = np.array(Image.open(truth_of[stem]).convert("RGB")).astype(float)
            unseen = np.array(Image.open(os.path.join(unseen_dir, v))) > 0
            edge = (unseen ^ np.roll(unseen, 1, 0)) | (unseen ^ np.roll(unseen, 1, 1))
            tiles = [truth]
            for name, _ in FILLS:
                r = np.array(Image.open(os.path.join(renders[name], stem + ".png"))
                             .convert("RGB")).astype(float)
                covered = r.sum(2) > 0
                seen = covered & ~unseen
                gain = [(truth[..., c][seen] * r[..., c][seen]).sum()
                        / max((r[..., c][seen] ** 2).sum(), 1e-9) for c in range(3)]
                g = np.clip(r * np.array(gain), 0, 255)
                g[~covered] = truth[~covered]
                tiles.append(g)
            # The object: where the vertex fill's render covers, and the unseen pixels.
            vertex = np.array(Image.open(os.path.join(renders["vertex"], stem + ".png")))
            ys, xs = np.nonzero((vertex[..., :3].sum(2) > 0) | unseen)
            pad = 16
            y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad, truth.shape[0])
            x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad, truth.shape[1])
            row = []
            for t in tiles:
                t = t.copy()
                t[edge] = [0, 230, 255]
                row.append(t[y0:y1, x0:x1])
            rows.append(np.concatenate(row, 1))
        width = max(r.shape[1] for r in rows)
        rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
        Image.fromarray(np.concatenate(rows, 0).astype(np.uint8)).save(out)
    print(f"wrote {out}: views {', '.join(views)}; columns truth | "
          + " | ".join(n for n, _ in FILLS))


if __name__ == "__main__":
    main()
