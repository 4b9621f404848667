"""Inference throughput of the ST-CNN (windows/s) on the CPU, and training throughput (samples/s).

Compares, in the same run and on the same weights:

* ``eager``: plain eager PyTorch, the two networks one after the other (classifier, argmax, regressor);
* ``fused``: ``lanecast.models.predict.FusedSTCNN`` (conv1 of both stacked, conv2-4 grouped) + the regressor head;
* ``fused+channels_last``: the same in channels-last memory format;
* ``fused+jit-frozen``: TorchScript trace of the fused module, frozen and optimised for inference;
* ``fused+compile``: ``torch.compile`` (inductor) of the fused module (compile time printed apart);
* ``forecaster``: the full library path ``STCNNForecaster.predict`` (numpy in: normalisation, top-3 of
  the 243 sequences, 3 regressions, de-normalisation).

    .venv/bin/python benchmarks/bench_inference.py [--threads 2] [--seconds 2] [--no-compile]

Figures depend on what else runs on the machine; the script prints the load average with them.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lanecast.models.predict import FusedSTCNN, STCNNForecaster
from lanecast.models.stcnn import STCNN
from lanecast.models.train import classifier_loss, regressor_loss


def rate(fn: Callable[[], object], batch: int, seconds: float) -> float:
    """Windows per second of ``fn`` (one call = ``batch`` windows), after warm-up; best of 3 runs."""
    return rates({"": fn}, batch, seconds, rounds=3)[""]


def rates(
    fns: dict[str, Callable[[], object]], batch: int, seconds: float, rounds: int = 6
) -> dict[str, float]:
    """Best windows/s of each function over ``rounds`` short bursts, taken in turn (round-robin), so
    that other load on a shared machine hits every variant alike."""
    for fn in fns.values():
        for _ in range(2):
            fn()
    best = dict.fromkeys(fns, 0.0)
    for _ in range(rounds):
        for name, fn in fns.items():
            n, start = 0, time.perf_counter()
            while time.perf_counter() - start < seconds / rounds:
                fn()
                n += 1
            best[name] = max(best[name], n * batch / (time.perf_counter() - start))
    return best


def load_model() -> tuple[STCNN, dict | None]:
    try:
        forecaster = STCNNForecaster.load(None)
        return forecaster.model, forecaster.card
    except Exception:  # no shipped weights yet: speed does not depend on the values
        torch.manual_seed(0)
        return STCNN().eval(), None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=2.0, help="per measurement")
    ap.add_argument("--batches", default="1,256,1024")
    ap.add_argument("--no-compile", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, card = load_model()
    fused = FusedSTCNN(model).eval()
    head = model.regressor.head
    print(
        f"torch {torch.__version__}, {args.threads} threads, load average {os.getloadavg()[0]:.2f}, "
        f"weights: {'shipped' if card else 'random'}"
    )

    def eager(x: torch.Tensor) -> torch.Tensor:
        logits = model.classifier(x)
        return model.regressor(x, logits.argmax(2))

    def fused_fn(module: Callable) -> Callable[[torch.Tensor], torch.Tensor]:
        def run(x: torch.Tensor) -> torch.Tensor:
            logits, features = module(x)
            return head(features, logits.argmax(2))

        return run

    variants: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
        "eager": eager,
        "fused": fused_fn(fused),
        "fused+channels_last": fused_fn(
            FusedSTCNN(model).eval().to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        ),
    }
    with torch.no_grad():
        example = torch.randn(256, 4, 8, 30)
        frozen = torch.jit.optimize_for_inference(
            torch.jit.freeze(torch.jit.trace(FusedSTCNN(model).eval(), example))
        )
        variants["fused+jit-frozen"] = fused_fn(frozen)
    if not args.no_compile:
        # one graph per batch size, layout and grad mode (two compiled modules share the code)
        torch._dynamo.config.recompile_limit = 64
        start = time.perf_counter()
        compiled = torch.compile(FusedSTCNN(model).eval(), dynamic=False)
        with torch.no_grad():
            for b in (int(v) for v in args.batches.split(",")):
                compiled(torch.randn(b, 4, 8, 30))
        print(f"torch.compile: {time.perf_counter() - start:.1f} s to compile for the batch sizes")
        variants["fused+compile"] = fused_fn(compiled)

    rng = np.random.default_rng(0)
    batches = [int(v) for v in args.batches.split(",")]
    forecaster = STCNNForecaster(model, card) if card is not None else None
    forecaster_c = (
        STCNNForecaster(model, card, compile=True) if card is not None and not args.no_compile else None
    )
    table: dict[str, list[float]] = {name: [] for name in variants}
    if forecaster is not None:
        table["forecaster (top-3)"] = []
    if forecaster_c is not None:
        table["forecaster, compiled"] = []
    for b in batches:
        x = torch.randn(b, 4, 8, 30)
        x_cl = x.contiguous(memory_format=torch.channels_last)
        fns: dict[str, Callable[[], object]] = {
            name: functools.partial(fn, x_cl if name == "fused+channels_last" else x)
            for name, fn in variants.items()
        }
        if forecaster is not None:
            inputs = rng.normal(size=(b, 4, 8, 30)).astype(np.float32)
            present = np.ones((b, 8, 30), bool)
            fns["forecaster (top-3)"] = functools.partial(
                forecaster.predict, inputs, present, top_k=3, batch_size=b
            )
            if forecaster_c is not None:
                fns["forecaster, compiled"] = functools.partial(
                    forecaster_c.predict, inputs, present, top_k=3, batch_size=b
                )
        with torch.inference_mode():
            for name, r in rates(fns, b, args.seconds * len(fns)).items():
                table[name].append(r)
    print(f"{'variant':<22}" + "".join(f"{'batch ' + str(b):>14}" for b in batches) + "   (windows/s)")
    for name, row in table.items():
        print(f"{name:<22}" + "".join(f"{r:>14,.0f}" for r in row), flush=True)

    # training: one step of each network (forward, backward, Adam), as lanecast.models.train does
    train_model = STCNN()
    opt_c = torch.optim.Adam(train_model.classifier.parameters(), 1e-3)
    opt_r = torch.optim.Adam(train_model.regressor.parameters(), 1e-3)
    for b in (256, 1024):
        x, y = torch.randn(b, 4, 8, 30), torch.randn(b, 5, 2)
        m = torch.randint(0, 3, (b, 5))

        def step(x: torch.Tensor = x, y: torch.Tensor = y, m: torch.Tensor = m) -> None:
            loss = classifier_loss(train_model.classifier(x), m)
            opt_c.zero_grad()
            loss.backward()
            opt_c.step()
            loss = regressor_loss(train_model.regressor(x, m), y)
            opt_r.zero_grad()
            loss.backward()
            opt_r.step()

        print(f"training, batch {b}: {rate(step, b, args.seconds):,.0f} samples/s (both networks)")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
