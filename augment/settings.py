"""Settings of the augment stage (hashed into the stage's folder name).

Lengths and widths are in pixels of a 256-pixel *reference* canvas (``REFERENCE_SIZE``), whatever
the size of the render read or of the sketch written, so one setting means the same look at 128²
(training) and at 512² (previews). Ranges follow what peers use for synthetic sketches
(SynDraw's stroke disturber, SketchRNN-style augmentation; see docs/augment.md):
per-stroke rotation ≤ 2.5°, scale 0.9–1.1, smooth lateral noise, 1–2 overdrawn copies,
ends extended/shortened, width 2.5 ± 0.75 px, splitting p ≈ 0.2–0.5 at 1–3 points with 0–4 px
gaps, stroke drop ≤ 0.1.
"""

from __future__ import annotations

import dataclasses

from pipeline.core.settings_io import setting

REFERENCE_SIZE = 256


@dataclasses.dataclass(frozen=True)
class VectorizeSettings:
    """Raster → centerline strokes. Lengths in pixels of the input image."""

    ink_threshold: int | None = setting(None, "gray level below which a pixel is ink; None = Otsu")
    max_ink_fraction: float = setting(0.5, "more ink than this is not a line drawing → error")
    spur_length: float = setting(5.0, "tip branches shorter than this at a junction are pruned")
    junction_merge: float = setting(3.0, "junction pixels closer than this form one junction")
    join_angle_deg: float = setting(45.0, "branches whose tangents bend less than this continue")
    tangent_length: float = setting(7.0, "arc length used to estimate a branch's end tangent")
    snap_radius: float = setting(4.0, "corner re-snap: snapped point must lie this close")
    corner_angle_deg: float = setting(50.0, "turns sharper than this (over ±tangent_length/2) are corners")
    hole_area: int = setting(6, "ink holes up to this many px are filled (no tiny loops)")
    link_gap: float = setting(3.5, "stroke ends this close, facing each other, are joined")
    link_angle_deg: float = setting(50.0, "... if the gap bends each end's tangent less than this")
    min_stroke_length: float = setting(4.0, "shorter strokes (specks) are dropped")
    smooth_sigma: float = setting(1.0, "Gaussian smoothing of the pixel chain (removes stairs)")
    simplify_epsilon: float = setting(0.4, "Douglas–Peucker tolerance")


