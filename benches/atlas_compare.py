#!/usr/bin/env python3
"""One-run comparison of `scantex param` with xatlas (default options) and libigl LSCM.

    pip install xatlas trimesh libigl numpy
    cargo build --release
    python3 benches/atlas_compare.py            # prints a markdown table

Meshes: the bundled sample, the corset with its UVs ignored, floor_patch's Poisson mesh, and
the corset subdivided to about 1.2M triangles (written to a temporary directory). Stretch is
Sander's L2 / L-infinity with the 2D area normalised to the 3D area, mirror-invariant (a
mirrored chart is not a flip). Every tool's output is measured by the same code
(`scantex uv-report --size 4096`: texel centres inside UV triangles, charts = UV islands);
xatlas gets the largest texel density that fits one 4096 page with a 4-texel padding, found by
bisection as scantex finds its own; its time is that of the final run.
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


def write_obj(path, V, F, UV, FT):
    with open(path, "w") as f:
        f.write("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in V))
        f.write("".join(f"vt {u:.9g} {v:.9g}\n" for u, v in UV))
        f.write("".join(f"f {a+1}/{ta+1} {b+1}/{tb+1} {c+1}/{tc+1}\n" for (a, b, c), (ta, tb, tc) in zip(F, FT)))


def uv_report(path):
    out = subprocess.run([BIN, "uv-report", path, "--size", "4096"], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def run_xatlas(m, tmp):
    V0, F = np.asarray(m.vertices, float), np.asarray(m.faces)
    # xatlas works with absolute epsilons: on the 4 cm corset it collapses most UVs (15,075 of
    # 18,324 triangles came out with zero UV area), and on a unit-sized 1M-triangle mesh too.
    # Stretch is scale-free, so give it the mesh scaled to a mean edge length of 1.
    e = np.linalg.norm(V0[F[:, [1, 2, 0]]] - V0[F], axis=2).mean()
    V = V0 / e
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    # One full run (charts + packing, timed) at the density of 60% utilisation of one page.
    atlas = xatlas.Atlas()
    atlas.add_mesh(V, F)
    po = xatlas.PackOptions()
    po.resolution = 4096
    po.padding = 4
    po.texels_per_unit = float(np.sqrt(0.6 * 4096 ** 2 / area))
    t = time.time()
    atlas.generate(pack_options=po)
    dt = time.time() - t
    charts = atlas.chart_count
    # That density may overflow one page (xatlas then opens a second). Find the largest density
    # that fits one page, as scantex does for itself, by repacking xatlas's own charts with
    # xatlas's packer (add_uv_mesh: packing only) and bisecting on the scale.
    vmap0, idx0, uv0 = atlas[0]
    # Texel coordinates of every chart at the first run's density.
    w0, h0 = atlas.width, atlas.height
    tex = (uv0 * np.array([w0, h0])).astype(np.float32)
    lo, hi, best = None, 2.0, None
    s = 1.0
    for _ in range(30):
        a = xatlas.Atlas()
        a.add_uv_mesh(tex, idx0.astype(np.uint32))
        p = xatlas.PackOptions()
        p.resolution = 4096
        p.padding = 4
        p.texels_per_unit = s
        a.generate(pack_options=p)
        if a.atlas_count == 1 and a.width <= 4096 and a.height <= 4096:
            lo, best = s, a
        else:
            hi = s
        if lo is None:
            s /= 1.1
            continue
        if hi / lo < 1.01:
            break
        s = float(np.sqrt(lo * hi))
    _, idx1, uv1 = best[0]
    px = uv1 * np.array([best.width, best.height]) / 4096.0
    path = os.path.join(tmp, "xatlas.obj")
    write_obj(path, V0, vmap0[idx0], px, idx1)
    r = uv_report(path)
    st = r["stretch"]
    return dict(charts=charts, l2=st["l2"], linf=st["linf"], flips=st["flipped"], degenerate=st["zero_area"],
                util=r["utilisation"], seams=r["seam_ratio"], time=dt, overlap=r["overlapping_texels"])


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
                util=r["utilisation"], seams=r["seam_ratio"], time=dt, overlap=r["overlapping_texels"])


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
    print("| mesh | faces | tool | charts | L2 | L-inf | flips | degenerate | seams | utilisation | overlap | time (s) |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, path in meshes:
        mesh = load(path)
        rows = [("scantex", run_scantex(path, tmp)), ("xatlas", run_xatlas(mesh, tmp)), ("libigl LSCM", run_lscm(mesh))]
        for tool, r in rows:
            if r is None or isinstance(r, str):
                print(f"| {name} | {len(mesh.faces)} | {tool} | {r or 'not installed'} | | | | | | | | |")
                continue
            print(f"| {name} | {len(mesh.faces)} | {tool} | {r['charts']} | {r['l2']:.4f} | {r['linf']:.2f} | "
                  f"{r.get('flips', '-')} | {r['degenerate']} | {r.get('seams', float('nan')):.3f} | {r['util']:.3f} | "
                  f"{r.get('overlap', '-')} | {r['time']:.2f} |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
