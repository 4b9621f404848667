"""The command-line vocabulary every command shares: one help format, one ``--model``.

Every command's parser uses ``HelpFormatter`` (examples kept as written, every default shown) and
declares its model with ``add_model_option`` so that ``--model`` means the same everywhere.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

# NGSIM's locations (lanecast.io_adapters.datasets.ngsim.reader.FREEWAYS + ARTERIALS, which a test checks);
# spelled out here so that `--help` does not import the reader.
NGSIM_LOCATIONS = ("us-101", "i-80", "lankershim", "peachtree")

MODEL_HELP = (
    "a model: a directory written by `lanecast train`, or its .safetensors/.json file "
    "(default: the shipped weights, models/weights/stcnn-sumo)"
)


def _has_default_to_show(action: argparse.Action) -> bool:
    return (
        action.default not in (None, False, argparse.SUPPRESS)
        and bool(action.option_strings or action.nargs in ("?", "*"))
        and "default" not in (action.help or "")
    )


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and examples as written; ``(default: …)`` added to every option that has a
    default and whose help does not already state it."""

    def _format_action(self, action: argparse.Action) -> str:
        if _has_default_to_show(action):
            action = copy.copy(action)
            action.help = f"{action.help or ''} (default: %(default)s)".lstrip()
        return super()._format_action(action)


def add_model_option(parser: argparse.ArgumentParser) -> None:
    """``--model MODEL``: the same option, with the same meaning, in every command that predicts."""
    parser.add_argument("--model", type=Path, metavar="MODEL", help=MODEL_HELP)


def add_location_option(parser: argparse.ArgumentParser) -> None:
    """``--location``: where NGSIM .txt files were recorded, when their names and folders do not say."""
    parser.add_argument(
        "--location",
        choices=NGSIM_LOCATIONS,
        help="NGSIM: the location of the .txt files (default: from the file or folder name; NGSIM's own "
        "trajectories-0750am-0805am.txt … are US-101, trajectories-0400-0415.txt … I-80)",
    )


FORCE_HELP = (
    "replace an existing output of the same name that lanecast did not write (by default such a "
    "file is named and refused, never overwritten; lanecast's own earlier outputs are replaced)"
)


def add_force_option(parser: argparse.ArgumentParser, help: str = FORCE_HELP) -> None:
    """``--force``: replace existing outputs that lanecast did not write (refused by default)."""
    parser.add_argument("--force", action="store_true", help=help)
