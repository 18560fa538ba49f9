#!/usr/bin/env python3
"""Side by side, in one run: scantex against MeshLab's raster texturing and (optionally) a
previous scantex binary, on the bundled sample, the corset scene and floor_patch. Prints wall
time, CPU time and peak memory of each tool, as ratios to the fastest peer, and the held-out
scores of every texture (`scantex eval --gain-fit`).

    cargo build --release
    pip install pymeshlab pycolmap        # MeshLab 2025.7 and a COLMAP model reader
    apt-get install xvfb libqt5gui5 libgl1-mesa-dri   # MeshLab's filter needs an OpenGL context
    python3 benches/peers.py [--baseline OLD_SCANTEX] [--scenes sample,corset,floor_patch]
                             [--scantex-args "--size 1024"]   # added to both scantex runs

MeshLab: `compute_texcoord_parametrization_and_texture_from_registered_rasters` (the filter
the issue calls `compute_texmap_from_registered_rasters`, renamed in MeshLab 2022) on the same
mesh and photographs, with an atlas of scantex's default size (4096), run under `xvfb-run`
with Mesa's software OpenGL. The COLMAP model is converted to a Bundler file first (not
timed): Bundler cannot hold a principal point off the centre (these scenes' are within half a
pixel of it); SIMPLE_RADIAL's k is written as Bundler's k1 (the sample's and the corset's are
about -0.05; floor_patch's photographs are undistorted), and whether MeshLab's filter applies
it was not checked.

Scenes:
  * sample: samples/torus, held out: its 4 held-out views;
  * corset: `scantex sample --from-mesh ../shared/data/scans/corset/Corset.gltf --up y
    --photos 24` (24 photographs, 4 held out);
  * floor_patch: ../shared/data/colmap/floor_patch/dense/0, photographs 1-4 textured and
    5.jpg held out (one fold of benches/texture_compare.py's leave-one-out).
Times come from /usr/bin/time (wall, user + system, maximum resident set), one run per tool.
"""
import argparse
import importlib.util
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data")
BIN = os.path.join(ROOT, "target", "release", "scantex")
SIZE = 4096
EXTRA = []  # --scantex-args
QT = "/usr/lib/x86_64-linux-gnu/qt5/plugins"

# The timed MeshLab process (`python3 -c MESHLAB_JOB mesh dir size`, inside xvfb-run).
MESHLAB_JOB = """
import pymeshlab, sys
mesh, d, size = sys.argv[1], sys.argv[2], int(sys.argv[3])
ms = pymeshlab.MeshSet()
ms.load_new_mesh(mesh)
ms.load_project([d + "/bundle.out", d + "/list.txt"])
ms.set_current_mesh(0)
ms.compute_texcoord_parametrization_and_texture_from_registered_rasters(
    texturesize=size, texturename="model.png")
ms.save_current_mesh(d + "/model.obj")
"""


def timed(cmd, env=None):
    """Runs `cmd` under /usr/bin/time: (wall s, cpu s, peak MB)."""
    r = subprocess.run(["/usr/bin/time", "-f", "TIME %e %U %S %M"] + cmd, capture_output=True,
                       text=True, env=env)
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{r.stderr[-3000:]}")
    line = [l for l in r.stderr.splitlines() if l.startswith("TIME ")][-1].split()
    return float(line[1]), float(line[2]) + float(line[3]), int(line[4]) / 1024


def bundler(model, images, names, d):
    """Writes `d`/bundle.out and list.txt for the images called `names` of COLMAP `model`."""
    import numpy as np
    import pycolmap

    r = pycolmap.Reconstruction(model)
    ims = sorted((i for i in r.images.values() if i.name in names), key=lambda i: i.name)
    flip = np.diag([1.0, -1.0, -1.0])  # COLMAP looks down +z with y down; Bundler down -z, y up
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "bundle.out"), "w") as b, open(os.path.join(d, "list.txt"), "w") as l:
        b.write(f"# Bundle file v0.3\n{len(ims)} 0\n")
        for im in ims:
            c = r.cameras[im.camera_id]
            p = [float(v) for v in c.params]
            model_name = c.model.name
            if model_name == "SIMPLE_RADIAL":
                f, k1 = p[0], p[3]
            elif model_name == "PINHOLE":
                f, k1 = 0.5 * (p[0] + p[1]), 0.0
            elif model_name == "SIMPLE_PINHOLE":
                f, k1 = p[0], 0.0
            else:
                sys.exit(f"camera model {model_name}: no Bundler equivalent")
            pose = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
            rot = flip @ pose.rotation.matrix()
            t = flip @ pose.translation
            b.write(f"{f!r} {k1!r} 0\n")
            for row in rot:
                b.write(" ".join(repr(float(v)) for v in row) + "\n")
            b.write(" ".join(repr(float(v)) for v in t) + "\n")
            l.write(os.path.abspath(os.path.join(images, im.name)) + "\n")


def evaluate(obj, eval_args, tmp):
    js = os.path.join(tmp, "eval.json")
    r = subprocess.run([BIN, "eval", "--mesh", obj, "--gain-fit", "--json", js] + eval_args,
                       capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"eval of {obj} failed:\n{r.stderr}")
    with open(js) as f:
        return json.load(f)["mean"]


