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

__all__ = ["RenderError", "render_png"]


class RenderError(RuntimeError):
    """No OpenGL backend could render; the message says how to get one."""


def render_png(plant, path: str | Path, *, width: int = 640, height: int = 480,
               azimuth_deg: float = 90.0, elevation_deg: float = -10.0, distance_m: float = 0.16) -> Path:
    """Render the plant's current state to a PNG file.

    Args:
        plant: a :class:`twin.sim.plant.Plant` (its model and data are drawn as they are).
        path: output file.
        width, height: image size (pixels).
        azimuth_deg, elevation_deg, distance_m: free camera looking at the middle of the
            backbone; the default looks along world +y at the horizontal endoscope's bending plane.

    Returns:
        The path written.

    Raises:
        RenderError: no OpenGL context could be created.
    """
    import matplotlib.image

    model, data = plant.model, plant.data
    try:
        renderer = mujoco.Renderer(model, height=height, width=width)
    except Exception as exc:  # the backends raise different types (RuntimeError, FatalError, ...)
        raise RenderError(
            f"no OpenGL backend for headless rendering (MUJOCO_GL={os.environ.get('MUJOCO_GL', 'unset')}): "
            f"{exc}. Install Mesa's EGL (Debian: libegl1 libegl-mesa0) or OSMesa (libosmesa6) and set "
            "MUJOCO_GL=egl or MUJOCO_GL=osmesa before importing mujoco."
        ) from exc
    try:
        camera = mujoco.MjvCamera()
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        camera.lookat[:] = plant.backbone_positions_m().mean(axis=0)
        camera.azimuth, camera.elevation, camera.distance = azimuth_deg, elevation_deg, distance_m
        renderer.update_scene(data, camera)
        pixels = renderer.render()
    finally:
        renderer.close()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(path, np.ascontiguousarray(pixels))
    return path
