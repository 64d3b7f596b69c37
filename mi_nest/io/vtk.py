"""Stress fields as VTK unstructured grids (``.vtu`` via meshio) for ParaView.

Point data: ``stress`` (the full tensor, 9 components, row-major), the principal
stresses ``sigma_1 >= sigma_2 >= sigma_3`` and their unit directions
``sigma_1_direction``... (vectors: ParaView's Glyph and Stream Tracer filters take
them; a direction is a line, signed by its largest component, see
``physics.tensors.principal_axes``), their difference ``sigma_1 - sigma_3`` and the
von Mises stress. A deviatoric field (a reconstruction: photoelasticity does not
see the mean stress) is written under its own names, ``deviatoric_stress``,
``s_1 >= s_2 >= s_3``, ``s_1_direction``... and ``s_1_minus_s_3``, so that it is
never read as the full stress.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..physics.tensors import principal_axes, stress_matrices, von_mises


def point_data(stress6: np.ndarray, deviatoric: bool = False) -> dict[str, np.ndarray]:
    principal, directions = principal_axes(stress6)
    tensor, prefix = ("deviatoric_stress", "s") if deviatoric else ("stress", "sigma")
    data = {tensor: stress_matrices(stress6).reshape(-1, 9)}
    for k in range(3):
        data[f"{prefix}_{k + 1}"] = principal[:, k]
        data[f"{prefix}_{k + 1}_direction"] = directions[:, k]
    return {**data, f"{prefix}_1_minus_{prefix}_3": principal[:, 0] - principal[:, 2], "von_mises": von_mises(stress6)}


def write_mesh_vtu(path: str | Path, nodes: np.ndarray, cells: np.ndarray, stress6: np.ndarray,
                   deviatoric: bool = False, extra: dict[str, np.ndarray] | None = None) -> None:
    """Tetrahedra (M, 4) or hexahedra (M, 8), VTK node order; ``deviatoric`` names the arrays as such;
    ``extra`` point data is written beside them (a reconstruction's trust map)."""
    import meshio
    cells = np.asarray(cells)
    kind = {4: "tetra", 8: "hexahedron"}[cells.shape[1]]
    data = {**point_data(stress6, deviatoric), **(extra or {})}
    meshio.Mesh(np.asarray(nodes, np.float64), [(kind, cells)], point_data=data).write(str(Path(path)))

