"""The ogiflow appliance: daemon, configuration and command-line interface."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("ogiflow")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+source"
