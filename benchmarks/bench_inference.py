"""Inference throughput of the ST-CNN (windows/s) on the CPU, and training throughput (samples/s).

Compared in the same run, on the same weights and inputs, interleaved (one burst of each variant per
round, the order reversed every round), medians with min–max over the rounds:

* ``library: ONNX Runtime``: ``OnnxForecaster.predict``, what every command uses wherever the
  model's ONNX export is fresh (normalise, classify, top-3 of the 243 sequences, 3 regressions,
  de-normalise: all in the exported graph);
* ``bare ONNX Runtime``: ``session.run`` on the same graph with ready arrays (the engine's ceiling);
* ``library: torch``: ``STCNNForecaster.predict``, the torch path, at torch's default thread count
  (what the library ran before ONNX: it never set one), and the same at ``--threads``;
* ``torch: …``: the torch network variants (eager, fused, channels-last, TorchScript frozen,
  ``torch.compile`` unless ``--no-compile``), network only (no top-3, no normalisation).

Threads: ``--threads`` for ONNX Runtime (the library's default, 1) and the torch variants; the first
torch library variant runs at torch's own default (``torch.get_num_threads()`` at start).

    .venv/bin/python benchmarks/bench_inference.py [--threads 1] [--rounds 7] [--burst 0.3] [--no-compile]
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from interleave import Samples, interleaved_rates, machine_line, ratio

from lanecast.models.losses import classifier_loss, regressor_loss
from lanecast.models.predict import FusedSTCNN, STCNNForecaster
from lanecast.models.runtime import load_forecaster
from lanecast.models.stcnn import STCNN

LIB_ORT, BARE_ORT, LIB_TORCH = (
    "library: ONNX Runtime",
    "bare ONNX Runtime",
    "library: torch (default threads)",
)
LIB_TORCH_N = "library: torch (--threads)"


def with_threads(n: int, fn: Callable[[], object]) -> Callable[[], object]:
    """``fn`` run with torch at n threads (set before each call: the variants share one process)."""

    def run() -> object:
        torch.set_num_threads(n)
        return fn()

    return run


def windows(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n plausible windows: the shipped normalisation's statistics, 30 % of entries absent."""
    from lanecast.models.onnx_export import synthetic_windows

    return synthetic_windows(STCNNForecaster.load(None).card, n, seed)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--burst", type=float, default=0.3, help="seconds per variant per round")
    ap.add_argument("--batches", default="1,256,1024")
    ap.add_argument("--no-compile", action="store_true")
    ap.add_argument("--library-only", action="store_true", help="only the three library/engine variants")
    args = ap.parse_args()
    default_threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    forecaster = STCNNForecaster.load(None)
    model = forecaster.model
    onnx = load_forecaster(None, engine="onnx", threads=args.threads)
    session = onnx.session  # type: ignore[attr-defined]
    head = model.regressor.head
    print(
        f"torch {torch.__version__} (default {default_threads} threads), onnxruntime "
        f"{__import__('onnxruntime').__version__}; --threads {args.threads}"
    )
    print(machine_line("before"))

    def fused_fn(module: Callable) -> Callable[[torch.Tensor], torch.Tensor]:
        def run(x: torch.Tensor) -> torch.Tensor:
            logits, features = module(x)
            return head(features, logits.argmax(2))

        return run

    def eager(x: torch.Tensor) -> torch.Tensor:
        logits = model.classifier(x)
        return model.regressor(x, logits.argmax(2))

    networks: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {}
    if not args.library_only:
        networks = {
            "torch: eager": eager,
            "torch: fused": fused_fn(FusedSTCNN(model).eval()),
            "torch: fused+channels_last": fused_fn(
                FusedSTCNN(model).eval().to(memory_format=torch.channels_last)  # type: ignore[call-overload]
            ),
        }
        with torch.no_grad():
            frozen = torch.jit.optimize_for_inference(
                torch.jit.freeze(torch.jit.trace(FusedSTCNN(model).eval(), torch.randn(256, 4, 8, 30)))
            )
        networks["torch: fused+jit-frozen"] = fused_fn(frozen)
        if not args.no_compile:
            torch._dynamo.config.recompile_limit = 64
            start = time.perf_counter()
            compiled = torch.compile(FusedSTCNN(model).eval(), dynamic=False)
            with torch.no_grad():
                for b in (int(v) for v in args.batches.split(",")):
                    compiled(torch.randn(b, 4, 8, 30))
            print(f"torch.compile: {time.perf_counter() - start:.1f} s to compile for the batch sizes")
            networks["torch: fused+compile"] = fused_fn(compiled)

    batches = [int(v) for v in args.batches.split(",")]
    table: dict[int, dict[str, Samples]] = {}
    for b in batches:
        inputs, present = windows(b, seed=b)
        feed = {"inputs": inputs, "present": present, "k": np.asarray(3, np.int64)}
        x = torch.from_numpy(inputs.copy())
        x_cl = x.contiguous(memory_format=torch.channels_last)
        fns: dict[str, Callable[[], object]] = {
            LIB_ORT: functools.partial(onnx.predict, inputs, present, top_k=3, batch_size=b),
            BARE_ORT: functools.partial(session.run, None, feed),
            LIB_TORCH: with_threads(
                default_threads, functools.partial(forecaster.predict, inputs, present, top_k=3, batch_size=b)
            ),
            LIB_TORCH_N: with_threads(
                args.threads, functools.partial(forecaster.predict, inputs, present, top_k=3, batch_size=b)
            ),
        }
        for name, fn in networks.items():
            fns[name] = with_threads(
                args.threads, functools.partial(fn, x_cl if "channels_last" in name else x)
            )
        with torch.inference_mode():
            table[b] = interleaved_rates(fns, b, args.burst, args.rounds)
        print(f"batch {b:>5} done ({machine_line()})", flush=True)

    torch.set_num_threads(args.threads)
    print(
        f"\nwindows/s, median (min–max; best) of {args.rounds} interleaved rounds of {args.burst:g} s bursts"
    )
    for b in batches:
        print(f"\nbatch {b}")
        for name, samples in table[b].items():
            print(f"  {name:<34}{samples.text()}")
        row = table[b]
        print(f"  ONNX library / torch library (default threads): {ratio(row[LIB_ORT], row[LIB_TORCH])}")
        print(f"  ONNX library / torch library (--threads)      : {ratio(row[LIB_ORT], row[LIB_TORCH_N])}")
        print(f"  ONNX library / bare ONNX     : {ratio(row[LIB_ORT], row[BARE_ORT])}")

    if not args.library_only:
        torch.set_num_threads(args.threads)
        train_model = STCNN()
        opt_c = torch.optim.Adam(train_model.classifier.parameters(), 1e-3)
        opt_r = torch.optim.Adam(train_model.regressor.parameters(), 1e-3)
        steps: dict[str, Callable[[], object]] = {}
        for b in (256, 1024):
            xb, yb, mb = torch.randn(b, 4, 8, 30), torch.randn(b, 5, 2), torch.randint(0, 3, (b, 5))

            def step(x: torch.Tensor = xb, y: torch.Tensor = yb, m: torch.Tensor = mb) -> None:
                loss = classifier_loss(train_model.classifier(x), m)
                opt_c.zero_grad()
                loss.backward()
                opt_c.step()
                loss = regressor_loss(train_model.regressor(x, m), y)
                opt_r.zero_grad()
                loss.backward()
                opt_r.step()

            steps[f"training, batch {b}"] = step
        for name, samples in {
            n: interleaved_rates({n: fn}, int(n.split()[-1]), args.burst, args.rounds)[n]
            for n, fn in steps.items()
        }.items():
            print(f"{name}: {samples.text()} samples/s (both networks: forward, backward, Adam)")
    print(machine_line("after"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
