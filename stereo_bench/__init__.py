"""stereo-bench: hardware-in-the-loop stereo measurement of a checkerboard square."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("stereo-bench")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+source"
