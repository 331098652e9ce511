"""Length units and scale of the CAD exports (STEP, IGES).

Predictions live in the unit-sphere frame of the training data (a model is about 2 units
across), which has no physical size. CAD files need one: ``CadUnits(units, scale)`` writes model
coordinates × ``scale`` and declares them in ``units``. Without a scale, one model unit becomes
``DEFAULT_MODEL_UNIT_MM`` (100 mm) whatever the declared unit, so a prediction opens about 20 cm
across — a desk-sized object rather than the 2 m a bare "metres" declaration gave.
"""

from __future__ import annotations

import dataclasses

from pipeline.core.settings_io import setting
from train.errors import UsageError

MM_PER_UNIT = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
DEFAULT_UNITS = "mm"
DEFAULT_MODEL_UNIT_MM = 100.0
# IGES 5.3 global section: units flag and name; STEP: OpenCASCADE's "write.step.unit" value
_IGES = {"mm": (2, "MM"), "cm": (10, "CM"), "m": (6, "M"), "in": (1, "INCH")}
_STEP = {"mm": "MM", "cm": "CM", "m": "M", "in": "INCH"}


@dataclasses.dataclass(frozen=True)
class CadUnits:
    units: str = DEFAULT_UNITS
    scale: float | None = None  # file units per model unit; None: 100 mm expressed in ``units``

    def __post_init__(self) -> None:
        if self.units not in MM_PER_UNIT:
            raise ValueError(f"unknown units {self.units!r}; use one of {', '.join(MM_PER_UNIT)}")
        if self.scale is not None and not self.scale > 0:
            raise ValueError(f"scale must be positive, got {self.scale}")

    @property
    def factor(self) -> float:
        """Multiplier from model coordinates to the numbers written in the file."""
        return self.scale if self.scale is not None else DEFAULT_MODEL_UNIT_MM / MM_PER_UNIT[self.units]

    @property
    def mm(self) -> float:
        """Millimetres per model unit (what a CAD reader that works in mm will see)."""
        return self.factor * MM_PER_UNIT[self.units]

    @property
    def iges(self) -> tuple[int, str]:
        return _IGES[self.units]

    @property
    def step(self) -> str:
        return _STEP[self.units]

    def describe(self) -> dict:
        return {"units": self.units, "scale": self.factor, "mm_per_model_unit": self.mm}


@dataclasses.dataclass(frozen=True, kw_only=True)
class CadFileSettings:
    """The ``--units`` / ``--scale`` flags of every command that writes CAD files (predict,
    export-fit, serve): subclass it, and ``cad_units()`` gives the checked ``CadUnits``."""

    units: str = setting(
        DEFAULT_UNITS, f"length unit declared in patches.stp / patches.igs: {', '.join(sorted(MM_PER_UNIT))}"
    )
    scale: float | None = setting(
        None, f"CAD file units per model unit (default: {DEFAULT_MODEL_UNIT_MM:g} mm in --units, ~20 cm across)"
    )

    def cad_units(self) -> CadUnits:
        try:
            return CadUnits(self.units, self.scale)
        except ValueError as exc:
            raise UsageError(f"--units/--scale: {exc}") from None
