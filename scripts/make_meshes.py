"""Regenerate the closed meshes shipped in scenes/meshes/ (unit sizes; scenes scale them).

    python scripts/make_meshes.py
"""
from pathlib import Path

import numpy as np
import trimesh

MESHES = Path(__file__).resolve().parents[1] / "scenes" / "meshes"


def disk(sections=256):
    """Closed cylinder, diameter 1 and height 1 along z, centred at the origin."""
    return trimesh.creation.cylinder(radius=0.5, height=1.0, sections=sections)


def tube(inner_ratio=0.5, sections=256):
    """Hollow cylinder, outer diameter 1, inner diameter ``inner_ratio``, height 1 along z."""
    return trimesh.creation.annulus(r_min=0.5 * inner_ratio, r_max=0.5, height=1.0, sections=sections)


def plate_with_hole(hole_ratio=0.2, sections=256):
    """Square plate of side 1 and thickness 1 (z), with a central hole of diameter ``hole_ratio``.

    Rings of points on the hole and on the square at the same angles (the
    square's corners among them) are joined by quads, then extruded.
    """
    assert sections % 8 == 0, "corners of the square must be sample angles"
    angle = np.arange(sections) * 2 * np.pi / sections + np.pi / 4
    direction = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    inner = 0.5 * hole_ratio * direction
    outer = 0.5 * direction / np.abs(direction).max(axis=1, keepdims=True)
    ring = np.concatenate([inner, outer])              # 0..n-1 inner, n..2n-1 outer
    vertices = np.concatenate([np.c_[ring, np.full(2 * sections, -0.5)], np.c_[ring, np.full(2 * sections, 0.5)]])
    n, top = sections, 2 * sections
    i = np.arange(n)
    j = (i + 1) % n
    faces = []
    # Bottom (normal -z) and top (normal +z) annular faces.
    faces += [np.c_[i, n + j, n + i], np.c_[i, j, n + j]]
    faces += [np.c_[top + i, top + n + i, top + n + j], np.c_[top + i, top + n + j, top + j]]
    # Hole wall (normal towards the axis) and outer wall (normal outwards).
    faces += [np.c_[i, top + i, top + j], np.c_[i, top + j, j]]
    faces += [np.c_[n + i, n + j, top + n + j], np.c_[n + i, top + n + j, top + n + i]]
    mesh = trimesh.Trimesh(vertices, np.concatenate(faces), process=True)
    mesh.fix_normals()
    return mesh


def main():
    for name, mesh in {"disk": disk(), "tube": tube(), "plate_with_hole": plate_with_hole()}.items():
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0, name
        mesh.export(MESHES / f"{name}.ply")
        print(f"{name}.ply: {len(mesh.faces)} faces, volume {mesh.volume:.4f}")


if __name__ == "__main__":
    main()
