"""Data-stage logic: sources, preparation, splits, shards, manifest. No Luigi in here."""

__version__ = "0.1.0"