@dataclasses.dataclass(frozen=True)
class AugmentSettings:
    """How each rendered view becomes K pencil-sketch variants."""

    variants: int = setting(2, "pencil variants drawn per view")
    out_size: int = setting(128, "sketch size in pixels (square)")
    # One width per variant, in rotation (variant k uses widths[k % len]); SynDraw: 2.5 ± 0.75.
    widths: tuple[float, ...] = setting((1.5, 2.5, 3.5), "stroke widths (reference px), one per variant in rotation")
    vectorize: VectorizeSettings = dataclasses.field(default_factory=VectorizeSettings)
    resample_spacing: float = setting(1.0, "strokes are resampled (Catmull-Rom) at this spacing")

    # Splitting (SynDraw / peers: p ≈ 0.2–0.5, 1–3 points, 0–4 px gaps).
    split_prob: float = setting(0.35, "chance a stroke is split")
    split_max_points: int = setting(3, "at most this many split points per stroke")
    split_gap: tuple[float, float] = setting((0.5, 4.0), "gap range at a split (px)")
    split_min_piece: float = setting(6.0, "never leave a piece shorter than this")
    # Truncation of ends (shorten each end by up to this fraction of the stroke / px).
    truncate_prob: float = setting(0.5, "chance a stroke end is shortened")
    truncate_max_fraction: float = setting(0.12, "at most this fraction of the stroke per end")
    truncate_max_px: float = setting(6.0, "... and at most this many px")
    # Extension / overshoot of ends along their tangent.
    extend_prob: float = setting(0.3, "chance a stroke end overshoots along its tangent")
    extend_max_px: float = setting(4.0, "overshoot length limit (px)")
    # Smooth lateral wobble: amplitude (px) and wavelength (px) of the offset along the normal.
    wobble_amplitude: float = setting(0.8, "smooth sideways wobble amplitude (px)")
    wobble_wavelength: float = setting(40.0, "wobble wavelength along the stroke (px)")
    # Per-stroke similarity jitter (peers: rotation ≤ 2.5°, scale 0.9–1.1).
    jitter_rotation_deg: float = setting(1.5, "per-stroke rotation jitter (degrees)")
    jitter_scale: float = setting(0.03, "per-stroke relative scale jitter")
    # Overdrawn duplicate strokes (peers: 1–2 copies).
    overdraw_prob: float = setting(0.15, "chance a stroke is drawn again beside itself")
    overdraw_max_copies: int = setting(2, "at most this many extra copies")
    overdraw_offset: float = setting(1.2, "copies lie up to this far from the stroke (px)")
    # Dropping strokes (peers: drop ≤ 0.1): short strokes go with drop_short_prob.
    drop_short_length: float = setting(8.0, "strokes shorter than this (px) count as short")
    drop_short_prob: float = setting(0.3, "chance a short stroke is dropped")
    drop_prob: float = setting(0.02, "chance any other stroke is dropped")
    drop_keep_fraction: float = setting(0.5, "dropped strokes return (longest first) to keep this share of ink")

    # Pencil look. Each variant takes the next of ``tones`` and ``shading`` in rotation (as with
    # ``widths``), so the variants span dark thin line drawings and light, broad, shaded ones
    # (the paper's demo sketches: ink darkness 0.23–0.31, 3–9 % of the frame; BENCHMARKS.md).
    tones: tuple[tuple[float, float], ...] = setting(((0.55, 0.95), (0.3, 0.6)), "per-stroke graphite opacity range")
    shading: tuple[float, ...] = setting((0.0, 0.6), "share of strokes given soft tone beside them")
    shade_offset: tuple[float, float] = setting((1.5, 4.0), "tone's distance from its stroke (reference px)")
    shade_tone: float = setting(0.45, "tone's opacity relative to the variant's")
    shade_width: float = setting(2.2, "tone's width relative to the variant's")
    taper_length: float = setting(10.0, "px over which pressure ramps at each end")
    pressure_noise: float = setting(0.15, "slow relative width variation")
    grain: float = setting(0.45, "0 = solid graphite, 1 = only paper tooth")
    paper_mottle: float = setting(0.02, "low-frequency paper brightness variation")
    supersample: int = setting(4, "raster supersampling factor (anti-aliasing)")

    def __post_init__(self) -> None:
        # Overrides arrive as JSON through pipeline.core.settings_io.from_dict, which makes lists
        # tuples and ints floats, so equal settings hash equally.
        if self.variants < 1 or self.out_size < 8:
            raise ValueError("variants must be >= 1 and out_size >= 8")
        if len(self.widths) < 1 or min(self.widths) <= 0:
            raise ValueError(f"widths must be positive: {self.widths}")
        for name in (
            "split_prob",
            "truncate_prob",
            "extend_prob",
            "overdraw_prob",
            "drop_short_prob",
            "drop_prob",
            "drop_keep_fraction",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1]")
        if self.supersample < 1:
            raise ValueError("supersample must be >= 1")
        if not self.tones or any(not (len(t) == 2 and 0.0 <= t[0] <= t[1] <= 1.0) for t in self.tones):
            raise ValueError(f"tones must be (low, high) pairs with 0 <= low <= high <= 1: {self.tones}")
        if not self.shading or any(not 0.0 <= p <= 1.0 for p in self.shading):
            raise ValueError(f"shading must be shares in [0, 1]: {self.shading}")

    def width_for(self, variant: int) -> float:
        """Width (reference px) drawn by ``variant``: the widths in rotation."""
        return float(self.widths[variant % len(self.widths)])

    def tones_for(self, variant: int) -> tuple[float, float]:
        lo, hi = self.tones[variant % len(self.tones)]
        return float(lo), float(hi)

    def shading_for(self, variant: int) -> float:
        return float(self.shading[variant % len(self.shading)])
