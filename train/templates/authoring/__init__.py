"""Offline template authoring: templates built from part cuboids (the shipped categories), from a
user's meshes or from a cuboid file, with the paper's rules (median model, optional parts, mirror
symmetry, patch budget) and the checks a template must pass. Training and export never import
this: they load the finished template (``train.templates``)."""
