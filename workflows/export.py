"""`lanecast export`: a model's prediction path to ONNX, for ONNX Runtime (see ``lanecast.models.onnx_export``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from lanecast.io_adapters.progress import activity
from lanecast.models.card import read_card
from lanecast.workflows.vocabulary import add_force_option

FORMATS = ("onnx",)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="export a model to ONNX (then every command predicts with ONNX Runtime)",
        description=(
            "Export MODEL (a model directory, its .json card or .safetensors weights) as one ONNX graph: "
            "normalisation, both networks, the top-K maneuver sequences and their trajectories. The file "
            "<stem>.onnx is written beside the weights (or into --out with a copy of the model) and the card "
            "records the opset, the shapes and the weights it came from; a model retrained afterwards is "
            "served by torch until exported again."
        ),
        epilog=(
            "examples:\n"
            "  lanecast export runs/model --to onnx\n"
            "  lanecast export runs/model/stcnn.json --to onnx --out deploy/model"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("model", type=Path, metavar="MODEL", help="model directory or file")
    p.add_argument("--to", choices=FORMATS, default="onnx", help="export format (default: onnx)")
    p.add_argument(
        "--out", type=Path, metavar="DIR", help="output directory (default: beside the weights, card updated)"
    )
    add_force_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lanecast.models.onnx_export import export_onnx

    with activity("export: tracing the model to ONNX and checking it against torch"):
        path = export_onnx(args.model, args.out, force=args.force)
    section = read_card(path.with_suffix(".json"))["onnx"]
    print(
        f"wrote {path} (opset {section['opset']}, {path.stat().st_size / 1e3:.0f} kB; "
        f"largest difference to torch {section['max_difference_to_torch']:.2g})"
    )
    return 0
