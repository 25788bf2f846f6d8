"""twin: a hardware-in-the-loop digital twin of a tendon-driven flexible endoscope."""

import os

from twin import resources

# Compiled kernels go to the per-user cache, not beside the (maybe installed) sources; numba
# reads this when first imported, which the imports below do.
resources.use_user_cache_for_numba()

if not os.environ.get("DISPLAY"):
    # Without a display GLFW cannot render; MuJoCo picks its GL backend when it is first
    # imported (twin.sim, and twin.tracking's eigensolver), so choose headless EGL before any
    # twin module imports mujoco.
    os.environ.setdefault("MUJOCO_GL", "egl")

from twin.params import DEFAULT_PARAMS_PATH, ParameterError, Params, load_params

__all__ = ["DEFAULT_PARAMS_PATH", "ParameterError", "Params", "load_params"]
__version__ = "0.1.0"
