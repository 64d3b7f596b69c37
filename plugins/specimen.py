from __future__ import annotations

import mitsuba as mi
import numpy as np

from mi_nest.fields.sources import load_mesh

from .stress import resolve_path

# Properties handed on to the interior stress medium.
_MEDIUM_PROPERTIES = ("stress_optic_coefficient", "fringe_value", "wavelength", "grid_resolution")


class Specimen(mi.Mesh):
    r"""
    .. _shape-specimen:

    Specimen from a stress file (:monosp:`specimen`)
    ------------------------------------------------

    .. pluginparameters::

     * - filename
       - |string|
       - A 3D-TSV ``.TSV``/``.stress`` file (tetrahedra or hexahedra), a
         ``.TSVcarti``/``.carti`` grid, or a mesh ``.npz``
         from ``mi-nest fem`` (``nodes``, ``cells``, nodal ``stress``). Lengths mm,
         stress MPa.

     * - stress_optic_coefficient, fringe_value, wavelength, grid_resolution
       - |float|
       - Material and resampling of the interior ``stress`` medium (see there).

    One shape that is both the boundary surface of the file's mesh (the faces
    used by exactly one cell, oriented outwards) and, as its interior, a
    ``stress`` medium holding the file's nodal stress. Coordinates are the
    file's own.

    .. tabs::

        .. code-tab:: xml

            <shape type="specimen">
                <string name="filename" value="kitten.stress"/>
                <float name="fringe_value" value="100"/>
            </shape>
    """

    def __init__(self, props):
        filename = resolve_path(props["filename"])
        mesh = load_mesh(filename)
        medium = {"type": "stress", "filename": filename}
        for key in _MEDIUM_PROPERTIES:
            if key in props:
                medium[key] = props[key]
        props["interior"] = mi.load_dict(medium)
        super().__init__("specimen", len(mesh.nodes), len(mesh.surface), props)
        params = mi.traverse(self)
        params["vertex_positions"] = mi.Float(mesh.nodes.astype(np.float32).ravel())
        params["faces"] = mi.UInt32(mesh.surface.astype(np.uint32).ravel())
        params.update()
        self.filename = filename
        self.cell_count = len(mesh.tets)

    def to_string(self) -> str:
        return f"Specimen[filename={self.filename}, vertices={self.vertex_count()}, faces={self.face_count()}]"


mi.register_shape("specimen", lambda props: Specimen(props))