def scene_rows(name, tex_args, mesh, model, images, names, eval_args, baseline, tmp):
    rows = []
    tools = [("scantex", BIN)] + ([("scantex (baseline)", baseline)] if baseline else [])
    for label, exe in tools:
        out = os.path.join(tmp, name, label.replace(" ", "_"))
        w, c, m = timed([exe, "texture", "-q", "-o", out] + tex_args + EXTRA)
        rows.append((label, w, c, m, evaluate(os.path.join(out, "model.obj"), eval_args, tmp)))
        print(f"{name}: {label} {w:.1f} s", file=sys.stderr)
    d = os.path.join(tmp, name, "meshlab")
    bundler(model, images, names, d)
    env = dict(os.environ, QT_PLUGIN_PATH=QT, QT_QPA_PLATFORM_PLUGIN_PATH=QT + "/platforms")
    job = [sys.executable, "-c", MESHLAB_JOB, mesh, d, str(SIZE)]
    w, c, m = timed(["xvfb-run", "-a"] + job, env)
    rows.append(("MeshLab 2025.7", w, c, m, evaluate(os.path.join(d, "model.obj"), eval_args, tmp)))
    print(f"{name}: MeshLab {w:.1f} s", file=sys.stderr)
    peer = min(r[1] for r in rows if not r[0].startswith("scantex"))
    print(f"\n### {name}\n")
    print("| tool | wall s | / fastest peer | CPU s | peak MB | held-out PSNR dB | 1 - NCC |")
    print("|---|---|---|---|---|---|---|")
    for label, w, c, m, e in rows:
        print(f"| {label} | {w:.1f} | {w / peer:.2f} | {c:.1f} | {m:.0f} | {e['psnr']:.2f} "
              f"| {e['one_minus_ncc']:.4f} |")
    sys.stdout.flush()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline", help="a previous scantex binary to run beside this one")
    ap.add_argument("--scenes", default="sample,corset,floor_patch")
    ap.add_argument("--scantex-args", default="", help="options added to every scantex texture")
    a = ap.parse_args()
    global EXTRA
    EXTRA = shlex.split(a.scantex_args)
    if not os.path.exists(BIN):
        sys.exit("build first: cargo build --release")
    # What MeshLab's run needs, checked before any scene is timed (each missing piece used to
    # surface only after scantex's runs, as a traceback or as MeshLab's bare "Aborted").
    missing = [m for m in ("pymeshlab", "pycolmap", "numpy")
               if importlib.util.find_spec(m) is None]
    if missing:
        sys.exit(f"missing Python modules: pip install {' '.join(missing)}")
    if shutil.which("xvfb-run") is None:
        sys.exit("xvfb-run not found: apt-get install xvfb")
    if not os.path.exists(os.path.join(QT, "platforms", "libqxcb.so")):
        sys.exit(f"Qt's xcb platform plugin is not in {QT}/platforms (MeshLab's filter aborts "
                 "without it): apt-get install libqt5gui5 libgl1-mesa-dri")
    scenes = a.scenes.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        if "sample" in scenes:
            s = os.path.join(ROOT, "samples", "torus")
            names = os.listdir(os.path.join(s, "images"))
            scene_rows("sample (samples/torus)", [s], os.path.join(s, "mesh.ply"),
                       os.path.join(s, "sparse", "0"), os.path.join(s, "images"), names,
                       [os.path.join(s, "heldout")], a.baseline, tmp)
        if "corset" in scenes:
            s = os.path.join(tmp, "corset_scene")
            subprocess.run([BIN, "sample", "--from-mesh",
                            os.path.join(DATA, "scans", "corset", "Corset.gltf"), "--up", "y",
                            "--photos", "24", "-o", s], check=True, capture_output=True)
            names = os.listdir(os.path.join(s, "images"))
            scene_rows("corset (24 photographs, 4 held out)", [s], os.path.join(s, "mesh.ply"),
                       os.path.join(s, "sparse", "0"), os.path.join(s, "images"), names,
                       [os.path.join(s, "heldout")], a.baseline, tmp)
        if "floor_patch" in scenes:
            d = os.path.realpath(os.path.join(DATA, "colmap", "floor_patch", "dense", "0"))
            if not os.path.isdir(d):
                sys.exit(f"{d}: floor_patch data missing")
            train, test = os.path.join(tmp, "fp_train"), os.path.join(tmp, "fp_test")
            os.makedirs(train)
            os.makedirs(test)
            names = [n for n in sorted(os.listdir(os.path.join(d, "images"))) if n != "5.jpg"]
            for n in sorted(os.listdir(os.path.join(d, "images"))):
                os.symlink(os.path.join(d, "images", n), os.path.join(test if n == "5.jpg" else train, n))
            common = ["--colmap", os.path.join(d, "sparse"), "--skip-missing"]
            mesh = os.path.join(d, "meshed-poisson.ply")
            scene_rows("floor_patch (photographs 1-4, 5.jpg held out)",
                       ["--mesh", mesh, "--images", train] + common, mesh,
                       os.path.join(d, "sparse"), train, names, ["--images", test] + common,
                       a.baseline, tmp)


if __name__ == "__main__":
    main()
