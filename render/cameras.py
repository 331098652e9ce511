"""Camera rigs in pure numpy, exported in the contract's OpenCV convention.

World: y up, the prepared model centred at the origin with radius ≤ 1, front facing −z.
Camera (OpenCV): x right, y down, z forward. Pixels: (u, v) from the image's top-left corner,
pixel i covering [i, i+1), so the principal point of an S×S image is (S/2, S/2).
Azimuth 0° puts the camera in front of the model (on −z); 90° on +x; elevation lifts it toward +y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from render.rigs import RIGS
from render.settings import RenderSettings


@dataclass(frozen=True)
class View:
    azimuth_deg: float
    elevation_deg: float
    distance: float
    orthographic: bool
    K: np.ndarray  # 3x3
    world_to_camera: np.ndarray  # 4x4, OpenCV axes
    projection: np.ndarray  # 3x4, homogeneous world -> homogeneous pixel

    @property
    def eye(self) -> np.ndarray:
        R, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -R.T @ t

    def to_json(self) -> dict:
        return {
            "azimuth_deg": self.azimuth_deg,
            "elevation_deg": self.elevation_deg,
            "distance": self.distance,
            "orthographic": self.orthographic,
            "K": self.K.tolist(),
            "world_to_camera": self.world_to_camera.tolist(),
            "projection": self.projection.tolist(),
        }


def eye_position(azimuth_deg: float, elevation_deg: float, distance: float) -> np.ndarray:
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return distance * np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])


def look_at(eye: np.ndarray, target: np.ndarray | None = None) -> np.ndarray:
    """4x4 world→camera (OpenCV) for a camera at ``eye`` looking at ``target`` with world y up."""
    target = np.zeros(3) if target is None else np.asarray(target, float)
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    up = np.array([0.0, 1.0, 0.0])
    if abs(forward @ up) > 0.999:  # looking straight down/up: let image-up point to the back (+z)
        up = np.array([0.0, 0.0, 1.0 if forward[1] < 0 else -1.0])
    right = _cross(forward, up)
    right /= np.linalg.norm(right)
    down = _cross(forward, right)
    R = np.stack([right, down, forward])
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = -R @ eye
    return M


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors, the same products and differences (identical floats),
    without its axis handling (~10 µs a call, 72 calls a model with the representative rig)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def intrinsics(settings: RenderSettings) -> np.ndarray:
    S = settings.image_size
    if settings.orthographic:
        f = S / settings.ortho_scale  # pixels per world unit
    else:
        f = S * settings.lens_mm / settings.sensor_mm
    return np.array([[f, 0.0, S / 2.0], [0.0, f, S / 2.0], [0.0, 0.0, 1.0]])


def make_view(settings: RenderSettings, azimuth_deg: float, elevation_deg: float) -> View:
    K = intrinsics(settings)
    w2c = look_at(eye_position(azimuth_deg, elevation_deg, settings.distance))
    if settings.orthographic:
        # Affine camera: drop perspective division by replacing the depth row with [0 0 0 1].
        Rt = np.vstack([w2c[:2], [0.0, 0.0, 0.0, 1.0]])
    else:
        Rt = w2c[:3]
    return View(
        float(azimuth_deg), float(elevation_deg), float(settings.distance), settings.orthographic, K, w2c, K @ Rt
    )


def rig(settings: RenderSettings, seed: int, category: str, model_id: str, vertices: np.ndarray) -> list[View]:
    """The views of one model from its rig (``render.rigs``): seeded by (seed, "render",
    category, model_id) only; ``vertices`` is the mesh they draw (a rig may pick views by it)."""
    pairs = RIGS[settings.rig](settings, seed, category, model_id, np.asarray(vertices, float))
    return [make_view(settings, az, el) for az, el in pairs]


def project(projection: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,3) world points → (n,2) pixel (u, v) with the stored 3x4 projection."""
    P = np.asarray(projection, float)
    h = np.c_[points, np.ones(len(points))] @ P.T
    return h[:, :2] / h[:, 2:3]


def blender_matrix_world(view: View) -> np.ndarray:
    """Blender camera object matrix (camera looks down its local −Z, +Y up) for a view."""
    R = view.world_to_camera[:3, :3]
    M = np.eye(4)
    # Columns: Blender X = OpenCV x (right), Blender Y = −OpenCV y (up), Blender Z = −OpenCV z.
    M[:3, 0], M[:3, 1], M[:3, 2] = R[0], -R[1], -R[2]
    M[:3, 3] = view.eye
    return M
