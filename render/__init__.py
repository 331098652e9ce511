"""Blender Freestyle contour rendering: camera rigs, scene set-up, stroke capture, batch runner."""
