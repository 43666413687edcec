"""PanoMan full-human model: load a model once, then pose, encode, fit and track with it.

Python bindings of the Rust library ``panoman`` (one native module, ``panoman._panoman``).
Units: metres and radians (axis-angle); world frame Z up, the character faces -Y.

Inputs are any array-like (numpy arrays in C or F order, CPU torch tensors, nested lists) of
float32/float64 (integers are accepted too), converted once to float64; outputs are numpy
arrays (float64 positions, int64 faces). Errors are :class:`panoman.Error` subclasses
(:class:`InvalidError` and :class:`FormatError` are ``ValueError`` s, :class:`FileError` an
``OSError``).

Example::

    import panoman
    model = panoman.Model.load(panoman.training.small_model())
    mesh = model.pose()                           # (V, 3) metres: the mean shape
    kp = model.keypoints(mesh)                    # (133, 3)
    fit = panoman.Fitter(model).fit(keypoints=kp)
    print(fit.report["keypoint_residuals"]["body"]["mean_mm"])
"""

from ._errors import Error, FileError, FormatError, InternalError, InvalidError, NumericalError
from ._panoman import (
    FitResult,
    Fitter,
    Generator,
    Model,
    Params,
    Tracker,
    __version__,
    keypoint_names,
)
from . import assets, io, training

__all__ = [
    "Error",
    "InvalidError",
    "FormatError",
    "FileError",
    "NumericalError",
    "InternalError",
    "Model",
    "Params",
    "Fitter",
    "FitResult",
    "Tracker",
    "Generator",
    "generate",
    "keypoint_names",
    "assets",
    "io",
    "training",
    "__version__",
]


def generate(params, topology="full", model=None):
    """The posed mesh ``(V, 3)`` float64 (metres) of generator parameters.

    ``params``: a dict or JSON text in the layout of ``docs/formats.md`` (phenotype, face
    units, local changes, per-bone Euler XYZ angles in degrees, root rotation/translation).
    ``topology``: ``"anny"`` (13,718 vertices), ``"full"`` (13,348) or ``"small"`` (1,229).
    ``model``: take the generator embedded in this :class:`Model` (no asset access); by
    default it is loaded from the asset tree (fetched with pip on first use).
    """
    gen = Generator.from_model(model) if model is not None else Generator.load()
    return gen.generate(params, topology)
