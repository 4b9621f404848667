"""lanecast: maneuver-based highway trajectory prediction (Mersch et al., IROS 2021).

Sub-packages (the repository's top-level folders, installed under this one namespace):
``lanecast.io_adapters`` (formats ⇄ contracts), ``lanecast.pipeline`` (track table → windows),
``lanecast.models`` (the network, training, metrics), ``lanecast.workflows`` (the commands).
"""

from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

try:
    __version__ = version("lanecast")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

# In a checkout, lanecast/<folder> links to the folder beside it; where git made no links
# (core.symlinks=false) the folders themselves are the sub-packages, as setup.py maps them in a build.
_here = Path(__file__).parent
if not (_here / "models").is_dir() and (_here.parent / "models" / "__init__.py").is_file():
    __path__.append(str(_here.parent))
