#!/usr/bin/env python3
"""Time and peak memory of `scantex texture` against the number of faces and of photographs
(issue 25), on the speed scene's corset (benches/speed_scene.py) subdivided to each face
count and photographed by each number of 12 MP cameras.

    pip install numpy pillow trimesh
    cargo build --release
    python3 benches/scale_curve.py <workdir> 70000:50 1000000:50 4000000:50 1000000:200
    python3 benches/scale_curve.py --small <workdir> 1000000:50 1000000:1000
    python3 benches/scale_curve.py --exact <workdir> 1500000:50

Each FACES:PHOTOS point refines the corset to the fewest triangles of at least FACES
(18,324 x 3^a x 4^b: 73k, 1.17M, 4.69M, 10.6M, 18.8M; see mesh_of) and renders PHOTOS
photographs (800x600 renders upscaled to 4000x3000 with sensor-like noise, as the speed
scene's). With --exact, the mesh has exactly FACES triangles: the most of at most FACES from
midpoint subdivisions alone (sqrt(3) steps repeated leave slivers along the corset's boundary
edges, which split charts: 2,776 charts for 1.48M faces, against 841 here), topped up by
splitting evenly spread triangles at their centroids (1.5M: 1,172,736 + 2 x 163,632).
Scenes are kept in <workdir> and reused (the photographs of one count are shared by every
face count). One run of `scantex texture <scene> -o out -q` (the defaults: --size auto, the
default memory limit) per point, timed by /usr/bin/time; the per-stage figures are
report.json's.
"""
import json
import os
import subprocess
import sys

import trimesh

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import speed_scene  # noqa: E402

BIN = speed_scene.BIN
DATA = speed_scene.DATA


def photos_of(work, n, small_only=False):
    """The 12 MP photographs, masks and COLMAP model of n cameras around the corset (with
    small_only, the 800 x 600 renders they are scaled from)."""
    scene = os.path.join(work, f"photos{n}")
    small = os.path.join(work, f"photos{n}_small")
    if not os.path.exists(os.path.join(small, "sparse", "0", "images.txt")):
        subprocess.run([BIN, "sample", "--from-mesh", os.path.join(DATA, "scans", "corset", "Corset.gltf"),
                        "--up", "y", "--photos", str(n), "-o", small], check=True, capture_output=True)
    if small_only:
        return small
    if not os.path.exists(os.path.join(scene, "sparse", "0", "images.txt")):
        speed_scene.scale_scene(small, scene)
    return scene


