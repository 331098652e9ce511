"""Patch templates: the Template model and its file format (template.py), built-in spheres (sphere.py), and a resolver.

Category templates are JSON files in train/templates/data/<category>.json (built by
train/templates/authoring/); templates users build for their own categories go to ./templates/ (the
working folder's). ``load_template`` accepts "sphere24", "sphere54", a category name (shipped,
then ./templates/<name>.json), or a path to a template file.
"""

from __future__ import annotations

from pathlib import Path

from train.templates.sphere import sphere24, sphere54, sphere_template
from train.templates.template import (
    Curve,
    FreePoint,
    JunctionPoint,
    Patch,
    Symmetry,
    Template,
    TemplateError,
    load_template_file,
    save_template,
)

DATA_DIR = Path(__file__).resolve().parent / "data"
USER_DIR = Path("templates")  # resolved against the working folder at lookup time
BUILTIN = {"sphere24": sphere24, "sphere54": sphere54}


def load_template(name_or_path: str | Path) -> Template:
    """Resolve a built-in sphere, a category template under ``DATA_DIR`` or ``./templates/``, or a file path."""
    key = str(name_or_path)
    if key in BUILTIN:
        return BUILTIN[key]()
    candidate, user = DATA_DIR / f"{key}.json", USER_DIR / f"{key}.json"
    if "/" not in key:
        for c in (candidate, user):
            if c.exists():
                return load_template_file(c)
    path = Path(name_or_path)
    if path.exists():
        return load_template_file(path)
    raise TemplateError(f"{key}: no built-in template, no {candidate} or ./{user}, and no such file")


__all__ = [
    "Curve",
    "DATA_DIR",
    "USER_DIR",
    "FreePoint",
    "JunctionPoint",
    "Patch",
    "Symmetry",
    "Template",
    "TemplateError",
    "load_template",
    "load_template_file",
    "save_template",
    "sphere24",
    "sphere54",
    "sphere_template",
]
