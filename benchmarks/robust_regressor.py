"""Fine-tune a trained model's regressor towards noisy derivatives, then interpolate its weights with
the base's: the shipped recipe's robust regressor stage (``train_shipped.py --robust-*``, α 0.25),
here for any base and several α at once, to measure the trade-off.

Recipes trained from scratch with a distrusted acceleration input win the real Peachtree sample's
creeping cars back and lose 3-4 % on clean simulation (BENCHMARKS.md, "Zero-shot"). Here the base
model keeps its classifier and its regressor is fine-tuned for ``--epochs`` on the base's own
training windows with the noisier augmentation (``--acc-noise``, ``--derivative-outliers``,
``--derivative-noise-spread``), starting from the base weights and normalisation; then for each
``--alpha`` the regressor's weights are ``(1 - alpha) * base + alpha * fine-tuned`` (weight-space
ensembling of a fine-tune and its start, as in Wortsman et al., "Robust fine-tuning of zero-shot
models", CVPR 2022). The regression-only ablation of the work directory gets the same treatment, so
that every ``--out/a<alpha>`` is a work directory that ``maneuver_claim.py``, ``real_proxy.py
--model`` and ``peachtree_breakdown.py`` measure like a ``train_shipped.py`` run. The cards carry
the base's checksum and this recipe; their ``metrics`` are emptied (they were the base's).

    .venv/bin/python benchmarks/robust_regressor.py --work /tmp/zs/shs0 --out /tmp/zs/robust \\
        --base /tmp/zs/shs0/weights --alpha 0.25 0.5 0.75 1.0
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lanecast.io_adapters.windows_store.dataset import load_windows  # noqa: E402
from lanecast.models.checkpoint import SHIPPED_STEM, load_checkpoint, save_checkpoint  # noqa: E402
from lanecast.models.finetune import interpolate_regressor  # noqa: E402
from lanecast.models.stcnn import STCNN  # noqa: E402
from lanecast.models.train import TrainConfig, train  # noqa: E402


def robust_regressor(
    base: STCNN,
    card: dict[str, Any],
    windows: Any,
    *,
    epochs: int = 4,
    lr: float = 3e-4,
    acc_noise: float = 0.7,
    outliers: float = 0.1,
    spread: float = 1.0,
    seed: int = 0,
    threads: int = 1,
) -> tuple[STCNN, dict[str, Any]]:
    """(``base`` with its classifier kept and its regressor fine-tuned on ``windows``, the recipe for
    the card): ``epochs`` at ``lr`` from the base's weights and normalisation, the base's training
    config but for the derivative noise (``acc_noise`` m/s², ``outliers``, ``spread``)."""
    config = dataclasses.replace(
        TrainConfig.from_dict(card["training"]["config"]),
        epochs=epochs,
        lr=lr,
        seed=seed,
        threads=threads,
        acc_noise_mps2=acc_noise,
        derivative_outliers=outliers,
        derivative_noise_spread=spread,
    )
    t0 = time.perf_counter()
    result = train(windows, config, init_from=(base, card), classifier_from=base)
    recipe = {
        "base_weights_sha256": card.get("weights_sha256"),
        "what": "classifier kept; regressor fine-tuned from the base on the base's training windows with "
        "this config, then interpolated with the base's regressor (weights (1 - alpha) * base + alpha * tuned)",
        "config": config.to_dict(),
        "best_epoch": result.card["training"]["best_epoch"]["regressor"],
        "train_seconds": round(time.perf_counter() - t0, 1),
    }
    return result.model, recipe


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, required=True, help="a train_shipped.py work directory")
    ap.add_argument(
        "--base",
        type=Path,
        help="the base weights (default: the shipped ones, refused if they went through this stage)",
    )
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--alpha", type=float, nargs="+", default=[0.5])
    ap.add_argument("--epochs", type=int, default=4)
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--acc-noise", type=float, default=0.7, help="m/s², std of acceleration-input jitter")
    ap.add_argument("--derivative-outliers", type=float, default=0.1)
    ap.add_argument("--derivative-noise-spread", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()

    windows = load_windows(args.work / "windows-train")
    models = {
        "weights": load_checkpoint(args.base),
        "regression-only": load_checkpoint(args.work / "regression-only"),
    }
    for name, (base, card) in models.items():
        if "robust_regressor" in card["training"]:
            raise SystemExit(
                f"the {name} model already went through this stage; give --base the weights before it"
            )
        tuned, recipe = robust_regressor(
            base,
            card,
            windows,
            epochs=args.epochs,
            lr=args.lr,
            acc_noise=args.acc_noise,
            outliers=args.derivative_outliers,
            spread=args.derivative_noise_spread,
            seed=args.seed,
            threads=args.threads,
        )
        print(
            f"{name}: fine-tuned in {recipe['train_seconds']:g} s, best epoch {recipe['best_epoch']}",
            flush=True,
        )
        stem = SHIPPED_STEM if name == "weights" else "stcnn"
        for alpha in args.alpha:
            run = args.out / f"a{alpha:g}"
            run.mkdir(parents=True, exist_ok=True)
            link = run / "windows-test"
            if not link.exists():
                link.symlink_to((args.work / "windows-test").resolve())
            training = {**card["training"], "robust_regressor": {**recipe, "alpha": alpha}}
            save_checkpoint(
                interpolate_regressor(base, tuned, alpha),
                {**card, "training": training, "metrics": {}, "reproduce": " ".join(sys.argv)},
                run / name,
                stem=stem,
            )
        print(
            f"{name}: written for alpha {', '.join(f'{a:g}' for a in args.alpha)} in {args.out}", flush=True
        )


if __name__ == "__main__":
    main()
