#!/usr/bin/env python3
"""Reference projections from COLMAP (pycolmap) for every camera model it defines.

Writes `models.json` (projections and rays per model) and `real_models.json` (COLMAP's own
recomputed per-point mean reprojection error for the real models in ../shared/data/colmap).
scantex's tests read these files; CI needs no Python. Regenerate with:

    pip install pycolmap==4.2.1 numpy
    python3 calib/colmap/generate.py

Do not regenerate to make a failing test pass: a change here means COLMAP changed.
"""
import json
import os
import sys

import numpy as np
import pycolmap

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.normpath(os.path.join(HERE, "..", "..", "..", "shared", "data", "colmap"))
rng = np.random.default_rng(20261122)

W, H = 1600, 1200

# Realistic parameters per model: focal ~ image width, distortion of the size real lenses show.
PARAMS = {
    "SIMPLE_PINHOLE": [1500.0, 801.3, 598.7],
    "PINHOLE": [1500.0, 1510.0, 801.3, 598.7],
    "SIMPLE_RADIAL": [1500.0, 801.3, 598.7, -0.12],
    "RADIAL": [1500.0, 801.3, 598.7, -0.12, 0.03],
    "OPENCV": [1500.0, 1510.0, 801.3, 598.7, -0.12, 0.03, 0.001, -0.0015],
    "OPENCV_FISHEYE": [600.0, 605.0, 801.3, 598.7, 0.05, -0.01, 0.002, -0.0005],
    "FULL_OPENCV": [1500.0, 1510.0, 801.3, 598.7, -0.12, 0.03, 0.001, -0.0015, 0.01, 0.02, -0.01, 0.005],
    "FOV": [1500.0, 1510.0, 801.3, 598.7, 0.4],
    "SIMPLE_RADIAL_FISHEYE": [600.0, 801.3, 598.7, 0.04],
    "RADIAL_FISHEYE": [600.0, 801.3, 598.7, 0.04, -0.005],
    "THIN_PRISM_FISHEYE": [600.0, 605.0, 801.3, 598.7, 0.05, -0.01, 0.001, -0.0015, 0.002, -0.0005, 0.0008, -0.0006],
    "RAD_TAN_THIN_PRISM_FISHEYE": [600.0, 605.0, 801.3, 598.7, 0.05, -0.01, 0.002, -0.0005, 0.0001, -0.00002,
                                   0.001, -0.0015, 0.0008, -0.0002, -0.0006, 0.0001],
    "SIMPLE_DIVISION": [1500.0, 801.3, 598.7, -0.1],
    "DIVISION": [1500.0, 1510.0, 801.3, 598.7, -0.1],
    "SIMPLE_FISHEYE": [600.0, 801.3, 598.7],
    "FISHEYE": [600.0, 605.0, 801.3, 598.7],
    "EUCM": [1000.0, 1005.0, 801.3, 598.7, 0.6, 1.1],
    "EQUIRECTANGULAR": [float(W), float(H)],
}


def random_pose():
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    t = rng.normal(size=3) * 2.0
    return q, t  # q as w, x, y, z (COLMAP text order)


def rigid(q, t):
    w, x, y, z = q
    return pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([x, y, z, w])), np.asarray(t, float))


