#!/usr/bin/env python3
"""The bundled sample undistorted by COLMAP (pycolmap's `undistort_images`), for the camera
formats that hold no distortion (OpenMVS) or only a different one (VisualSFM).

Writes `calib/undistorted/torus/` (COLMAP's PINHOLE text model of the undistorted
photographs: the reference the converted files are checked against) and, under <work>
(default /tmp/torus_undistorted), a scene scantex can texture: `images/` (COLMAP's
undistorted photographs), `masks/` (the sample's masks resampled the same way, nearest
neighbour), `sparse/0` and `mesh.ply`. The scene is not committed.

    pip install pycolmap==4.2.1 numpy pillow
    python3 calib/undistorted/make.py [work]
"""
import os
import shutil
import sys

import numpy as np
import pycolmap
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, "..", ".."))
SAMPLE = os.path.join(ROOT, "samples", "torus")


def main(work):
    if os.path.exists(work):
        shutil.rmtree(work)
    pycolmap.undistort_images(work, os.path.join(SAMPLE, "sparse", "0"), os.path.join(SAMPLE, "images"))
    rec = pycolmap.Reconstruction(os.path.join(work, "sparse"))
    src = pycolmap.Reconstruction(os.path.join(SAMPLE, "sparse", "0"))
    os.makedirs(os.path.join(work, "masks"))
    by_name = {im.name: im for im in src.images.values()}
    for im in rec.images.values():
        cam = rec.cameras[im.camera_id]
        scam = src.cameras[by_name[im.name].camera_id]
        stem = os.path.splitext(im.name)[0]
        mask = np.asarray(Image.open(os.path.join(SAMPLE, "masks", stem + ".png")).convert("L"))
        # Each undistorted pixel centre -> its ray -> the distorted camera's pixel.
        ys, xs = np.mgrid[0:cam.height, 0:cam.width]
        pix = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], axis=1)
        rays = cam.cam_from_img(pix)
        src_pix = scam.img_from_cam(np.concatenate([rays, np.ones((len(rays), 1))], axis=1))
        sx = np.clip(np.floor(src_pix[:, 0]).astype(int), 0, scam.width - 1)
        sy = np.clip(np.floor(src_pix[:, 1]).astype(int), 0, scam.height - 1)
        out = mask[sy, sx].reshape(cam.height, cam.width)
        Image.fromarray(out).save(os.path.join(work, "masks", stem + ".png"))
    os.makedirs(os.path.join(work, "sparse", "0"))
    for f in os.listdir(os.path.join(work, "sparse")):
        if f.endswith(".bin"):
            shutil.move(os.path.join(work, "sparse", f), os.path.join(work, "sparse", "0", f))
    shutil.copy(os.path.join(SAMPLE, "mesh.ply"), os.path.join(work, "mesh.ply"))
    ref = os.path.join(HERE, "torus")
    os.makedirs(ref, exist_ok=True)
    rec.write_text(ref)
    # Only cameras and poses are needed as the reference: keep the files small.
    lines = open(os.path.join(ref, "images.txt")).read().split("\n")
    head = [l for l in lines if l.startswith("#")]
    body = [l for l in lines if l and not l.startswith("#")]
    with open(os.path.join(ref, "images.txt"), "w") as f:
        f.write("\n".join(head) + "\n")
        for k in range(0, len(body), 2):
            f.write(body[k] + "\n\n")
    with open(os.path.join(ref, "points3D.txt"), "w") as f:
        f.write("# 3D point list with one line of data per point: none kept\n")
    shutil.rmtree(os.path.join(work, "stereo"), ignore_errors=True)
    for f in ("run-colmap-geometric.sh", "run-colmap-photometric.sh"):
        p = os.path.join(work, f)
        if os.path.exists(p):
            os.remove(p)
    print(f"{len(rec.images)} photographs undistorted into {work}; model in {ref}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "/tmp/torus_undistorted")
