#!/usr/bin/env python3
"""Whether what lies under a mask's black reaches the texture: the bundled sample with its
photographs as PNGs, magenta in one copy and green in the other wherever the sample's masks
are black, each textured by every scantex binary given; prints, per binary and page side, how
many texels differ between the two copies (none: the backdrop does not reach the texture) and
the held-out scores of each (`scantex eval --gain-fit` on the sample's held-out views).

    pip install numpy pillow
    python3 benches/mask_backdrop.py WORKDIR BIN [BIN ...] [--sizes 1024,auto] [--sheet OUT.jpg]

With --sheet, the magenta copy's textures at the first size, first binary left and last
right, are written side by side (docs/images/mask_backdrop.jpg).
"""
import argparse
import os
import shutil
import subprocess

import numpy as np
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE = os.path.join(ROOT, "samples", "torus")


def variant(work, name, colour):
    """The sample in work/name with `colour` under its masks' black, PNG photographs."""
    dst = os.path.join(work, name)
    if os.path.exists(dst):
        shutil.rmtree(dst)
    shutil.copytree(SAMPLE, dst)
    images = os.path.join(dst, "sparse", "0", "images.txt")
    with open(images) as f:
        text = f.read()
    with open(images, "w") as f:
        f.write(text.replace(".jpg", ".png"))
    for f in sorted(os.listdir(os.path.join(SAMPLE, "images"))):
        stem = os.path.splitext(f)[0]
        rgb = np.array(Image.open(os.path.join(SAMPLE, "images", f)).convert("RGB"))
        mask = np.array(Image.open(os.path.join(SAMPLE, "masks", stem + ".png")).convert("L"))
        rgb[mask < 128] = colour
        os.remove(os.path.join(dst, "images", f))
        Image.fromarray(rgb).save(os.path.join(dst, "images", stem + ".png"))
    return dst


def held_out(binary, out):
    r = subprocess.run(
        [binary, "eval", os.path.join(SAMPLE, "heldout"), "--mesh",
         os.path.join(out, "model.obj"), "--gain-fit"],
        check=True, capture_output=True, text=True)
    mean = [l for l in r.stdout.splitlines() if l.startswith("mean")][0].split()
    return float(mean[2]), float(mean[4])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("work")
    ap.add_argument("binaries", nargs="+")
    ap.add_argument("--sizes", default="1024,auto")
    ap.add_argument("--sheet")
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    scenes = {"magenta": variant(a.work, "magenta", (255, 0, 255)),
              "green": variant(a.work, "green", (0, 255, 0))}
    print("| binary | --size | texels differing | max difference | held-out PSNR / 1-NCC, magenta | green |")
    print("| --- | --- | --- | --- | --- | --- |")
    for bi, binary in enumerate(a.binaries):
        for size in a.sizes.split(","):
            outs, scores = {}, {}
            for name, scene in scenes.items():
                out = os.path.join(a.work, f"out_{bi}_{size}_{name}")
                subprocess.run([binary, "texture", scene, "-o", out, "-q", "--size", size],
                               check=True, capture_output=True)
                outs[name] = np.array(Image.open(os.path.join(out, "model.png"))).astype(int)
                scores[name] = held_out(binary, out)
            d = np.abs(outs["magenta"] - outs["green"]).max(axis=2)
            m, g = scores["magenta"], scores["green"]
            print(f"| {binary} | {size} | {int((d > 0).sum()):,} of {d.size:,} | {d.max()} "
                  f"| {m[0]:.2f} / {m[1]:.4f} | {g[0]:.2f} / {g[1]:.4f} |")
    if a.sheet:
        size = a.sizes.split(",")[0]
        tex = [Image.open(os.path.join(a.work, f"out_{bi}_{size}_magenta", "model.png"))
               for bi in (0, len(a.binaries) - 1)]
        sheet = Image.new("RGB", (tex[0].width + tex[1].width, max(t.height for t in tex)))
        sheet.paste(tex[0].convert("RGB"), (0, 0))
        sheet.paste(tex[1].convert("RGB"), (tex[0].width, 0))
        sheet.save(a.sheet, quality=90)


if __name__ == "__main__":
    main()
