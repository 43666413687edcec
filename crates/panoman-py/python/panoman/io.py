"""Mesh files: OBJ and PLY (the format follows the extension)."""

from ._panoman import read_mesh, write_mesh

__all__ = ["read_mesh", "write_mesh"]
