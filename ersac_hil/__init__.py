"""ersac_hil: the learner (critic, ERSAC), its daemon, the robot-side agent and the CLI."""
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("ersac-hil")
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"
