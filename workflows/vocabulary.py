"""The command-line vocabulary every command shares: one help format, one ``--model``.

Every command's parser uses ``HelpFormatter`` (examples kept as written, every default shown) and
declares its model with ``add_model_option`` so that ``--model`` means the same everywhere.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

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
