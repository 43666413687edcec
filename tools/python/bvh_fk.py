"""Joint positions of a BVH file by forward kinematics, read with the PyPI `bvh` package.

A second reader for the tests of `panoman mocap export`, independent of panoman's own
(`crates/panoman-mocap/src/bvh.rs`): the `bvh` package parses the file, this script
composes the transforms in float64.

    python bvh_fk.py FILE.bvh OUT.json

OUT.json: {"frames": N, "joints": {name: [[x, y, z] per frame]}} in the file's units.
"""
import json
import math
import sys

from bvh import Bvh


def axis_matrix(axis, degrees):
    """Rotation by `degrees` about the x, y or z axis (3x3, row-major)."""
    c = math.cos(math.radians(degrees))
    s = math.sin(math.radians(degrees))
    if axis == "X":
        return [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
    if axis == "Y":
        return [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    return [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def apply(m, v):
    return [sum(m[i][k] * v[k] for k in range(3)) for i in range(3)]


def main():
    src, out = sys.argv[1], sys.argv[2]
    with open(src) as f:
        mocap = Bvh(f.read())
    names = mocap.get_joints_names()
    parent = {}
    for n in names:
        p = mocap.joint_parent(n)
        parent[n] = p.name if p is not None else None
    channels = {n: mocap.joint_channels(n) for n in names}
    offsets = {n: mocap.joint_offset(n) for n in names}
    result = {n: [] for n in names}
    for frame in range(mocap.nframes):
        world = {}
        for n in names:  # parents come before their children in file order
            values = mocap.frame_joint_channels(frame, n, channels[n]) if channels[n] else []
            local_r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            local_t = list(offsets[n])
            for ch, v in zip(channels[n], values):
                if ch.endswith("position"):
                    local_t["XYZ".index(ch[0])] += v
                else:
                    local_r = matmul(local_r, axis_matrix(ch[0], v))
            if parent[n] is None:
                world[n] = (local_r, local_t)
            else:
                pr, pt = world[parent[n]]
                t = apply(pr, local_t)
                world[n] = (matmul(pr, local_r), [pt[i] + t[i] for i in range(3)])
            result[n].append(world[n][1])
    with open(out, "w") as f:
        json.dump({"frames": mocap.nframes, "joints": result}, f)


if __name__ == "__main__":
    main()
