"""Meshes and what is built from them once: validation and files, the operators, the
regularizers, line fields, tetrahedralization and sampling on grids."""
