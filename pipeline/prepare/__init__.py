"""Stage 1: source mesh -> watertight, normalized mesh, line mesh and surface samples."""
