"""Settings of the fit stage (``BuildSettings.fit_patches``): the category's template fitted to
every prepared model. Here, in the base layer, because both sides read them: the build hashes
them into the stage's folder (workflows) and the stage's own process fits with them
(``train.patch_fit``, which the dataset side runs but never imports)."""

from __future__ import annotations

import dataclasses

from pipeline.core.settings_io import setting


@dataclasses.dataclass(frozen=True)
class PatchFitSettings:
    """How the template is fitted: Adam on its parameters against the model's surface samples,
    the training loss (the collision term at ``collision``), parts masked as in training."""

    steps: int = setting(150, "Adam steps per model")
    lr: float = setting(0.01, "Adam learning rate")
    points: int = setting(4000, "target surface points per model: a seeded subset of prepare's samples")
    collision: float = setting(
        0.0,
        "weight of the collision term in the fit (0: off, the cheapest; fits made without it may "
        "cross themselves, and a network taught them with --w-fit learns the crossings)",
    )
    templates: tuple[str, ...] = setting(
        (), "CATEGORY=TEMPLATE pairs (a category name, sphere24, sphere54 or a file); default: the category's own"
    )

    def __post_init__(self) -> None:
        for name, low in (("steps", 1), ("points", 64)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"PatchFitSettings.{name} must be an integer >= {low}, got {value!r}")
        if not self.collision >= 0:
            raise ValueError(f"PatchFitSettings.collision must be >= 0, got {self.collision!r}")
        if not self.lr > 0:
            raise ValueError(f"PatchFitSettings.lr must be > 0, got {self.lr!r}")
        for item in self.templates:
            category, sep, template = item.partition("=")
            if not (sep and category and template):
                raise ValueError(f"PatchFitSettings.templates: {item!r} is not CATEGORY=TEMPLATE")

    def template_for(self, category: str) -> str:
        """The template fitted to ``category``'s models: its pair in ``templates``, else its own name."""
        named = dict(item.partition("=")[::2] for item in self.templates)
        return named.get(category, category)
