"""photosurf.pipeline: orchestration, CLI, workspace, synthetic scenes, report.

No algorithm lives here; every arrow of the data flow is driven from here.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("photosurf")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
