#!/usr/bin/env python3
"""Writes the seed corpora under fuzz/seeds/<target>/ (stdlib only; run from the repo root).

Small valid files (excerpts of the committed fixtures, hand-made meshes, tiny datasets) and
hand-made bad ones (lying counts, truncations, non-finite values). Re-running overwrites.
Optional input: a model file (argv[1] or $PANOMAN_FUZZ_MODEL, default
<tmp>/panoman-examples/small.safetensors) for the model seed, stripped of its large optional
tensors (the embedded rig, the MLPs).
"""
import json, os, struct, sys, tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEEDS = os.path.join(ROOT, "fuzz", "seeds")
MOCAP = os.path.join(ROOT, "crates", "panoman-mocap", "tests", "data")
ORACLE = os.path.join(ROOT, "fixtures", "anny-oracle")


def put(target, name, data):
    d = os.path.join(SEEDS, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def safetensors(tensors, meta=None):
    """tensors: [(name, dtype, shape, bytes)] -> safetensors bytes."""
    h, off, body = {}, 0, b""
    if meta:
        h["__metadata__"] = meta
    for name, dt, shape, data in tensors:
        h[name] = {"dtype": dt, "shape": shape, "data_offsets": [off, off + len(data)]}
        off += len(data)
        body += data
    hb = json.dumps(h, separators=(",", ":")).encode()
    hb += b" " * ((8 - len(hb) % 8) % 8)
    return struct.pack("<Q", len(hb)) + hb + body


def f32(*v):
    return struct.pack("<%df" % len(v), *v)


def f64(*v):
    return struct.pack("<%dd" % len(v), *v)


def u32(*v):
    return struct.pack("<%dI" % len(v), *v)


def lines_head(path, n):
    with open(path, "rb") as f:
        return b"".join(f.readlines()[:n])


# --- OBJ / PLY -------------------------------------------------------------------------
OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvn 0 0 1\nvt 0 0\nf 1/1/1 2/1/1 3/1/1\nf 1 3 4\nf -1 -2 -3\n"
put("obj", "tetra.obj", OBJ)
put("obj", "quad.obj", "o q\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\ns off\nf 1 2 3 4\n")
put("obj", "bad_index.obj", "v 0 0 0\nv 1 0 0\nf 1 2 99999999999\n")
put("obj", "nan.obj", "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
ply_hdr = "ply\nformat {fmt} 1.0\ncomment x\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\nelement face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
put("ply", "ascii.ply", ply_hdr.format(fmt="ascii", nv=4, nf=2) + "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 3\n")
binv = f32(0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1)
binf = b"".join(b"\x03" + struct.pack("<3i", *t) for t in [(0, 1, 2), (0, 2, 3)])
put("ply", "binle.ply", ply_hdr.format(fmt="binary_little_endian", nv=4, nf=2).encode() + binv + binf)
bev = struct.pack(">12f", 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1)
bef = b"".join(b"\x03" + struct.pack(">3i", *t) for t in [(0, 1, 2), (0, 2, 3)])
put("ply", "binbe.ply", ply_hdr.format(fmt="binary_big_endian", nv=4, nf=2).encode() + bev + bef)
put("ply", "lying_counts.ply", ply_hdr.format(fmt="binary_little_endian", nv=4000000000, nf=4000000000).encode() + binv)
# Fuzz finding (2026-12-04): an element without properties and a lying count; its rows take
# no bytes, so the binary reader looped for ever (a libFuzzer timeout).
put("ply", "empty_element_rows.ply", "ply\nformat binary_big_endian 1.0\nelement padding 99999999999994\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n".encode() + struct.pack(">3f", 0, 0, 1))
put("ply", "points_double.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nproperty uchar red\nend_header\n".encode()
    + b"".join(f64(i, i * 0.5, 1) + b"\x07" for i in range(3)))

# --- npy ---------------------------------------------------------------------------------
def npy(descr, shape, data):
    h = "{'descr': '%s', 'fortran_order': False, 'shape': %s, }" % (descr, shape)
    while (10 + len(h) + 1) % 64:
        h += " "
    h += "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(h)) + h.encode() + data


put("npy", "points_f8.npy", npy("<f8", "(3, 3)", f64(*range(9))))
put("npy", "f4.npy", npy("<f4", "(2, 3)", f32(*range(6))))
put("npy", "i8.npy", npy("<i8", "(4,)", struct.pack("<4q", 1, 2, 3, -4)))
put("npy", "i4.npy", npy("<i4", "(2, 2)", struct.pack("<4i", 1, 2, 3, 4)))
put("npy", "lying_shape.npy", npy("<f8", "(100000000000, 3)", f64(1, 2, 3)))
put("npy", "overflow_shape.npy", npy("<f8", "(4294967296, 4294967296, 4294967296)", b""))
with open(os.path.join(ORACLE, "case_default_bone_heads.npy"), "rb") as f:
    put("npy", "oracle_bone_heads.npy", f.read())

# --- keypoints (TC-127), handles, params ------------------------------------------------
put("keypoints", "tc127.json", json.dumps({"keypoints": {"pelvis": [0, 0, 1], "neck": [0, 0, 1.5], "head_top": [0, 0.1, 1.8]}, "weights": {"pelvis": 2.0}}))
put("keypoints", "nan.json", '{"keypoints": {"pelvis": [NaN, 0, 1]}}')
put("keypoints", "dup.json", '{"keypoints": {"pelvis": [0, 0, 1], "pelvis": [1, 1, 1]}, "weights": {"nope": -1}}')
for name in ("case_default.json",):
    with open(os.path.join(ORACLE, name), "rb") as f:
        put("keypoints", "oracle_" + name, f.read())
put("handles", "ok.json", json.dumps({"handles": [{"vertex": 12, "position": [0, 0.5, 1], "weight": 1}, {"vertex": 0, "position": [1, 0, 0], "weight": 0.5}]}))
put("handles", "bad.json", '{"handles": [{"vertex": 18446744073709551615, "position": [1e300, 0, 0], "weight": -1}]}')
put("params", "ok.json", json.dumps({"alpha": [0.1, -0.2, 0, 0, 0, 0], "beta": {"body_l": [0.5] * 25, "face_a": [0.0] * 13}, "translation": [0, 0, 1], "rotation": [0, 0.1, 0]}))
put("params", "bad.json", '{"alpha": [1e999], "beta": {"nope": []}, "translation": [0, 0]}')
put("params", "empty.json", "{}")

# --- OpenPose / Panoptic / TC-127 via the interchange importer -------------------------
pose = [float(i % 7) for i in range(25 * 4)]
put("keypoints_in", "openpose.json", "\0" + json.dumps({"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_3d": pose, "face_keypoints_3d": [0.0] * (70 * 4), "hand_left_keypoints_3d": [1.0] * (21 * 4), "hand_right_keypoints_3d": []}]}))
put("keypoints_in", "panoptic.json", "\x05" + json.dumps({"version": 0.7, "univTime": 1.0, "fpsType": "hd_29_97", "bodies": [{"id": 0, "joints19": [float(i % 5) for i in range(19 * 4)]}]}))
put("keypoints_in", "tc127.json", "\x01" + json.dumps({"keypoints": {"pelvis": [0, 0, 1]}}))
put("keypoints_in", "bad_openpose.json", '\x02{"people": [{"pose_keypoints_3d": [1, 2, 3]}], "bodies": []}')

