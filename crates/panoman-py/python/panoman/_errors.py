"""The exceptions of panoman: every failure of the library is a :class:`Error`.

The messages are the one-line messages the ``panoman`` command prints after ``error:``
(for a file: ``<path>: <what is wrong>``).
"""

__all__ = ["Error", "InvalidError", "FormatError", "FileError", "NumericalError", "InternalError"]


class Error(Exception):
    """Base class of every panoman error."""


class InvalidError(Error, ValueError):
    """An argument is invalid: wrong shape or dtype, non-finite values, unknown keypoint or
    block names, parameters that do not fit the model, nothing to fit."""


class FormatError(Error, ValueError):
    """A file is malformed or inconsistent with the model (not a model, corrupt, wrong
    sizes); the message starts with the file's path."""


class FileError(Error, OSError):
    """A file could not be read or written (missing, unreadable), or the assets are missing
    and could not be fetched; the message starts with the path."""


class NumericalError(Error, RuntimeError):
    """A numerical failure (a factorization or solve that did not succeed)."""


class InternalError(Error, RuntimeError):
    """A bug: a panic inside the Rust library, caught at the boundary (the interpreter keeps
    running)."""
