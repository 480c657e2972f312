#!/usr/bin/env python3
"""Refine an .off triangle mesh to about N vertices by splitting its longest edges at their
midpoints (each split edge's two triangles become four; no triangle has two split edges).
The surface is unchanged, the original vertices keep their indices (so a ground truth by
vertex index still holds for them) and new vertices are appended. Used by scan-times.sh to
time a scan of a given size from a TOSCA shape.
    scripts/split-edges.py IN.off OUT.off VERTICES
"""
import math
import sys


def read_off(path):
    with open(path) as f:
        words = [w for line in f for w in line.split("#")[0].split()]
    if not words or words[0] != "OFF":
        sys.exit(f"split-edges.py: {path}: not an OFF file")
    nv, nf = int(words[1]), int(words[2])
    pos = 4
    verts = []
    for _ in range(nv):
        verts.append([float(w) for w in words[pos:pos + 3]])
        pos += 3
    faces = []
    for _ in range(nf):
        k = int(words[pos])
        if k != 3:
            sys.exit(f"split-edges.py: {path}: face with {k} vertices (triangles only)")
        faces.append([int(w) for w in words[pos + 1:pos + 4]])
        pos += 4
    return verts, faces


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    src, dst, target = sys.argv[1], sys.argv[2], int(sys.argv[3])
    verts, faces = read_off(src)
    wanted = target - len(verts)
    if wanted <= 0:
        sys.exit(f"split-edges.py: {src} already has {len(verts)} vertices")
    edge_faces = {}
    for fi, f in enumerate(faces):
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            edge_faces.setdefault((min(a, b), max(a, b)), []).append(fi)
    edges = sorted(edge_faces, key=lambda e: -math.dist(verts[e[0]], verts[e[1]]))
    used = [False] * len(faces)
    chosen = []
    for e in edges:
        fs = edge_faces[e]
        if len(fs) <= 2 and not any(used[fi] for fi in fs):
            for fi in fs:
                used[fi] = True
            chosen.append(e)
            if len(chosen) == wanted:
                break
    if len(chosen) < wanted:
        sys.exit(f"split-edges.py: only {len(chosen)} independent edges, {wanted} wanted")
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
    with open(dst, "w") as f:
        f.write(f"OFF\n{len(verts)} {len(out_faces)} 0\n")
        f.writelines(f"{x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in verts)
        f.writelines(f"3 {a} {b} {c}\n" for a, b, c in out_faces)


if __name__ == "__main__":
    main()
