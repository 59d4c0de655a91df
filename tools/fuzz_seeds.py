#!/usr/bin/env python3
"""Writes the fuzz targets' seed inputs (fuzz/seeds/TARGET/): one small valid file per format
and variant, made here from the formats' own definitions so that the fuzzer starts past the
magic numbers and headers. Run from the repository root; the output is committed."""
import base64, json, os, struct

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "fuzz", "seeds")


def put(target, name, data):
    d = os.path.join(ROOT, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data if isinstance(data, bytes) else data.encode())


def fnv1a(b):
    h = 0xCBF29CE484222325
    for x in b:
        h = ((h ^ x) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


# --- glTF: a two-triangle quad skinned to two joints, one animation (rotation, translation,
# a CUBICSPLINE scale), a material with a base-colour factor; .gltf with a data URI and .glb.
def gltf_parts():
    pos = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    nrm = [(0, 0, 1)] * 4
    uv = [(0, 0), (1, 0), (1, 1), (0, 1)]
    joints = [(0, 1, 0, 0)] * 4
    weights = [(0.75, 0.25, 0, 0), (0.5, 0.5, 0, 0), (0.25, 0.75, 0, 0), (1, 0, 0, 0)]
    idx = [0, 1, 2, 0, 2, 3]
    ibm = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1] + [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, -1, 0, 1]
    times = [0.0, 1.0]
    rot = [(0, 0, 0, 1), (0, 0, 0.3826834, 0.9238795)]
    tr = [(0, 1, 0), (0.2, 1, 0)]
    scale_cs = [(0, 0, 0), (1, 1, 1), (0, 0, 0), (0, 0, 0), (1.2, 1, 1), (0, 0, 0)]
    chunks = [
        ("VEC3", 5126, 4, b"".join(struct.pack("<3f", *p) for p in pos), [0, 0, 0], [1, 1, 0]),
        ("VEC3", 5126, 4, b"".join(struct.pack("<3f", *p) for p in nrm), None, None),
        ("VEC2", 5126, 4, b"".join(struct.pack("<2f", *p) for p in uv), None, None),
        ("VEC4", 5121, 4, b"".join(struct.pack("<4B", *p) for p in joints), None, None),
        ("VEC4", 5126, 4, b"".join(struct.pack("<4f", *p) for p in weights), None, None),
        ("SCALAR", 5123, 6, b"".join(struct.pack("<H", i) for i in idx), None, None),
        ("MAT4", 5126, 2, b"".join(struct.pack("<f", x) for x in ibm), None, None),
        ("SCALAR", 5126, 2, b"".join(struct.pack("<f", x) for x in times), [0], [1]),
        ("VEC4", 5126, 2, b"".join(struct.pack("<4f", *p) for p in rot), None, None),
        ("VEC3", 5126, 2, b"".join(struct.pack("<3f", *p) for p in tr), None, None),
        ("VEC3", 5126, 6, b"".join(struct.pack("<3f", *p) for p in scale_cs), None, None),
    ]
    buf, views, accs = b"", [], []
    for i, (ty, ct, count, data, mn, mx) in enumerate(chunks):
        while len(buf) % 4:
            buf += b"\0"
        views.append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(data)})
        a = {"bufferView": i, "componentType": ct, "count": count, "type": ty}
        if ct == 5121 and ty == "VEC4" and i == 3:
            pass
        if mn is not None:
            a["min"], a["max"] = mn, mx
        accs.append(a)
        buf += data
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "Body", "mesh": 0, "skin": 0},
            {"name": "root", "children": [2]},
            {"name": "tip", "translation": [0, 1, 0]},
        ],
        "meshes": [{"name": "Head", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2, "JOINTS_0": 3, "WEIGHTS_0": 4},
            "indices": 5, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.6, 0.5, 1]}}],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": 6, "skeleton": 1}],
        "animations": [{"name": "Wave", "samplers": [
            {"input": 7, "output": 8, "interpolation": "LINEAR"},
            {"input": 7, "output": 9, "interpolation": "STEP"},
            {"input": 7, "output": 10, "interpolation": "CUBICSPLINE"}],
            "channels": [
                {"sampler": 0, "target": {"node": 2, "path": "rotation"}},
                {"sampler": 1, "target": {"node": 2, "path": "translation"}},
                {"sampler": 2, "target": {"node": 1, "path": "scale"}}]}],
        "accessors": accs,
        "bufferViews": views,
        "buffers": [{"byteLength": len(buf)}],
    }
    return doc, buf


