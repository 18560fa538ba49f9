#!/usr/bin/env python3
"""One-run comparison of `scantex param` with xatlas (default options) and libigl LSCM.

    pip install xatlas trimesh libigl numpy
    cargo build --release
    python3 benches/atlas_compare.py            # prints a markdown table

Meshes: the bundled sample, the corset with its UVs ignored, floor_patch's Poisson mesh, and
the corset subdivided to about 1.2M triangles (written to a temporary directory). Stretch is
Sander's L2 / L-infinity with the 2D area normalised to the 3D area, mirror-invariant (a
mirrored chart is not a flip). Utilisation is measured at 4096 with a 4-texel gutter.
"""
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import trimesh
import xatlas

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data")
BIN = os.path.join(ROOT, "target", "release", "scantex")


def stretch(V, F, UV):
    p = V[F]
    q = UV[F].astype(float).copy()
    sa = 0.5 * ((q[:, 1, 0] - q[:, 0, 0]) * (q[:, 2, 1] - q[:, 0, 1]) - (q[:, 1, 1] - q[:, 0, 1]) * (q[:, 2, 0] - q[:, 0, 0]))
    q[sa < 0, :, 0] *= -1
    a2 = np.abs(sa)
    a3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    k = np.sqrt(a2.sum() / a3.sum())
    q = q / k
    a2n = a2 / k / k
    ok = a2n > 0
    A = np.where(ok, a2n, 1)[:, None]
    s, t = q[:, :, 0], q[:, :, 1]
    Ss = (p[:, 0] * (t[:, 1] - t[:, 2])[:, None] + p[:, 1] * (t[:, 2] - t[:, 0])[:, None] + p[:, 2] * (t[:, 0] - t[:, 1])[:, None]) / (2 * A)
    St = (p[:, 0] * (s[:, 2] - s[:, 1])[:, None] + p[:, 1] * (s[:, 0] - s[:, 2])[:, None] + p[:, 2] * (s[:, 1] - s[:, 0])[:, None]) / (2 * A)
    a, b, c = (Ss * Ss).sum(1), (Ss * St).sum(1), (St * St).sum(1)
    l2 = np.sqrt((a + c) / 2)
    linf = np.sqrt(((a + c) + np.sqrt((a - c) ** 2 + 4 * b * b)) / 2)
    return float(np.sqrt((l2[ok] ** 2 * a3[ok]).sum() / a3[ok].sum())), float(linf[ok].max()), int((~ok).sum())


def load(path):
    m = trimesh.load(path, process=False, force="mesh")
    m.merge_vertices(merge_tex=True, merge_norm=True)
    return m


def run_xatlas(m):
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces)
    # xatlas works with absolute epsilons: on the 4 cm corset it collapses most UVs (15,075 of
    # 18,324 triangles came out with zero UV area), and on a unit-sized 1M-triangle mesh too.
    # Stretch is scale-free, so give it the mesh scaled to a mean edge length of 1.
    e = np.linalg.norm(V[F[:, [1, 2, 0]]] - V[F], axis=2).mean()
    V = V / e
    t = time.time()
    atlas = xatlas.Atlas()
    atlas.add_mesh(V, F)
    po = xatlas.PackOptions()
    po.resolution = 4096
    po.padding = 4
    # An atlas of 4096 needs a texel density; xatlas's own estimate targets a smaller atlas.
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    po.texels_per_unit = float(np.sqrt(0.6 * 4096 ** 2 / area))
    atlas.generate(pack_options=po)
    dt = time.time() - t
    vmap, idx, uv = atlas[0]
    l2, linf, degenerate = stretch(V[vmap], idx, uv)
    return dict(charts=atlas.chart_count, l2=l2, linf=linf, degenerate=degenerate, util=atlas.utilization, time=dt)


def run_lscm(m):
    try:
        import igl
    except ImportError:
        return None
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces)
    # LSCM needs a disk: one component with Euler characteristic 1.
    if m.euler_number != 1 or len(m.split(only_watertight=False)) != 1:
        return "n/a: not a disk"
    bnd = igl.boundary_loop(F)
    b = np.array([bnd[0], bnd[len(bnd) // 2]])
    bc = np.array([[0.0, 0.0], [1.0, 0.0]])
    t = time.time()
    res = igl.lscm(V, F, b, bc)
    uv = res[1] if isinstance(res, tuple) else res
    dt = time.time() - t
    l2, linf, degenerate = stretch(V, F, uv)
    return dict(charts=1, l2=l2, linf=linf, degenerate=degenerate, util=float("nan"), time=dt)


def run_scantex(path, tmp):
    out = os.path.join(tmp, "p.obj")
    rep = os.path.join(tmp, "r.json")
    t = time.time()
    subprocess.run([BIN, "param", path, "-o", out, "--report", rep], check=True, stdout=subprocess.DEVNULL)
    dt = time.time() - t
    r = json.load(open(rep))
    s = r["stretch"]
    return dict(charts=r["charts"], l2=s["l2"], linf=s["linf"], flips=s["flipped"], degenerate=s["zero_area"],
                util=r["utilisation"], seams=r["seam_ratio"], time=dt)


def main():
    tmp = tempfile.mkdtemp()
    corset = os.path.join(DATA, "scans", "corset", "Corset.obj")
    big = os.path.join(tmp, "corset_1m.ply")
    m = load(corset)
    for _ in range(3):
        m = m.subdivide()
    m.export(big)
    meshes = [
        ("sample torus", os.path.join(ROOT, "samples", "torus", "mesh.ply")),
        ("corset (UVs ignored)", corset),
        ("floor_patch poisson", os.path.join(DATA, "colmap", "floor_patch", "dense", "0", "meshed-poisson.ply")),
        ("corset subdivided", big),
    ]
    print("| mesh | faces | tool | charts | L2 | L-inf | flips | degenerate | seams | utilisation | time (s) |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, path in meshes:
        mesh = load(path)
        rows = [("scantex", run_scantex(path, tmp)), ("xatlas", run_xatlas(mesh)), ("libigl LSCM", run_lscm(mesh))]
        for tool, r in rows:
            if r is None or isinstance(r, str):
                print(f"| {name} | {len(mesh.faces)} | {tool} | {r or 'not installed'} | | | | | | | |")
                continue
            print(f"| {name} | {len(mesh.faces)} | {tool} | {r['charts']} | {r['l2']:.4f} | {r['linf']:.2f} | "
                  f"{r.get('flips', '-')} | {r['degenerate']} | {r.get('seams', float('nan')):.3f} | {r['util']:.3f} | {r['time']:.2f} |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
