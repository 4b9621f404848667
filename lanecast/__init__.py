"""lanecast: maneuver-based highway trajectory prediction (Mersch et al., IROS 2021).

Sub-packages (the repository's top-level folders, installed under this one namespace):
``lanecast.io_adapters`` (formats ⇄ contracts), ``lanecast.pipeline`` (track table → windows),
``lanecast.models`` (the network, training, metrics), ``lanecast.workflows`` (the commands).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lanecast")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"