def sqrt3_split(v, f):
    """Each triangle split in three at its centroid, then each edge the split kept flipped to
    join the two new centroids (Kobbelt's sqrt(3) step without smoothing): three times the
    faces, still well shaped, on the same surface up to the flips' small chords (but the
    triangles on one of the corset's 4,500 boundary edges lose two thirds of their height at each
    step)."""
    import numpy as np
    n, nv = len(f), len(v)
    c = v[f].mean(axis=1)
    m = nv + np.arange(n)
    # Triangle (a, b, m_i) per face i and edge k; flipped in pairs across each shared edge.
    a = f.reshape(-1)
    b = np.roll(f, -1, axis=1).reshape(-1)
    mi = np.repeat(m, 3)
    key = np.minimum(a, b).astype(np.int64) * (nv + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    out = np.stack([a, b, mi], axis=1)
    # Edges with exactly two triangles, opposite in direction, are flipped.
    first = np.flatnonzero((ks[:-1] == ks[1:]) & np.r_[True, ks[1:-1] != ks[:-2]]
                           & np.r_[ks[2:] != ks[1:-1], True])
    t1, t2 = order[first], order[first + 1]
    ok = (a[t1] == b[t2]) & (b[t1] == a[t2])
    t1, t2 = t1[ok], t2[ok]
    ea, eb, m1, m2 = a[t1], b[t1], mi[t1], mi[t2]
    out[t1] = np.stack([ea, m2, m1], axis=1)
    out[t2] = np.stack([eb, m1, m2], axis=1)
    return np.vstack([v, c]), out


def top_up(v, f, faces):
    """Evenly spread triangles split in three at their centroids (no flips) until there are
    `faces` (one short when the difference is odd)."""
    import numpy as np
    k = (faces - len(f)) // 2
    if k <= 0:
        return v, f
    pick = np.linspace(0, len(f) - 1, k).round().astype(np.int64)
    c = v[f[pick]].mean(axis=1)
    m = len(v) + np.arange(k)
    a, b, d = f[pick, 0], f[pick, 1], f[pick, 2]
    out = f.copy()
    out[pick] = np.stack([a, b, m], axis=1)
    extra = np.vstack([np.stack([b, d, m], axis=1), np.stack([d, a, m], axis=1)])
    return np.vstack([v, c]), np.vstack([out, extra])


def mesh_of(work, faces, exact=False):
    """The corset refined to the fewest faces of at least `faces`: 18,324 x 3^a x 4^b
    triangles, a (0 to 2) sqrt(3) splits then b midpoint subdivisions (73k, 1.17M, 4.69M,
    10.6M, 18.8M ...); with `exact`, midpoint subdivisions only (b), the most of at most
    `faces`, topped up to `faces` (top_up)."""
    base = 18324
    recipes = [(a, b) for a in range(3) for b in range(8)]
    count = lambda r: base * 3 ** r[0] * 4 ** r[1]  # noqa: E731
    if exact:
        if faces < base:
            sys.exit(f"--exact needs at least {base} faces (the corset's)")
        a, b = max((r for r in recipes if count(r) <= faces and r[0] == 0), key=count)
    else:
        a, b = min((r for r in recipes if count(r) >= faces), key=count)
    path = os.path.join(work, f"mesh_s{a}_m{b}" + (f"_exact{faces}" if exact else "") + ".ply")
    if not os.path.exists(path):
        m = trimesh.load(os.path.join(DATA, "scans", "corset", "Corset.gltf"), force="mesh", process=False)
        m.merge_vertices()
        v, f = m.vertices, m.faces
        for _ in range(a):
            v, f = sqrt3_split(v, f)
        for _ in range(b):
            v, f = trimesh.remesh.subdivide(v, f)
        if exact:
            v, f = top_up(v, f, faces)
        trimesh.Trimesh(v, f, process=False).export(path)
    return path


def scene_of(work, faces, photos, small=False, exact=False):
    scene = os.path.join(work, f"scene{faces}_{photos}" + ("_small" if small else "")
                         + ("_exact" if exact else ""))
    os.makedirs(scene, exist_ok=True)
    src = photos_of(work, photos, small)
    for d in ("images", "masks", "sparse"):
        link = os.path.join(scene, d)
        if not os.path.exists(link):
            os.symlink(os.path.join(src, d), link)
    link = os.path.join(scene, "mesh.ply")
    if not os.path.exists(link):
        os.symlink(mesh_of(work, faces, exact), link)
    return scene


def main():
    args = sys.argv[1:]
    # --small: the 800 x 600 renders instead of 12 MP (memory against the photograph count
    # without hours of generating 12 MP photographs).
    small = "--small" in args
    # --exact: exactly FACES triangles (mesh_of) instead of the next refinement up.
    exact = "--exact" in args
    args = [a for a in args if a not in ("--small", "--exact")]
    work = args[0]
    points = [tuple(int(x) for x in p.split(":")) for p in args[1:]]
    print("| faces | photographs | pages | wall s | peak MB | estimate MB | atlas s | bind s | "
          "resample+merge s | restore s | synth s | largest stage peak MB (stage) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for faces, photos in points:
        scene = scene_of(work, faces, photos, small, exact)
        out = os.path.join(work, f"out{faces}_{photos}" + ("_small" if small else "")
                           + ("_exact" if exact else ""))
        r = subprocess.run(["/usr/bin/time", "-v", BIN, "texture", scene, "-o", out, "-q"],
                           capture_output=True, text=True)
        if r.returncode != 0:
            print(f"| {faces} | {photos} | failed: {r.stderr.strip().splitlines()[-1]} |")
            continue
        lines = r.stderr.splitlines()
        peak = int([l for l in lines if "Maximum resident" in l][0].split()[-1]) * 1024 / 1e6
        wall = [l for l in lines if "Elapsed (wall clock)" in l][0].split()[-1]
        wall = sum(float(x) * 60 ** i for i, x in enumerate(reversed(wall.split(":"))))
        rep = json.load(open(os.path.join(out, "report.json")))

        def total(stage):
            return sum(s["seconds"] for s in rep["stages"] if s["stage"] == stage)

        top = max(rep["stages"], key=lambda s: s["peak_mb"])
        print(f"| {rep['faces']} | {photos} | {len(rep['pages'])} of {rep['atlas_size']} | {wall:.1f} | "
              f"{peak:.0f} | {rep['memory']['estimate_bytes'] / 1e6:.0f} | {total('atlas'):.1f} | "
              f"{total('bind'):.1f} | {total('resample+merge'):.1f} | {total('restore'):.1f} | "
              f"{total('synth'):.1f} | {top['peak_mb']:.0f} ({top['stage']}) |", flush=True)


if __name__ == "__main__":
    main()
