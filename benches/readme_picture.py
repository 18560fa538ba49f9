#!/usr/bin/env python3
"""Makes the README's picture, docs/images/texture_sample.png: a held-out photograph of the
bundled sample beside the mesh textured with the defaults, rendered from the same camera.

    cargo build --release
    pip install numpy pillow
    python3 benches/readme_picture.py

The render gets one gain per channel fitted on the object (as `scantex eval --gain-fit`
does: the held-out photograph has its own exposure and white balance) and is laid over the
photograph's background. Prints the held-out PSNR of the run.
"""
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "scantex")
SCENE = os.path.join(ROOT, "samples", "torus")
VIEW = "heldout_01"


def run(args):
    r = subprocess.run([BIN] + args, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"scantex {' '.join(args)} failed:\n{r.stderr}")


def main():
    if not os.path.exists(BIN):
        sys.exit("build first: cargo build --release")
    with tempfile.TemporaryDirectory() as tmp:
        out, ren = os.path.join(tmp, "out"), os.path.join(tmp, "render")
        run(["texture", SCENE, "-q", "-o", out])
        mesh = os.path.join(out, "model.obj")
        run(["render", "--mesh", mesh, "-o", ren, os.path.join(SCENE, "heldout")])
        js = os.path.join(tmp, "eval.json")
        run(["eval", "--mesh", mesh, "--gain-fit", "--json", js, os.path.join(SCENE, "heldout")])
        with open(js) as f:
            print(f"held-out PSNR {json.load(f)['mean']['psnr']:.2f} dB")
        photo = np.asarray(Image.open(os.path.join(SCENE, "heldout", "images", VIEW + ".jpg"))
                           .convert("RGB"), dtype=np.float64)
        render = np.asarray(Image.open(os.path.join(ren, VIEW + ".png")).convert("RGB"),
                            dtype=np.float64)
        mask = np.asarray(Image.open(os.path.join(ren, "masks", VIEW + ".png")).convert("L")) > 127
    gain = (photo[mask] * render[mask]).sum(0) / np.maximum((render[mask] ** 2).sum(0), 1e-9)
    shown = photo.copy()
    shown[mask] = np.clip(render[mask] * gain, 0, 255)
    h, w, _ = photo.shape
    gap = 7
    sheet = np.full((h, 2 * w + gap, 3), 255, np.uint8)
    sheet[:, :w] = photo.astype(np.uint8)
    sheet[:, w + gap:] = shown.astype(np.uint8)
    path = os.path.join(ROOT, "docs", "images", "texture_sample.png")
    Image.fromarray(sheet).save(path)
    print(f"wrote {path} (gains {np.round(gain, 3).tolist()})")


if __name__ == "__main__":
    main()
