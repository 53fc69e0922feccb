"""carfeel: the feel of a car's primary controls (steering wheel, manual gearshift) from physics."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("carfeel")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0"

__all__ = ["__version__"]
