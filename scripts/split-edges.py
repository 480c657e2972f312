#!/usr/bin/env python3
"""Refine an .off triangle mesh to about N vertices by splitting its longest edges at their
midpoints (each split edge's two triangles become four; no triangle has two split edges).
The surface is unchanged, the original vertices keep their indices (so a ground truth by
vertex index still holds for them) and new vertices are appended. Used by scan-times.sh to
time a scan of a given size from a TOSCA shape.
    scripts/split-edges.py IN.off OUT.off VERTICES
With --class, the meshes of a class that share their vertex indexing (TOSCA poses: the same
vertices, their triangles differ in places) are refined alike: the edges split are the longest
(on the first mesh) among those all of them have, no triangle of any of them split twice, so
new vertex k is the midpoint of the same edge in every pose and the indexing stays shared.
    scripts/split-edges.py --class OUT_DIR VERTICES MESH.off...
"""
import math
import os
import sys

import off_io


def read_off(path):
    verts, faces = off_io.read_off(path)
    if any(len(f) != 3 for f in faces):
        sys.exit(f"split-edges.py: {path}: a face that is not a triangle (triangles only)")
    return verts, faces


def choose_edges(meshes, wanted, src):
    """The `wanted` longest edges (on the first mesh) that every mesh has, no triangle of any
    mesh holding two of them; boundary and interior edges alike."""
    verts = meshes[0][0]
    edge_faces = []
    for _, faces in meshes:
        ef = {}
        for fi, f in enumerate(faces):
            for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
                ef.setdefault((min(a, b), max(a, b)), []).append(fi)
        edge_faces.append(ef)
    common = [e for e in edge_faces[0] if all(e in ef and len(ef[e]) <= 2 for ef in edge_faces)]
    common.sort(key=lambda e: -math.dist(verts[e[0]], verts[e[1]]))
    used = [[False] * len(faces) for _, faces in meshes]
    chosen = []
    for e in common:
        if any(used[m][fi] for m, ef in enumerate(edge_faces) for fi in ef[e]):
            continue
        for m, ef in enumerate(edge_faces):
            for fi in ef[e]:
                used[m][fi] = True
        chosen.append(e)
        if len(chosen) == wanted:
            return chosen
    sys.exit(f"split-edges.py: {src}: only {len(chosen)} independent edges, {wanted} wanted")


def refine(verts, faces, chosen):
    verts = [list(v) for v in verts]
    split = {}
    for a, b in chosen:
        split[(a, b)] = len(verts)
        verts.append([(x + y) / 2 for x, y in zip(verts[a], verts[b])])
    out_faces = []
    for f in faces:
        for i in range(3):
            a, b, c = f[i], f[(i + 1) % 3], f[(i + 2) % 3]
            m = split.get((min(a, b), max(a, b)))
            if m is not None:
                out_faces += [[a, m, c], [m, b, c]]
                break
        else:
            out_faces.append(f)
    return verts, out_faces


def write_off(path, verts, faces):
    with open(path, "w") as f:
        f.write(f"OFF\n{len(verts)} {len(faces)} 0\n")
        f.writelines(f"{x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in verts)
        f.writelines(f"3 {a} {b} {c}\n" for a, b, c in faces)


def main():
    args = sys.argv[1:]
    if len(args) >= 4 and args[0] == "--class":
        out_dir, target, paths = args[1], int(args[2]), args[3:]
        outs = [os.path.join(out_dir, os.path.basename(p)) for p in paths]
    elif len(args) == 3:
        paths, outs, target = [args[0]], [args[1]], int(args[2])
    else:
        sys.exit(__doc__)
    meshes = [read_off(p) for p in paths]
    n = len(meshes[0][0])
    if any(len(v) != n for v, _ in meshes):
        sys.exit("split-edges.py: the meshes do not have the same number of vertices")
    wanted = target - n
    if wanted <= 0:
        sys.exit(f"split-edges.py: {paths[0]} already has {n} vertices")
    chosen = choose_edges(meshes, wanted, paths[0])
    for (verts, faces), out in zip(meshes, outs):
        write_off(out, *refine(verts, faces, chosen))


if __name__ == "__main__":
    main()