def model_case(name, params):
    cam = pycolmap.Camera(model=name, width=W, height=H, params=params)
    # Pixels: uniform over the image, plus the border rows/columns and corners.
    n = 300
    px = np.column_stack([rng.uniform(0, W, n), rng.uniform(0, H, n)])
    border = np.array([[0.0, 0.0], [W, 0.0], [0.0, H], [W, H], [W / 2, 0.0], [0.0, H / 2], [W, H / 2],
                       [W / 2, H], [0.5, 0.5], [W - 0.5, H - 0.5]])
    px = np.vstack([px, border])
    rays = np.asarray(cam.cam_ray_from_img(px), float)
    norm = np.asarray(cam.cam_from_img(px), float)
    # 3D points along those rays at random depths, plus (fisheye / spherical) wide-angle points.
    depth = rng.uniform(0.5, 20.0, len(px))
    pts_cam = rays * depth[:, None]
    if cam.is_perspective_fisheye or name in ("EQUIRECTANGULAR", "EUCM"):
        ang = rng.uniform(np.radians(60), np.radians(89), 60)
        az = rng.uniform(0, 2 * np.pi, 60)
        wide = np.column_stack([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)])
        pts_cam = np.vstack([pts_cam, wide * rng.uniform(0.5, 5.0, 60)[:, None]])
    ok = np.all(np.isfinite(pts_cam), axis=1)
    pts_cam = pts_cam[ok]
    q, t = random_pose()
    world_from_cam = rigid(q, t).inverse()
    pts_world = np.asarray(world_from_cam * pts_cam, float)
    proj = np.asarray(cam.img_from_cam(np.asarray(rigid(q, t) * pts_world, float)), float)
    keep = np.all(np.isfinite(proj), axis=1)
    return {
        "model": name,
        "width": W,
        "height": H,
        "params": list(map(float, params)),
        "qvec": list(map(float, q)),
        "tvec": list(map(float, t)),
        "points_world": pts_world[keep].tolist(),
        "pixels": proj[keep].tolist(),
        "ray_pixels": px[np.all(np.isfinite(rays), axis=1)].tolist(),
        "rays": rays[np.all(np.isfinite(rays), axis=1)].tolist(),
        "norm_pixels": px[np.all(np.isfinite(norm), axis=1)].tolist(),
        "normalized": norm[np.all(np.isfinite(norm), axis=1)].tolist(),
    }


def real_model(rel):
    path = os.path.join(DATA, rel)
    rec = pycolmap.Reconstruction(path)
    out = {}
    for pid, p in rec.points3D.items():
        errs = []
        for el in p.track.elements:
            img = rec.images[el.image_id]
            cam = rec.cameras[img.camera_id]
            pc = np.asarray(img.cam_from_world() * p.xyz, float)
            xy = np.asarray(cam.img_from_cam(pc.reshape(1, 3)), float)[0]
            errs.append(float(np.linalg.norm(xy - img.points2D[el.point2D_idx].xy)))
        out[str(pid)] = float(np.mean(errs))
    return out


def main():
    names = [n for n in pycolmap.CameraModelId.__members__ if n != "INVALID"]
    missing = set(names) - set(PARAMS)
    if missing:
        sys.exit(f"pycolmap has camera models without test parameters: {sorted(missing)}")
    cases = [model_case(n, PARAMS[n]) for n in names]
    with open(os.path.join(HERE, "models.json"), "w") as f:
        json.dump({"pycolmap_version": pycolmap.__version__, "cases": cases}, f)
    real = {}
    for rel in ["statue_of_liberty/sparse/0", "test_colmap/sparse/0", "test_colmap/dense/0/sparse",
                "floor_patch/dense/0/sparse"]:
        real[rel] = real_model(rel)
    # The text copy of the statue model (6 significant digits in images.txt).
    import shutil
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        for f in ("cameras.txt", "images.txt", "points3D.txt"):
            shutil.copy(os.path.join(DATA, "statue_of_liberty/sparse/0", f), tmp)
        rec = pycolmap.Reconstruction(tmp)
        real["statue_of_liberty/sparse/0 (text)"] = {
            str(pid): float(np.mean([np.linalg.norm(
                np.asarray(rec.cameras[rec.images[el.image_id].camera_id].img_from_cam(
                    np.asarray(rec.images[el.image_id].cam_from_world() * p.xyz, float).reshape(1, 3)), float)[0]
                - rec.images[el.image_id].points2D[el.point2D_idx].xy) for el in p.track.elements]))
            for pid, p in rec.points3D.items()}
    with open(os.path.join(HERE, "real_models.json"), "w") as f:
        json.dump({"pycolmap_version": pycolmap.__version__, "mean_track_error": real}, f)
    print(f"pycolmap {pycolmap.__version__}: {len(cases)} models, {len(real)} real models")


if __name__ == "__main__":
    main()