# --- mocap: excerpts of the committed fixtures + bad ones ------------------------------
put("bvh", "01_01_excerpt.bvh", lines_head(os.path.join(MOCAP, "01_01_head.bvh"), 200))
put("bvh", "tiny.bvh", "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n JOINT Chest\n {\n  OFFSET 0 5 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 3 0\n  }\n }\n}\nMOTION\nFrames: 2\nFrame Time: 0.033333\n0 0 0 0 0 0 1 2 3\n1 1 1 10 20 30 4 5 6\n")
put("bvh", "lying_frames.bvh", "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 99999999999999\nFrame Time: 0.01\n1 2 3\n")
put("csm", "thomas_excerpt.csm", lines_head(os.path.join(MOCAP, "ThomasFechten_head.csm"), 40))
put("vsk", "nick01.vsk", open(os.path.join(MOCAP, "Nick01.vsk"), "rb").read())
put("vsk", "tiny.vsk", '<?xml version="1.0"?>\n<KinematicModel><Parameters><Parameter NAME="a" VALUE="1"/></Parameters><Skeleton><Segment NAME="Pelvis" POSITION="0 0 0"><Segment NAME="Thigh" POSITION="0 0 -400"/></Segment></Skeleton><MarkerSet><Markers><Marker NAME="LASI" SEGMENT="Pelvis" POSITION="10 20 30"/></Markers><Sticks/></MarkerSet></KinematicModel>\n')
with open(os.path.join(MOCAP, "nick_freeform_001_head.c3d"), "rb") as f:
    c3d = f.read()
