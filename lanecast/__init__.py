"""lanecast: maneuver-based highway trajectory prediction (Mersch et al., IROS 2021).

Sub-packages (the repository's top-level folders, installed under this one namespace):
``lanecast.io_adapters`` (formats ⇄ contracts), ``lanecast.pipeline`` (track table → windows),
``lanecast.models`` (the network, training, metrics), ``lanecast.workflows`` (the commands).
"""

from pathlib import Path


def __getattr__(name: str) -> str:
    """``__version__``, looked up when first asked for: importlib.metadata would cost every
    command ~30 ms of start-up."""
    if name != "__version__":
        raise AttributeError(f"module 'lanecast' has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("lanecast")
    except PackageNotFoundError:  # running from a source tree that was never installed
        value = "0+unknown"
    globals()["__version__"] = value
    return value


# In a checkout, lanecast/<folder> links to the folder beside it; where git made no links
# (core.symlinks=false) the folders themselves are the sub-packages, as setup.py maps them in a build.
_here = Path(__file__).parent
if not (_here / "models").is_dir() and (_here.parent / "models" / "__init__.py").is_file():
    __path__.append(str(_here.parent))