def glb(doc, buf):
    j = json.dumps(doc, separators=(",", ":")).encode()
    j += b" " * (-len(j) % 4)
    buf += b"\0" * (-len(buf) % 4)
    body = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(buf), 0x004E4942) + buf
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


doc, buf = gltf_parts()
put("gltf", "quad.glb", glb(doc, buf))
d2 = json.loads(json.dumps(doc))
d2["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(buf).decode()
put("gltf", "quad.gltf", json.dumps(d2, indent=1))
d3 = json.loads(json.dumps(d2))
del d3["skins"], d3["nodes"][0]["skin"], d3["animations"]
put("gltf", "static.gltf", json.dumps(d3, indent=1))

# --- OBJ, OFF, PLY (ascii, binary little and big endian, with an extra property).
put("obj", "quad.obj", "# quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "vn 0 0 1\nf 1/1/1 2/2/1 3/3/1 4/4/1\nf -4 -2 -1\n")
put("obj", "tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
put("off", "quad.off", "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n")
put("off", "quad4.off", "OFF\n# comment\n4 1 4\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
verts = [(0, 0, 0, 0.5), (1, 0, 0, 0.25), (1, 1, 0, 1.0), (0, 1, 0, 0.0)]
faces = [(0, 1, 2), (0, 2, 3)]
head = ("ply\nformat {}\ncomment seed\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nproperty float ao\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n")
put("ply", "ascii.ply", head.format("ascii 1.0") + "".join(f"{x} {y} {z} {a}\n" for x, y, z, a in verts)
    + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces))
for name, fmt, e in [("le.ply", "binary_little_endian 1.0", "<"), ("be.ply", "binary_big_endian 1.0", ">")]:
    body = b"".join(struct.pack(e + "4f", *v) for v in verts) + b"".join(struct.pack(e + "B3i", 3, *f) for f in faces)
    put("ply", name, head.format(fmt).encode() + body)

# --- .sph: levels branch, then x y z r importance per node (1 + 2 + 4 nodes).
lines = ["3 2"] + [f"{0.1*i:.7f} {0.2*i:.7f} {0.05*i:.7f} {1.0/(1+i):.7f} {i%3:.7f}" for i in range(7)]
put("sph", "tree.sph", "\n".join(lines) + "\n")

# --- Environment maps: byte 0 selects EXR (odd) or RGBE (even) in the target.
def rgbe(r, g, b):
    m = max(r, g, b)
    if m < 1e-32:
        return bytes(4)
    import math
    e = math.frexp(m)[1]
    s = 256.0 / (2.0 ** e)
    return bytes([int(r * s), int(g * s), int(b * s), e + 128])


w, h = 16, 8
px = [rgbe(0.5 + 0.1 * (x % 3), 0.4, 0.3 + 0.05 * y) if (x, y) != (3, 2) else rgbe(900, 850, 700)
      for y in range(h) for x in range(w)]
put("envmap", "flat.hdr", b"\0" + b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n-Y 8 +X 16\n" + b"".join(px))
# New-style run-length rows need width 8..32767: a 32 x 16 map, each row as 4 channel runs.
w, h = 32, 16
rows = b""
for y in range(h):
    row = [rgbe(1.0 + (x == 5 and y == 4) * 500, 0.8, 0.6) for x in range(w)]
    rows += bytes([2, 2, w >> 8, w & 255])
    for c in range(4):
        vals = bytes(p[c] for p in row)
        rows += bytes([128 + w // 2, vals[0]]) + bytes([w // 2]) + vals[w // 2:]
put("envmap", "rle.hdr", b"\0" + b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16 +X 32\n" + rows)


def exr(width, height, compression, pixel):
    def attr(name, ty, data):
        return name.encode() + b"\0" + ty.encode() + b"\0" + struct.pack("<i", len(data)) + data
    chans = b"".join(c.encode() + b"\0" + struct.pack("<i4Bii", 2, 0, 0, 0, 0, 1, 1) for c in "BGR") + b"\0"
    hdr = (struct.pack("<ii", 20000630, 2) + attr("channels", "chlist", chans)
           + attr("compression", "compression", bytes([compression]))
           + attr("dataWindow", "box2i", struct.pack("<4i", 0, 0, width - 1, height - 1))
           + attr("displayWindow", "box2i", struct.pack("<4i", 0, 0, width - 1, height - 1))
           + attr("lineOrder", "lineOrder", bytes([0]))
           + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
           + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
           + attr("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\0")
    table_at = len(hdr)
    blocks, offs = b"", []
    start = table_at + 8 * height
    for y in range(height):
        line = b""
        for c in range(3):
            line += b"".join(struct.pack("<f", pixel(x, y)[2 - c]) for x in range(width))
        offs.append(start + len(blocks))
        blocks += struct.pack("<ii", y, len(line)) + line
    return hdr + b"".join(struct.pack("<Q", o) for o in offs) + blocks


put("envmap", "flat.exr", b"\1" + exr(16, 8, 0, lambda x, y: (1.0 + 100.0 * (x == 4 and y == 2), 0.7, 0.5 - 0.01 * x)))
put("envmap", "ringing.exr", b"\1" + exr(16, 8, 0, lambda x, y: (50.0 if (x, y) == (8, 3) else (-3.0 if abs(x - 8) == 1 and y == 3 else 0.2), 0.2, 0.2)))

# --- Transfer caches (the target appends the checksum).
k, n = 4, 3
axes = [(0, 0, 1), (1, 0, 0), (0, 1, 0), (0.577, 0.577, 0.577)]
tb = b"VKSGTRF\0" + struct.pack("<IIfQd", 1, k, 4.0, n, 0.01)
tb += b"".join(struct.pack("<3f", *a) for a in axes) + b"".join(struct.pack("<f", 0.1 * i) for i in range(n * k))
put("transfer", "transfer.bin", tb)
m, cl = 1, 2
cb = b"VKSGCPC\0" + struct.pack("<IIIIfQd", 1, k, m, cl, 4.0, n, 0.02)
cb += b"".join(struct.pack("<3f", *a) for a in axes) + b"".join(struct.pack("<I", i % cl) for i in range(n))
cb += b"".join(struct.pack("<f", 0.05 * i) for i in range(cl * (m + 1) * k)) + b"".join(struct.pack("<f", 0.5) for _ in range(n * m))
put("transfer", "transfer.cpca", cb)

# --- btf_dir: a one-texel PNG behind the target's three selector bytes (pair 5, .png; see
# fuzz/fuzz_targets/btf_dir.rs), and a file name for its parse_name branch.
import zlib


def png_chunk(t, d):
    return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)


png = (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0))
       + png_chunk(b"IDAT", zlib.compress(b"\0\x80\x64\x5a")) + png_chunk(b"IEND", b""))
put("btf_dir", "png_1x1", b"\x05\x00\x00" + png)
put("btf_image", "png_1x1", b"\x00" + png)
put("btf_dir", "name", "btf_tl015_pl060_tv030_pv090.png")
# btf_json's seed is the btf.json of `vkshade btf synth --pattern weave --size 4` (committed).
put("btf_image", "flat.exr", b"\x01" + exr(4, 4, 0, lambda x, y: (0.5, 0.25 * x, 0.1 * y)))
