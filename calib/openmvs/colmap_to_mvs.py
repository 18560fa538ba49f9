#!/usr/bin/env python3
"""Writes a COLMAP text model of pinhole cameras as an OpenMVS interface archive (`.mvs`),
laid out as OpenMVS's `libs/MVS/Interface.h` defines it: an `MVSI` header with the version
(none for version 0), then little-endian u64-counted vectors and strings, u32 ids and
row-major f64 matrices.

As OpenMVS's `InterfaceCOLMAP` writes them: COLMAP's fx, fy, cx, cy go into K as they are;
version 0 stores no resolution, so K is divided by max(width, height) (`--normalize` in
OpenMVS writes version 0 the same way). With `--rig`, each camera sits on its platform with a
rotation and an offset, and each image's platform pose is made so that the camera's pose is
COLMAP's, as on a multi-camera rig; without it the camera's own pose is the identity, as
`InterfaceCOLMAP` writes.

Usage (the undistorted sample of calib/undistorted/make.py):
    python3 calib/openmvs/colmap_to_mvs.py calib/undistorted/torus calib/openmvs/torus_v1.mvs 1
    python3 calib/openmvs/colmap_to_mvs.py calib/undistorted/torus calib/openmvs/torus_v0.mvs 0
    python3 calib/openmvs/colmap_to_mvs.py calib/undistorted/torus calib/openmvs/torus_v7_rig.mvs 7 --rig
"""
import math
import os
import struct
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from colmap_text import quat_to_matrix, read_cameras, read_images  # noqa: E402


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def transpose(a):
    return [[a[j][i] for j in range(3)] for i in range(3)]


def apply(a, v):
    return [sum(a[i][k] * v[k] for k in range(3)) for i in range(3)]


class Out:
    def __init__(self):
        self.b = bytearray()

    def u32(self, v):
        self.b += struct.pack("<I", v)

    def u64(self, v):
        self.b += struct.pack("<Q", v)

    def f32(self, v):
        self.b += struct.pack("<f", v)

    def f64s(self, vals):
        self.b += struct.pack(f"<{len(vals)}d", *vals)

    def string(self, s):
        data = s.encode()
        self.u64(len(data))
        self.b += data


def main(model, out_path, version, rig):
    cams = read_cameras(model)
    images = read_images(model)
    cam_ids = sorted(cams, key=int)
    # The rig's camera-on-platform rotation (about a tilted axis) and offset.
    a = 0.3
    rc = quat_to_matrix(math.cos(a / 2), math.sin(a / 2) * 0.6, math.sin(a / 2) * 0.8, 0.0) if rig else \
        [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    cc = [0.05, -0.02, 0.1] if rig else [0.0, 0.0, 0.0]
    o = Out()
    if version > 0:
        o.b += b"MVSI"
        o.u32(version)
        o.u32(0)
    # Platforms: one per COLMAP camera, its images' poses on it.
    poses = {cid: [] for cid in cam_ids}
    pose_of = {}
    for iid, p, cid, name in images:
        r = quat_to_matrix(*p[:4])
        c = [-v for v in apply(transpose(r), p[4:7])]
        # Camera pose = (rc * R_pose, R_pose^T cc + C_pose) must equal (r, c).
        rp = matmul(transpose(rc), r)
        cp = [c[i] - apply(transpose(rp), cc)[i] for i in range(3)]
        pose_of[iid] = (cid, len(poses[cid]))
        poses[cid].append((rp, cp))
    o.u64(len(cam_ids))
    for cid in cam_ids:
        model_name, w, h, q = cams[cid]
        if model_name == "SIMPLE_PINHOLE":
            q = [q[0], q[0], q[1], q[2]]
        elif model_name != "PINHOLE":
            sys.exit(f"camera {cid}: {model_name} is not a pinhole camera (undistort first)")
        fx, fy, cx, cy = q
        s = 1.0 / max(w, h) if version == 0 else 1.0
        o.string(f"platform{int(cid):03d}")
        o.u64(1)
        o.string(model_name)
        if version > 3:
            o.string("RGB")
        if version > 0:
            o.u32(w)
            o.u32(h)
        o.f64s([fx * s, 0.0, cx * s, 0.0, fy * s, cy * s, 0.0, 0.0, 1.0])
        o.f64s([v for row in rc for v in row])
        o.f64s(cc)
        o.u64(len(poses[cid]))
        for rp, cp in poses[cid]:
            o.f64s([v for row in rp for v in row])
            o.f64s(cp)
    o.u64(len(images))
    for iid, p, cid, name in images:
        o.string(f"images/{name}")
        if version > 4:
            o.string("")
        o.u32(cam_ids.index(cid))
        o.u32(0)
        o.u32(pose_of[iid][1])
        if version > 2:
            o.u32(iid)
        if version > 6:
            for v in (0.0, 0.0, 0.0):
                o.f32(v)
            o.u64(0)
    for _ in range(3):  # vertices, normals, colours
        o.u64(0)
    if version > 0:
        for _ in range(3):  # lines, their normals and colours
            o.u64(0)
        if version > 1:
            o.f64s([1.0 if i % 5 == 0 else 0.0 for i in range(16)])
            if version > 5:
                o.f64s([1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0])
    with open(out_path, "wb") as f:
        f.write(o.b)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]), "--rig" in sys.argv[4:])
