"""Stage 0: where models come from (source layouts, mesh formats)."""
