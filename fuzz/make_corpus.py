#!/usr/bin/env python3
"""Writes the small seed corpora in fuzz/corpus/<target>/ (committed). Needs only the standard
library and a built scantex (cargo build --release), which writes the GLB and the JPEG.

    python3 fuzz/make_corpus.py
"""
import os, struct, subprocess, tempfile, zlib

HERE = os.path.dirname(os.path.abspath(__file__))
SCANTEX = os.path.join(HERE, "..", "target", "release", "scantex")


def put(target, name, data):
    d = os.path.join(HERE, "corpus", target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data if isinstance(data, bytes) else data.encode())


def png(w, h, channels, depth, pixel):
    color = {1: 0, 3: 2}[channels]
    raw = b""
    for y in range(h):
        raw += b"\0"
        for x in range(w):
            for v in pixel(x, y)[:channels]:
                raw += struct.pack(">H", v * 257) if depth == 16 else bytes([v])
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    ihdr = struct.pack(">IIBBBBB", w, h, depth, color, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


TETRA_V = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
TETRA_F = [(0, 2, 1), (0, 1, 3), (1, 2, 3), (0, 3, 2)]

obj = "".join(f"v {x} {y} {z}\n" for x, y, z in TETRA_V) + "".join(
    f"f {a+1} {b+1} {c+1}\n" for a, b, c in TETRA_F)
put("obj", "tetra.obj", obj)
put("obj", "uv_normals.obj", obj.split("f ")[0] + "vt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1\nf 1/1 3/3 4/2\n")

hdr = "ply\nformat {}\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
put("ply", "ascii.ply", hdr.format("ascii 1.0") + "".join(f"{x} {y} {z}\n" for x, y, z in TETRA_V)
    + "".join(f"3 {a} {b} {c}\n" for a, b, c in TETRA_F))
put("ply", "binary.ply", hdr.format("binary_little_endian 1.0").encode()
    + b"".join(struct.pack("<3f", *v) for v in TETRA_V)
    + b"".join(struct.pack("<B3i", 3, *f) for f in TETRA_F))

# One PINHOLE camera, two images observing three points (as tests/it/bad_input.rs builds).
cams = "1 PINHOLE 64 48 50 50 32 24\n"
imgs = ""
obs = {}
for iid in (1, 2):
    pts = []
    for k, (pid, (x, y, z)) in enumerate(zip((1, 2, 3), TETRA_V[:3])):
        tx = 0.1 * iid
        u = 50 * (x + tx) / (z + 5) + 32
        v = 50 * y / (z + 5) + 24
        pts.append((u, v, pid))
        obs.setdefault(pid, []).append((iid, k))
    imgs += f"{iid} 1 0 0 0 {0.1 * iid} 0 5 1 img{iid}.png\n" + " ".join(f"{u} {v} {p}" for u, v, p in pts) + "\n"
pts3 = "".join(f"{pid} {x} {y} {z} 1 2 3 0.0 " + " ".join(f"{i} {k}" for i, k in obs[pid]) + "\n"
               for pid, (x, y, z) in zip((1, 2, 3), TETRA_V[:3]))
put("colmap_text", "tetra", cams + "\0" + imgs + "\0" + pts3)

cb = struct.pack("<Q", 1) + struct.pack("<IiQQ", 1, 1, 64, 48) + struct.pack("<4d", 50, 50, 32, 24)
ib = struct.pack("<Q", 2)
for iid in (1, 2):
    ib += struct.pack("<I4d3dI", iid, 1, 0, 0, 0, 0.1 * iid, 0, 5, 1) + f"img{iid}.png".encode() + b"\0"
    ib += struct.pack("<Q", 3) + b"".join(struct.pack("<2dQ", 10.0 + k, 12.0, k + 1) for k in range(3))
pb = struct.pack("<Q", 3) + b"".join(
    struct.pack("<Q3d3BdQ", pid, *TETRA_V[pid - 1], 1, 2, 3, 0.0, 2)
    + struct.pack("<IIII", 1, pid - 1, 2, pid - 1) for pid in (1, 2, 3))
put("colmap_binary", "cameras.bin", cb)
put("colmap_binary", "images.bin", ib)
put("colmap_binary", "points3D.bin", pb)

put("image_mask", "rgb8.png", png(8, 6, 3, 8, lambda x, y: (x * 30, y * 40, 128)))
put("image_mask", "grey16.png", png(5, 4, 1, 16, lambda x, y: (x * 50,)))
with tempfile.TemporaryDirectory() as t:
    src, mask = os.path.join(t, "a.png"), os.path.join(t, "m.png")
    open(src, "wb").write(png(8, 8, 3, 8, lambda x, y: (x * 30, y * 30, 90)))
    open(mask, "wb").write(png(8, 8, 1, 8, lambda x, y: (255 if (x, y) == (3, 3) else 0,)))
    subprocess.run([SCANTEX, "inpaint", src, "--mask", mask, "-o", os.path.join(t, "a.jpg")], check=True,
                   capture_output=True)
    put("image_mask", "rgb.jpg", open(os.path.join(t, "a.jpg"), "rb").read())
    o = os.path.join(t, "tetra.obj")
    open(o, "w").write(obj)
    subprocess.run([SCANTEX, "param", o, "-o", os.path.join(t, "tetra.glb"), "--size", "64", "--gutter", "1"],
                   check=True, capture_output=True)
    put("gltf", "tetra.glb", open(os.path.join(t, "tetra.glb"), "rb").read())
put("gltf", "minimal.gltf", '{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],'
    '"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],'
    '"buffers":[{"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA","byteLength":36}],'
    '"bufferViews":[{"buffer":0,"byteLength":36}],'
    '"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}]}')
print("wrote", os.path.join(HERE, "corpus"))
