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

__all__ = ["RenderError", "TwinCamera", "labelled_figure", "render_png"]


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

    def metres_per_pixel(self) -> float:
        """Image scale (m per pixel) in the plane through the look-at point facing the camera:
        the bending plane of the default view."""
        fovy_rad = np.deg2rad(self._plant.model.vis.global_.fovy)
        return 2.0 * self._camera.distance * np.tan(fovy_rad / 2) / self._renderer.height

    def screen_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """World directions (unit (3,)) of the image's right and up."""
        az, el = np.deg2rad(self._camera.azimuth), np.deg2rad(self._camera.elevation)
        forward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        return right, np.cross(right, forward)

    def render(self) -> np.ndarray:
        """(height, width, 3) uint8 RGB of the twin now, the camera on the backbone's middle."""
        self._camera.lookat[:] = self._plant.backbone_positions_m().mean(axis=0)
        self._renderer.update_scene(self._plant.data, self._camera)
        return np.ascontiguousarray(self._renderer.render())

    def close(self) -> None:
        self._renderer.close()


def render_png(plant, path: str | Path, *, labelled: bool = False, title: str = "", **camera) -> Path:
    """Render the plant's current state to a PNG file; ``camera``: :class:`TwinCamera`'s options.

    Args:
        plant: a :class:`twin.sim.plant.Plant`.
        path: the PNG file.
        labelled: compose the picture for a report: a scale bar (1 cm in the bending plane), the
            world axes along the image's right and up, and ``title``; else the bare pixels
            (``width`` x ``height``).
        title: the labelled picture's title.

    Raises:
        RenderError: no OpenGL context could be created.
    """
    import matplotlib.image

    view = TwinCamera(plant, **camera)
    try:
        pixels = view.render()
        scale_m_per_px = view.metres_per_pixel()
        right, up = view.screen_axes()
    finally:
        view.close()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if labelled:
        labelled_figure(pixels, scale_m_per_px, right, up, title=title).savefig(path, dpi=100)
    else:
        matplotlib.image.imsave(path, pixels)
    return path


def _axis_name(direction: np.ndarray) -> str:
    """'+x', '-z', ... for the world axis nearest ``direction``."""
    k = int(np.argmax(np.abs(direction)))
    return f"{'+' if direction[k] > 0 else '-'}{'xyz'[k]}"


def labelled_figure(pixels: np.ndarray, scale_m_per_px: float, right: np.ndarray, up: np.ndarray, *,
                    title: str = ""):
    """A matplotlib Figure of a rendered picture with a 1 cm scale bar and the world axes of the
    image's right and up (``right``, ``up``: unit world directions), sized to the picture (100 dpi)."""
    from matplotlib.figure import Figure
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    height, width = pixels.shape[:2]
    fig = Figure(figsize=(width / 100, height / 100 + 0.5))
    ax = fig.add_axes((0.0, 0.0, 1.0, height / (height + 50)))
    ax.imshow(pixels)
    ax.set_axis_off()
    ax.add_artist(AnchoredSizeBar(ax.transData, 0.01 / scale_m_per_px, "1 cm (bending plane)", "lower right",
                                  pad=0.5, color="white", frameon=False, size_vertical=2, label_top=True))
    # The world axes along the image's right and up, from the lower left corner.
    x0, y0, arm = 0.04 * width, 0.92 * height, 0.08 * width
    ax.annotate("", (x0 + arm, y0), (x0, y0), arrowprops=dict(arrowstyle="->", color="white"))
    ax.annotate("", (x0, y0 - arm), (x0, y0), arrowprops=dict(arrowstyle="->", color="white"))
    ax.text(x0 + arm, y0 + 0.03 * height, _axis_name(right), color="white", ha="center", va="top", fontsize=8)
    ax.text(x0 - 0.01 * width, y0 - arm, _axis_name(up), color="white", ha="right", va="center", fontsize=8)
    fig.suptitle(title or "the twin (MuJoCo)", y=0.99, va="top", fontsize=10)
    return fig
