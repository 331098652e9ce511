"""Stage 0: where models come from (source layouts, mesh formats, the per-category listing)."""
