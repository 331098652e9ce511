"""Raster → centerline strokes, stroke augmentation, and the procedural pencil rasterizer."""
