"""twin: a hardware-in-the-loop digital twin of a tendon-driven flexible endoscope."""

from twin.params import DEFAULT_PARAMS_PATH, ParameterError, Params, load_params

__all__ = ["DEFAULT_PARAMS_PATH", "ParameterError", "Params", "load_params"]
__version__ = "0.1.0"
