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

    def render(self, *, target_m=None, floor_grid: bool = False) -> np.ndarray:
        """(height, width, 3) uint8 RGB of the twin now, the camera on the backbone's middle.

        Args:
            target_m: a target tip position (3,), world frame (m), drawn as a green sphere of
                :data:`TARGET_RADIUS_M`; None draws none.
            floor_grid: draw a horizontal grid of :data:`GRID_SPACING_M` squares under the robot
                (the picture's scale: each square is 1 cm) with a red 1 cm bar along world x and a
                blue one along world y at its corner, so a frame shows lengths and directions.
        """
        backbone = self._plant.backbone_positions_m()
        self._camera.lookat[:] = backbone.mean(axis=0)
        self._renderer.update_scene(self._plant.data, self._camera)
        scene = self._renderer.scene
        if floor_grid:
            _add_floor_grid(scene, backbone, target_m)
        if target_m is not None:
            _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, [TARGET_RADIUS_M, 0, 0], np.asarray(target_m, float),
                      (0.1, 0.8, 0.2, 0.8))
        return np.ascontiguousarray(self._renderer.render())

    def close(self) -> None:
        self._renderer.close()


# The target sphere's radius (m): a few millimetres, visible at the default 16 cm camera distance.
TARGET_RADIUS_M = 0.003
# Floor-grid square (m): 1 cm, the scale a reader counts the tip's travel in.
GRID_SPACING_M = 0.01


def _add_geom(scene, kind, size, pos, rgba, *, ends=None, width: float = 0.0) -> bool:
    """Append one decoration geom to ``scene`` (a connector from ``ends[0]`` to ``ends[1]`` when
    given); False when the scene is full."""
    if scene.ngeom >= scene.maxgeom:
        return False
    geom = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(geom, kind, np.asarray(size, float), np.asarray(pos, float), np.eye(3).ravel(),
                        np.asarray(rgba, np.float32))
    if ends is not None:
        mujoco.mjv_connector(geom, kind, width, np.asarray(ends[0], float), np.asarray(ends[1], float))
    scene.ngeom += 1
    return True


def _add_floor_grid(scene, backbone_m: np.ndarray, target_m=None) -> None:
    """A grid of 1 cm squares 1 cm below the lowest of the backbone and the target, covering
    both with a margin, and 1 cm bars along world x (red) and y (blue) at its corner."""
    points = backbone_m if target_m is None else np.vstack([backbone_m, np.asarray(target_m, float)[None]])
    step = GRID_SPACING_M
    low = np.floor(points.min(axis=0) / step) * step - 2 * step
    high = np.ceil(points.max(axis=0) / step) * step + 2 * step
    z = low[2] + step
    grey = (0.55, 0.55, 0.55, 1.0)
    for x in np.arange(low[0], high[0] + step / 2, step):
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_LINE, [0, 0, 0], [0, 0, 0], grey, ends=([x, low[1], z], [x, high[1], z]),
                  width=1.0)
    for y in np.arange(low[1], high[1] + step / 2, step):
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_LINE, [0, 0, 0], [0, 0, 0], grey, ends=([low[0], y, z], [high[0], y, z]),
                  width=1.0)
    corner = np.array([low[0], low[1], z])
    for axis, rgba in ((0, (0.9, 0.1, 0.1, 1.0)), (1, (0.1, 0.2, 0.9, 1.0))):
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_CAPSULE, [0, 0, 0], [0, 0, 0], rgba,
                  ends=(corner, corner + step * np.eye(3)[axis]), width=0.0008)


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
