"""coopsim: cooperative-manipulator closed-chain dynamics, validated against MuJoCo."""

from importlib.metadata import PackageNotFoundError as _NotFound, version as _version

try:
    __version__ = _version("coopsim")
except _NotFound:   # a source tree that is not installed
    __version__ = "unknown"
