"""Exports of predicted patches: welded triangle OBJ, quad mesh (ILP subdivision), sewn STEP solid
(OpenCASCADE), IGES NURBS, in chosen CAD units; a CAD read-back preview (cad_view)."""
