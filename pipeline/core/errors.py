"""Errors that name the offending file and the reason, so a batch can record and move on."""

from __future__ import annotations

from pathlib import Path


class ModelError(Exception):
    """One model failed a stage. Recorded in the batch/manifest; never stops the batch."""

    def __init__(self, path: str | Path, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")

    def to_json(self) -> dict:
        return {"path": self.path, "reason": self.reason}
