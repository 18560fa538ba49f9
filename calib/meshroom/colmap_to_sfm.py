"""Writes a COLMAP text model as a Meshroom / AliceVision `cameras.sfm` (file version 1.2.6),
the layout AliceVision's own writer uses (src/aliceVision/sfmDataIO/jsonIO.cpp):

- focal length in millimetres on a 36 mm sensor width, `pixelRatio` = fy / fx;
- principal point as an offset from the image centre (COLMAP's cx - w / 2: AliceVision's
  COLMAP exporter writes w / 2 + offset as cx, with no half-pixel shift);
- SIMPLE_RADIAL (f, cx, cy, k) as `radial1` (k1 = k), PINHOLE / SIMPLE_PINHOLE as `pinhole`;
- pose `rotation` = the world-to-camera matrix in Eigen's column-major order, `center` = the
  camera centre -R^T t;
- every number as a string, as AliceVision writes them, and view paths as Windows paths (as
  Meshroom run on Windows leaves them) so the reader's file-name split is exercised.

Usage: python3 calib/meshroom/colmap_to_sfm.py samples/torus/sparse/0 calib/meshroom/torus_cameras.sfm
"""
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from colmap_text import quat_to_matrix, read_cameras, read_images  # noqa: E402


def s(v):
    return repr(float(v))


def main(model, out):
    cams = read_cameras(model)
    intrinsics = []
    for cid, (model_name, w, h, p) in sorted(cams.items(), key=lambda kv: int(kv[0])):
        if model_name == "SIMPLE_RADIAL":
            fx = fy = p[0]
            cx, cy, dist, ty = p[1], p[2], [s(p[3])], "radial1"
        elif model_name == "SIMPLE_PINHOLE":
            fx = fy = p[0]
            cx, cy, dist, ty = p[1], p[2], "", "pinhole"
        elif model_name == "PINHOLE":
            fx, fy, cx, cy = p
            dist, ty = "", "pinhole"
        else:
            sys.exit(f"camera {cid}: {model_name} is not converted by this script")
        intrinsics.append({
            "intrinsicId": cid, "width": str(w), "height": str(h),
            "sensorWidth": "36", "sensorHeight": s(36.0 * h / w), "serialNumber": "",
            "type": ty, "initializationMode": "calibrated", "initialFocalLength": "-1",
            "focalLength": s(fx * 36.0 / w), "pixelRatio": s(fy / fx), "pixelRatioLocked": "true",
            "principalPoint": [s(cx - w / 2), s(cy - h / 2)],
            "distortionInitializationMode": "none", "distortionParams": dist,
            "undistortionOffset": ["0", "0"], "undistortionParams": "", "locked": "true",
        })
    views, poses = [], []
    for iid, p, cid, name in read_images(model):
        q, tr = p[:4], p[4:7]
        r = quat_to_matrix(*q)
        centre = [-sum(r[i][j] * tr[i] for i in range(3)) for j in range(3)]
        column_major = [r[i][j] for j in range(3) for i in range(3)]
        pid = str(1000 + int(iid))
        w, h = cams[cid][1], cams[cid][2]
        views.append({"viewId": str(2000 + int(iid)), "poseId": pid, "intrinsicId": cid,
                      "path": f"C:\\scans\\torus\\images\\{name}", "width": str(w), "height": str(h),
                      "metadata": ""})
        poses.append({"poseId": pid, "pose": {"transform": {
            "rotation": [s(v) for v in column_major], "center": [s(v) for v in centre]},
            "locked": "1", "valid": "1"}})
    doc = {"version": ["1", "2", "6"], "views": views, "intrinsics": intrinsics, "poses": poses}
    with open(out, "w") as f:
        json.dump(doc, f, indent=4)
        f.write("\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
