#!/usr/bin/env python3
"""Packing many charts: writes a mesh of N separate, slightly skewed 3 x 3-vertex patches
(8 triangles each, random sizes 0.2-1.5 and orientations: every patch is its own chart) and
times `scantex param` on it, printing the charts, the flattening and packing seconds and the
utilisation from its report.

    cargo build --release
    pip install numpy
    python3 benches/many_charts.py 1000:4096 3000:4096 10000:2048   # charts:atlas size ...
    SCANTEX=/path/to/old/scantex python3 benches/many_charts.py ...  # the same, another binary

Issue 23 asks for hundreds of charts packed in well under a second and 10k in seconds.
"""
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# SCANTEX=<binary> times another build (a previous release) on the same meshes.
BIN = os.environ.get("SCANTEX", os.path.join(ROOT, "target", "release", "scantex"))


def patches(path, n, seed=3):
    rng = np.random.default_rng(seed)
    verts, faces = [], []
    for _ in range(n):
        s = rng.uniform(0.2, 1.5)
        c = rng.uniform(-50, 50, 3)
        a, b = rng.normal(size=3), rng.normal(size=3)
        a /= np.linalg.norm(a)
        b -= a * np.dot(a, b)
        b /= np.linalg.norm(b)
        base = len(verts)
        for u in range(3):
            for v in range(3):
                verts.append(c + s * (u * a + v * b * rng.uniform(0.6, 1.4)))
        for u in range(2):
            for v in range(2):
                p = base + u * 3 + v
                faces += [(p, p + 3, p + 1), (p + 1, p + 3, p + 4)]
    with open(path, "w") as f:
        f.write(f"ply\nformat ascii 1.0\nelement vertex {len(verts)}\nproperty float x\n"
                f"property float y\nproperty float z\nelement face {len(faces)}\n"
                "property list uchar int vertex_indices\nend_header\n")
        f.writelines("%f %f %f\n" % tuple(v) for v in verts)
        f.writelines("3 %d %d %d\n" % t for t in faces)


def main():
    cases = [tuple(int(x) for x in a.split(":")) for a in sys.argv[1:]] or [(1000, 4096)]
    work = tempfile.mkdtemp()
    print("| charts asked | atlas | charts | flatten s | pack s | wall s | utilisation |")
    print("|---|---|---|---|---|---|---|")
    for n, size in cases:
        mesh = os.path.join(work, f"patches{n}.ply")
        patches(mesh, n)
        rep = os.path.join(work, "r.json")
        t = time.time()
        subprocess.run([BIN, "param", mesh, "-o", os.path.join(work, "p.obj"), "--size", str(size),
                        "--report", rep], check=True, capture_output=True)
        wall = time.time() - t
        r = json.load(open(rep))
        print(f"| {n} | {size} | {r['charts']} | {r['seconds_charts']:.2f} | {r['seconds_pack']:.2f} "
              f"| {wall:.1f} | {r['utilisation']:.3f} |", flush=True)


if __name__ == "__main__":
    main()
