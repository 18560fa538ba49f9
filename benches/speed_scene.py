#!/usr/bin/env python3
"""Builds the speed scene of docs/benchmarks.md: the corset subdivided to ~1.2M triangles,
photographed by 50 cameras at 4000x3000 (12 MP), then times `scantex texture` into an 8192
atlas against decoding the 50 JPEGs once.

    pip install numpy pillow trimesh
    cargo build --release
    python3 benches/speed_scene.py [workdir]      # default workdir: a temporary directory

The photographs are `scantex sample` renders at 800x600 upscaled five times (bicubic) with the
cameras' intrinsics scaled to match: the geometry is exact and the files have the size, JPEG
cost and decode cost of real 12 MP photographs (sensor-like noise added: about 5 MB each),
which is what the timing needs.
"""
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import trimesh
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data")
# SCANTEX_BIN runs another build (a copy, so that rebuilding during a long run is safe).
BIN = os.environ.get("SCANTEX_BIN", os.path.join(ROOT, "target", "release", "scantex"))
SCALE = 5
PHOTOS = 50


def subdivided_corset(path):
    m = trimesh.load(os.path.join(DATA, "scans", "corset", "Corset.gltf"), force="mesh", process=False)
    m.merge_vertices()
    v, f = m.vertices, m.faces
    while len(f) < 1_000_000:
        v, f = trimesh.remesh.subdivide(v, f)
    trimesh.Trimesh(v, f, process=False).export(path)
    return len(f)


def scale_scene(src, dst):
    rng = np.random.default_rng(1)
    os.makedirs(os.path.join(dst, "images"), exist_ok=True)
    os.makedirs(os.path.join(dst, "masks"), exist_ok=True)
    os.makedirs(os.path.join(dst, "sparse", "0"), exist_ok=True)
    sp = os.path.join(src, "sparse", "0")
    with open(os.path.join(sp, "cameras.txt")) as f, open(os.path.join(dst, "sparse", "0", "cameras.txt"), "w") as g:
        for line in f:
            if line.startswith("#") or not line.strip():
                g.write(line)
                continue
            p = line.split()
            # SIMPLE_RADIAL: f cx cy k; the radial term is in normalised coordinates.
            w, h = int(p[2]) * SCALE, int(p[3]) * SCALE
            fx, cx, cy, k = (float(x) for x in p[4:8])
            g.write(f"{p[0]} {p[1]} {w} {h} {fx * SCALE} {cx * SCALE} {cy * SCALE} {k}\n")
    with open(os.path.join(sp, "images.txt")) as f, open(os.path.join(dst, "sparse", "0", "images.txt"), "w") as g:
        data = 0
        for line in f:
            if line.startswith("#"):
                g.write(line)
                continue
            data += 1
            if data % 2 == 1:
                g.write(line)
                continue
            # Observations: scale X and Y, keep the point ids.
            p = line.split()
            for j in range(0, len(p), 3):
                p[j] = repr(float(p[j]) * SCALE)
                p[j + 1] = repr(float(p[j + 1]) * SCALE)
            g.write(" ".join(p) + "\n")
    with open(os.path.join(sp, "points3D.txt")) as f, open(os.path.join(dst, "sparse", "0", "points3D.txt"), "w") as g:
        g.write(f.read())
    for name in sorted(os.listdir(os.path.join(src, "images"))):
        im = Image.open(os.path.join(src, "images", name))
        big = np.asarray(im.resize((im.width * SCALE, im.height * SCALE), Image.BICUBIC), dtype=np.float32)
        # Sensor-like noise so that the files have a real photograph's size and decode cost
        # (an upscaled render alone compresses to 0.3 MB and decodes 3x faster).
        big += rng.normal(0.0, 4.0, big.shape).astype(np.float32)
        Image.fromarray(np.clip(big, 0, 255).astype(np.uint8)).save(os.path.join(dst, "images", name), quality=92)
        for cand in (name + ".png", os.path.splitext(name)[0] + ".png", name):
            mp = os.path.join(src, "masks", cand)
            if os.path.exists(mp):
                mk = Image.open(mp)
                mk.resize((mk.width * SCALE, mk.height * SCALE), Image.NEAREST).save(os.path.join(dst, "masks", cand))
                break


def main():
    work = sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp()
    small = os.path.join(work, "corset50_small")
    scene = os.path.join(work, "corset50_12mp")
    if not os.path.exists(os.path.join(scene, "mesh.ply")):
        subprocess.run([BIN, "sample", "--from-mesh", os.path.join(DATA, "scans", "corset", "Corset.gltf"),
                        "--up", "y", "--photos", str(PHOTOS), "-o", small], check=True, capture_output=True)
        scale_scene(small, scene)
        faces = subdivided_corset(os.path.join(scene, "mesh.ply"))
        print(f"scene: {faces} triangles, {PHOTOS} photographs {800 * SCALE}x{600 * SCALE}", file=sys.stderr)
    # The floor: decoding every photograph once (PIL's libjpeg-turbo, one core).
    t = time.time()
    for name in sorted(os.listdir(os.path.join(scene, "images"))):
        Image.open(os.path.join(scene, "images", name)).load()
    decode = time.time() - t
    out = os.path.join(work, "out")
    t = time.time()
    r = subprocess.run(["/usr/bin/time", "-v", BIN, "texture", scene, "-o", out, "--size", "8192", "-q"],
                       capture_output=True, text=True)
    wall = time.time() - t
    if r.returncode != 0:
        sys.exit(r.stderr)
    peak = [l for l in r.stderr.splitlines() if "Maximum resident" in l][0].split()[-1]
    rep = json.load(open(os.path.join(out, "report.json")))
    print("| what | seconds | peak MB |")
    print("|---|---|---|")
    print(f"| decode the {PHOTOS} JPEGs once (PIL, 1 core) | {decode:.1f} | |")
    print(f"| scantex texture, 8192 atlas | {wall:.1f} | {int(peak) / 1024:.0f} |")
    for s in rep["stages"]:
        print(f"| stage {s['stage']} | {s['seconds']:.1f} | {s['peak_mb']:.0f} |")
    r = rep["pages"][0]["resample"]
    print(f"| resample: depth maps and mip pyramids, all photographs | {r['seconds_photo_setup']:.1f} | |")
    print(f"| resample: sampling texels, all photographs | {r['seconds_texels']:.1f} | |")
    print(f"\nratio texture / decode: {wall / decode:.1f}")


if __name__ == "__main__":
    main()
