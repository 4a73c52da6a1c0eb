"""cistern-archive: maps, 3D models and reports from stationary sonar scans of flooded sites."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("cistern-archive")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0+unknown"

__all__ = ["__version__"]