put("c3d", "nick_head.c3d", c3d)
put("c3d", "nick_head_truncated.c3d", c3d[:4096])

# --- safetensors store, model, dataset -------------------------------------------------
store = safetensors([("a.weight", "F32", [2, 3], f32(*range(6))), ("b", "F64", [2], f64(1, 2)),
                     ("i", "U32", [3], u32(1, 2, 3)), ("k", "U8", [4], b"\x00\x01\x02\x03"),
                     ("l", "I64", [1], struct.pack("<q", -7))], {"panoman.model": "{}"})
put("store", "small.safetensors", store)
mlp = safetensors([("m.layer0.weight", "F32", [2, 2], f32(1, 0, 0, 1)), ("m.layer0.bias", "F32", [2], f32(0, 0)),
                   ("m.input_mean", "F32", [2], f32(0, 0)), ("m.input_scale", "F32", [2], f32(1, 1)),
                   ("m.output_mean", "F32", [2], f32(0, 0)), ("m.output_scale", "F32", [2], f32(1, 1))],
                  {"m": json.dumps({"activation": "relu"})})
put("store", "mlp.safetensors", mlp)
put("store", "lying_header.safetensors", struct.pack("<Q", 1 << 40) + b"{}")
put("store", "bad_offsets.safetensors", struct.pack("<Q", 64) + json.dumps({"x": {"dtype": "F32", "shape": [1 << 30, 1 << 30], "data_offsets": [0, 4]}}).encode().ljust(64) + b"\0\0\0\0")

model = sys.argv[1] if len(sys.argv) > 1 else os.environ.get("PANOMAN_FUZZ_MODEL") or os.path.join(tempfile.gettempdir(), "panoman-examples", "small.safetensors")
if os.path.exists(model):
    with open(model, "rb") as f:
        n = struct.unpack("<Q", f.read(8))[0]
        h = json.loads(f.read(n))
        base = 8 + n
        keep = []
        for name, info in sorted(h.items(), key=lambda kv: kv[1].get("data_offsets", [0])[0] if kv[0] != "__metadata__" else -1):
            if name == "__metadata__" or name.startswith(("rig.", "correction.", "motion.")):
                continue
            a, b = info["data_offsets"]
            f.seek(base + a)
            keep.append((name, info["dtype"], info["shape"], f.read(b - a)))
        meta = {k: v for k, v in h.get("__metadata__", {}).items() if k == "panoman.model"}
        # The header records which optional parts exist; drop them so that the seed is valid.
        hdr = json.loads(meta["panoman.model"])
        hdr["correction"] = False
        hdr["motion_bones"] = None
        meta["panoman.model"] = json.dumps(hdr)
        put("model", "small_no_rig.safetensors", safetensors(keep, meta))
        # rig.postcard: the first 4 KiB (the magic, then the start of the postcard body).
        info = h["rig.postcard"]
        f.seek(base + info["data_offsets"][0])
        put("rigfile", "rig_head_4k.bin", b"\0" + f.read(4096))
        # The correction MLP alone (config in the metadata) for the store target.
        mlp_t = []
        for name, info in sorted(h.items(), key=lambda kv: kv[1].get("data_offsets", [0])[0] if kv[0] != "__metadata__" else -1):
            if name.startswith("correction.mlp."):
                a, b = info["data_offsets"]
                f.seek(base + a)
                mlp_t.append((name, info["dtype"], info["shape"], f.read(b - a)))
        put("store", "correction_mlp.safetensors", safetensors(mlp_t, {"correction.mlp": h["__metadata__"]["correction.mlp"]}))
