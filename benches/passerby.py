#!/usr/bin/env python3
"""What photo-consistency rejection is worth when something crosses the scene: the corset scene
of texture_compare.py with a "passer-by" (a dark red disc covering a third of the object's
height) painted into some of the training photographs, textured with each `--consistency`
rule and scored on the clean held-out views.

    pip install numpy pillow
    cargo build --release
    python3 benches/passerby.py            # prints a markdown table
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image, ImageDraw

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data")
BIN = os.path.join(ROOT, "target", "release", "scantex")


def run(args):
    r = subprocess.run([BIN] + args, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"scantex {' '.join(args)} failed:\n{r.stderr}")


def paint(scene, every):
    """Paints a disc over the object's middle in every `every`-th training photograph."""
    names = sorted(os.listdir(os.path.join(scene, "images")))
    painted = 0
    for k, name in enumerate(names):
        if k % every:
            continue
        mask_path = next(
            os.path.join(scene, "masks", c)
            for c in (name + ".png", os.path.splitext(name)[0] + ".png", name)
            if os.path.exists(os.path.join(scene, "masks", c))
        )
        m = np.asarray(Image.open(mask_path)) > 127
        ys, xs = np.nonzero(m)
        cy, cx = ys.mean(), xs.mean()
        r = 0.18 * (ys.max() - ys.min())
        im = Image.open(os.path.join(scene, "images", name)).convert("RGB")
        ImageDraw.Draw(im).ellipse((cx - r, cy - r, cx + r, cy + r), fill=(150, 20, 30))
        im.save(os.path.join(scene, "images", name), quality=97)
        painted += 1
    return painted, len(names)


def main():
    with tempfile.TemporaryDirectory() as tmp:
        scene = os.path.join(tmp, "corset")
        run(["sample", "--from-mesh", os.path.join(DATA, "scans", "corset", "Corset.gltf"),
             "--up", "y", "--photos", "24", "-o", scene])
        rows = []
        for every in (0, 8, 4):
            s = os.path.join(tmp, f"scene{every}")
            shutil.copytree(scene, s)
            painted, total = paint(s, every) if every else (0, 24)
            for rule in ("face", "vertex", "off"):
                out = os.path.join(tmp, "out")
                run(["texture", s, "-o", out, "-q", "--size", "2048", "--consistency", rule])
                js = os.path.join(tmp, "e.json")
                run(["eval", "--mesh", os.path.join(out, "model.obj"), os.path.join(s, "heldout"),
                     "--gain-fit", "--json", js])
                m = json.load(open(js))["mean"]
                rows.append((f"{painted} of {total}", rule, m))
                print(f"{painted}/{total} {rule}: {m['psnr']:.2f}", file=sys.stderr)
        print("| photographs with a passer-by | --consistency | PSNR dB | SSIM | 1 - NCC |")
        print("|---|---|---|---|---|")
        for p, rule, m in rows:
            print(f"| {p} | {rule} | {m['psnr']:.2f} | {m['ssim']:.4f} | {m['one_minus_ncc']:.4f} |")


if __name__ == "__main__":
    main()
