#!/usr/bin/env python3
"""Time and peak memory of `scantex texture` against the number of faces and of photographs
(issue 25), on the speed scene's corset (benches/speed_scene.py) subdivided to each face
count and photographed by each number of 12 MP cameras.

    pip install numpy pillow trimesh
    cargo build --release
    python3 benches/scale_curve.py <workdir> 70000:50 1000000:50 4000000:50 1000000:200

Each FACES:PHOTOS point subdivides the corset until it has at least FACES triangles (18,324
x 4^k: 73k, 293k, 1.17M, 4.69M, 18.8M) and renders PHOTOS photographs (800x600 renders
upscaled to 4000x3000 with sensor-like noise, as the speed scene's). Scenes are kept in
<workdir> and reused (the photographs of one count are shared by every face count). One run
of `scantex texture <scene> -o out -q` (the defaults: --size auto, the default memory limit)
per point, timed by /usr/bin/time; the per-stage figures are report.json's.
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


def photos_of(work, n):
    """The 12 MP photographs, masks and COLMAP model of n cameras around the corset."""
    scene = os.path.join(work, f"photos{n}")
    if not os.path.exists(os.path.join(scene, "sparse", "0", "images.txt")):
        small = os.path.join(work, f"photos{n}_small")
        subprocess.run([BIN, "sample", "--from-mesh", os.path.join(DATA, "scans", "corset", "Corset.gltf"),
                        "--up", "y", "--photos", str(n), "-o", small], check=True, capture_output=True)
        speed_scene.scale_scene(small, scene)
    return scene


def mesh_of(work, faces):
    """The corset subdivided until it has at least `faces` triangles."""
    path = os.path.join(work, f"mesh{faces}.ply")
    if not os.path.exists(path):
        m = trimesh.load(os.path.join(DATA, "scans", "corset", "Corset.gltf"), force="mesh", process=False)
        m.merge_vertices()
        v, f = m.vertices, m.faces
        while len(f) < faces:
            v, f = trimesh.remesh.subdivide(v, f)
        trimesh.Trimesh(v, f, process=False).export(path)
    return path


def scene_of(work, faces, photos):
    scene = os.path.join(work, f"scene{faces}_{photos}")
    os.makedirs(scene, exist_ok=True)
    src = photos_of(work, photos)
    for d in ("images", "masks", "sparse"):
        link = os.path.join(scene, d)
        if not os.path.exists(link):
            os.symlink(os.path.join(src, d), link)
    link = os.path.join(scene, "mesh.ply")
    if not os.path.exists(link):
        os.symlink(mesh_of(work, faces), link)
    return scene


def main():
    work = sys.argv[1]
    points = [tuple(int(x) for x in p.split(":")) for p in sys.argv[2:]]
    print("| faces | photographs | pages | wall s | peak MB | estimate MB | atlas s | bind s | "
          "resample+merge s | restore s | synth s | largest stage peak MB (stage) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for faces, photos in points:
        scene = scene_of(work, faces, photos)
        out = os.path.join(work, f"out{faces}_{photos}")
        r = subprocess.run(["/usr/bin/time", "-v", BIN, "texture", scene, "-o", out, "-q"],
                           capture_output=True, text=True)
        if r.returncode != 0:
            print(f"| {faces} | {photos} | failed: {r.stderr.strip().splitlines()[-1]} |")
            continue
        lines = r.stderr.splitlines()
        peak = int([l for l in lines if "Maximum resident" in l][0].split()[-1]) * 1024 / 1e6
        wall = [l for l in lines if "Elapsed (wall clock)" in l][0].split()[-1]
        m, s = wall.split(":")[-2:]
        wall = float(m) * 60 + float(s)
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
