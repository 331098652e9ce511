"""Coons-patch geometry, templates, losses, the patch-regression model, trainer and export."""
