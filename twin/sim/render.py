"""Headless pictures of the twin for reports (EGL or OSMesa; GLFW needs a display).

MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when ``mujoco`` is first imported; without a
display :mod:`twin` defaults it to ``egl`` (set ``MUJOCO_GL=osmesa`` yourself for OSMesa).
:func:`render_png` raises :class:`RenderError` naming what to install or set when no backend works.
"""

from __future__ import annotations

import os
from pathlib import Path

import mujoco
import numpy as np

__all__ = ["RenderError", "TwinCamera", "render_png"]


class RenderError(RuntimeError):
    """No OpenGL backend could render; the message says how to get one."""


class TwinCamera:
    """An offscreen camera on a plant: :meth:`render` gives the twin as it is now, as pixels.

    Args:
        plant: a :class:`twin.sim.plant.Plant`.
        width, height: image size (pixels).
        azimuth_deg, elevation_deg, distance_m: free camera looking at the middle of the
            backbone; the default looks along world +y at the horizontal endoscope's bending plane.

    Raises:
        RenderError: no OpenGL context could be created.
    """

    def __init__(self, plant, *, width: int = 640, height: int = 480, azimuth_deg: float = 90.0,
                 elevation_deg: float = -10.0, distance_m: float = 0.16):
        self._plant = plant
        try:
            self._renderer = mujoco.Renderer(plant.model, height=height, width=width)
        except Exception as exc:  # the backends raise different types (RuntimeError, FatalError, ...)
            raise RenderError(
                f"no OpenGL backend for headless rendering (MUJOCO_GL={os.environ.get('MUJOCO_GL', 'unset')}): "
                f"{exc}. Install Mesa's EGL (Debian: libegl1 libegl-mesa0) or OSMesa (libosmesa6) and set "
                "MUJOCO_GL=egl or MUJOCO_GL=osmesa before importing mujoco."
            ) from exc
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._camera.azimuth, self._camera.elevation, self._camera.distance = azimuth_deg, elevation_deg, distance_m

    def render(self) -> np.ndarray:
        """(height, width, 3) uint8 RGB of the twin now, the camera on the backbone's middle."""
        self._camera.lookat[:] = self._plant.backbone_positions_m().mean(axis=0)
        self._renderer.update_scene(self._plant.data, self._camera)
        return np.ascontiguousarray(self._renderer.render())

    def close(self) -> None:
        self._renderer.close()


def render_png(plant, path: str | Path, **camera) -> Path:
    """Render the plant's current state to a PNG file; ``camera``: :class:`TwinCamera`'s options.

    Raises:
        RenderError: no OpenGL context could be created.
    """
    import matplotlib.image

    view = TwinCamera(plant, **camera)
    try:
        pixels = view.render()
    finally:
        view.close()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(path, pixels)
    return path
