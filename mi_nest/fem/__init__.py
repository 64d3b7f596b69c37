"""Linear-elastic FEM (scikit-fem) producing nodal stress on tetrahedral meshes.

``meshing`` builds meshes (BSD primitives; gmsh optional), ``regions`` and
``loads`` describe where forces and fixtures act, ``solve`` assembles and
solves and recovers nodal stress as a :class:`~mi_nest.fields.mesh.TetMeshStress`,
``spec`` reads a whole model from TOML/JSON (``mi-nest fem --spec``).
"""
from .config import FemError
from .loads import (Fixture, NodeForces, PointForce, Pressure, SurfaceForce, Traction, check_rigid_modes,
                    rigid_body_modes)
from .meshing import (BoxGeometry, CylinderGeometry, MeshFileGeometry, TubeGeometry, mesh_surface,
                      read_volume_mesh)
from .regions import Box, CylindricalSurface, Group, NearestNode, Nodes, Plane, Predicate, Sphere
from .solve import FemResult, Material, SolveReport, SolverConfig, solve
from .spec import FemSpec, file_boundary_conditions, load_spec, spec_from_flags

__all__ = ["FemError", "Fixture", "NodeForces", "PointForce", "Pressure", "SurfaceForce", "Traction", "check_rigid_modes",
           "rigid_body_modes", "BoxGeometry", "CylinderGeometry", "MeshFileGeometry", "TubeGeometry",
           "mesh_surface", "read_volume_mesh", "Box", "CylindricalSurface", "Group", "NearestNode", "Nodes", "Plane", "Predicate",
           "Sphere", "FemResult", "Material", "SolveReport", "SolverConfig", "solve", "FemSpec", "load_spec",
           "spec_from_flags", "file_boundary_conditions"]
