"""Models from the assets. Only the small example model is bound (``panoman train`` and
``panoman synth`` build full models from the command line)."""

from ._panoman import small_model

__all__ = ["small_model"]
