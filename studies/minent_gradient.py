"""How strong is MinEnt's entropy term: ‖∇θ L_ent‖ / ‖∇θ L_seg‖ over the segmenter's parameters? Not
yet reported in the results record (docs/training.md, "Adaptation methods", quotes its figures).

On training batches of ``experiment=demo model/method=minent`` (the real config and data module;
BatchNorm in train mode, each domain through its own forward as in training), for each segmenter
state given (``init`` = the configured initialisation, or ``uss-train`` checkpoints): the norm of
the gradient of the weighted source segmentation loss ``λ_seg_aux·CE(aux) + λ_seg_main·CE(main)``
and of the weighted target entropy ``λ_ent_aux·E(aux) + λ_ent_main·E(main)``, each alone, and
their ratio (median and range over the batches), at ADVENT's weights (0.0002 / 0.001) and at the
configured ones. The ratio is linear in the entropy weights.

    .venv/bin/python studies/minent_gradient.py                       # renders small data
    .venv/bin/python studies/minent_gradient.py --data outputs/demo/data --states init CKPT
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from collections.abc import Sequence
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from uss_slam.synthetic import render_sequence, render_voc
from uss_slam.train.losses import entropy_loss
from uss_slam.train.methods import MinEnt, SourceSegmentation
from uss_slam.train.module import AdversarialSegmentation

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
ADVENT_WEIGHTS = (0.0002, 0.001)
"""ADVENT's ``LAMBDA_ENT_AUX`` / ``LAMBDA_ENT_MAIN``."""


def small_data(root: Path) -> list[str]:
    """Data overrides for a small rendered source tree and target sequence under ``root``."""
    voc = render_voc(root / "voc", images=24, size=(160, 120), seed=0)
    target = render_sequence(
        root / "target", preset="walking_xyz", frames=30, size=(320, 240), seed=0
    )
    val = render_sequence(root / "val", preset="walking_xyz", frames=6, size=(160, 120), seed=1)
    return [
        f"data.source.root={voc}",
        f"data.target.roots=[{target}]",
        f"data.val.roots=[{val}]",
    ]


def _grad_norm(loss: torch.Tensor, params: Sequence[torch.nn.Parameter]) -> float:
    grads = torch.autograd.grad(loss, params, allow_unused=True)
    return float(torch.sqrt(sum((g.double() ** 2).sum() for g in grads if g is not None)))


def measure(
    module: AdversarialSegmentation, batches: list[dict], weights: tuple[float, float]
) -> list[tuple[float, float]]:
    """``(‖∇ L_seg‖, ‖∇ L_ent‖)`` per batch at entropy ``weights`` (aux, main)."""
    net = module.segmenter
    net.train()
    params = [p for p in net.parameters() if p.requires_grad]
    out = []
    for batch in batches:
        src = SourceSegmentation(
            net(batch["source"]["image"]), batch["source"]["label"], module.loss_weights, 0
        )
        images = batch["target"]["image"]
        pred = net(images)
        size = images.shape[-2:]
        ent = weights[0] * entropy_loss(pred.aux, size) + weights[1] * entropy_loss(pred.main, size)
        out.append((_grad_norm(src.loss, params), _grad_norm(ent, params)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="a `make demo` data folder (default: render)")
    parser.add_argument("--states", nargs="+", default=["init"], help="init and/or checkpoints")
    parser.add_argument("--batches", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(2)
    with tempfile.TemporaryDirectory() as tmp:
        overrides = [f"paths.data_dir={args.data}"] if args.data else small_data(Path(tmp) / "data")
        with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
            cfg = compose(
                "train",
                overrides=["experiment=demo", "model/method=minent", "data.num_workers=0"]
                + overrides,
            )
        torch.manual_seed(args.seed)
        datamodule = instantiate(cfg.data)
        datamodule.setup("fit")
        loader = iter(datamodule.train_dataloader())
        batches = []
        for _ in range(args.batches):
            batch, *_ = next(loader)
            batches.append(batch)
        for state in args.states:
            torch.manual_seed(args.seed)
            module = instantiate(cfg.model)
            if state != "init":
                blob = torch.load(state, map_location="cpu", weights_only=True)["state_dict"]
                seg = {
                    k[len("segmenter.") :]: v for k, v in blob.items() if k.startswith("segmenter.")
                }
                module.segmenter.load_state_dict(seg)
            method = module.method
            if not isinstance(method, MinEnt):
                raise SystemExit(f"model.method is {type(method).__name__}, expected MinEnt")
            configured = (method.lambda_ent_aux, method.lambda_ent_main)
            for name, weights in (("ADVENT", ADVENT_WEIGHTS), ("configured", configured)):
                norms = measure(module, batches, weights)
                ratios = [e / s for s, e in norms]
                print(
                    f"{state}: λ_ent {name} {weights}: |∇L_ent| / |∇L_seg| median "
                    f"{100 * statistics.median(ratios):.3f}% (range {100 * min(ratios):.3f}-"
                    f"{100 * max(ratios):.3f}%, {len(ratios)} batches); |∇L_seg| median "
                    f"{statistics.median(s for s, _ in norms):.4g}"
                )


if __name__ == "__main__":
    main()
