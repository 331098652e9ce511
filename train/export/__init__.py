"""Exports of predicted patches: welded triangle OBJ, quad mesh (ILP subdivision), IGES NURBS."""