else:
    print("no model file at %s: the model corpus has only the store seeds" % model)
put("model", "store_small.safetensors", store)
# rigfile: first byte ≢ 0 (mod 8) → the target prepends the magic (see fuzz_targets/rigfile.rs).
put("rigfile", "empty_body.bin", b"\x01")
put("rigfile", "short_body.bin", b"\x01" + bytes([3, 0, 1, 2, 255, 255, 255, 255, 15]))
put("rigfile", "wrong_magic.bin", b"\x00panoman-rig-v999" + bytes(8))

# Dataset: input = dataset.json, the separator, dataset.safetensors (see fuzz_targets/dataset.rs).
SEP = b"\n#SAFETENSORS#\n"
def dataset(n_v, bones, rows, n_id, train, held):
    """rows: [(kind, identity, rest_of)]"""
    n = len(rows)
    p = 3 * len(bones)
    counts = {k: sum(1 for r in rows if r[0] == i) for i, k in enumerate(["rest", "body", "face", "hand"])}
    meta = {"format": "panoman-dataset", "format_version": 1, "n_rows": n, "n_identities": n_id,
            "topology": {"hash": "0123456789abcdef", "n_vertices": n_v, "n_triangles": 1, "name": "small"},
            "theta": {"bones": bones}, "split": {"train": train, "held_out": held}, "counts": counts}
    st = safetensors([("vertices", "F32", [n, n_v, 3], f32(*[0.5] * (n * n_v * 3))),
                      ("theta", "F32", [n, p], f32(*[0.1] * (n * p))),
                      ("phenotype", "F32", [n, 6], f32(*[0.5] * (n * 6))),
                      ("face_units", "F32", [n, 52], f32(*[0.0] * (n * 52))),
                      ("identity", "U32", [n], u32(*[r[1] for r in rows])),
                      ("rest_of", "U32", [n], u32(*[r[2] for r in rows])),
                      ("kind", "U8", [n], bytes(r[0] for r in rows))],
                     {"format": "panoman-dataset", "topology_hash": "0123456789abcdef"})
    return json.dumps(meta).encode() + SEP + st
put("dataset", "one_row.bin", dataset(3, ["spine05"], [(0, 0, 0)], 1, [0], []))
put("dataset", "two_ids.bin", dataset(2, ["spine05", "head"], [(0, 0, 0), (1, 0, 0), (0, 1, 2), (3, 1, 2)], 2, [0], [1]))
put("dataset", "lying_ids.bin", dataset(1, [], [(0, 0, 0)], 10**15, [0], []))
put("dataset", "repeated_id.bin", dataset(1, ["head"], [(0, 0, 0)], 257, [0] * 257, []))
no_rows = dataset(1, ["head"], [(0, 0, 0)], 1, [0], []).replace(b'"n_rows": 1', b'"n_rows": 0').replace(b'"n_vertices": 1', b'"n_vertices": 1099511627776')
put("dataset", "no_rows_huge_vertices.bin", no_rows)

# Point clouds (read_points): first byte picks the extension (even: .ply, odd: .obj).
put("points", "ply.bin", b"\x00" + (ply_hdr.format(fmt="ascii", nv=4, nf=0) + "0 0 0\n0.5 0 0\n0 0.5 0\n0 0 0.5\n").encode())
put("points", "obj.bin", b"\x01" + OBJ.encode())

print("seeds written under", SEEDS)
