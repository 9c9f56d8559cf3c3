"""The package's version (one owner: the package, the wheel's metadata and ``microg --version`` read it)."""

__version__ = "0.27.0"
