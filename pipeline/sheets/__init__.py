"""Contact sheets that only read files: the dataset's shards (``python -m pipeline preview``) and
the procedural shapes. The stage sheets, which run stages, are in workflows/sheets."""
