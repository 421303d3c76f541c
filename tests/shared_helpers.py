"""Helpers several test areas use: the real training and ``uss-slam`` configs composed for a
test, the overrides that point the training config at the ``uda_data`` fixture, a tiny
segmenter and a ``uss-train`` run folder holding it, the metadata of an exported segmenter, and
a tiny ONNX segmenter built with ``onnx.helper`` (no torch) whose output is known for every
pixel. Torch is imported only by the helpers that build networks, when called.

The tiny model's logits are ``(bias, R, G, B)`` per pixel, so a pixel's label is 0 where every
channel is below ``bias`` (ties go to the first index, as ArgMax), else the index of its largest
channel among R, G, B (+1): :func:`colour_labels`.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import onnx
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, open_dict
from onnx import TensorProto, helper

if TYPE_CHECKING:
    from torch import nn

    from uss_slam.core.onnx_contract import SegmenterMetadata
    from uss_slam.models import DeepLabV2

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
NET_YAML = CONFIG_DIR / "model" / "net" / "deeplab_small.yaml"


def data_overrides(data: dict[str, Path]) -> list[str]:
    """``uss-train`` overrides pointing at the synthetic data of the ``uda_data`` fixture."""
    return [
        f"data.source.root={data['voc']}",
        f"data.target.roots=[{data['target']}]",
        f"data.val.roots=[{data['val']}]",
        "data.val.stride=1",
    ]


def compose_train(overrides: Sequence[str], output_dir: Path) -> DictConfig:
    """The real ``train.yaml`` composed with ``overrides``; outputs go to ``output_dir`` (set as
    Hydra's runtime output folder, as in a ``uss-train`` run). As ``uss-train`` does before
    building the model, ``model.method`` keeps only its method's own settings (an experiment's
    discriminator width is dropped for ``source_only``)."""
    from uss_slam.train.train import drop_unused_method_settings

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=list(overrides), return_hydra_config=True)
    drop_unused_method_settings(cfg)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(output_dir)
        cfg.hydra.job.num = 0
        cfg.paths.log_dir = str(output_dir.parent / "logs")
    HydraConfig().set_config(cfg)
    return cfg


def compose_slam_eval(overrides: Sequence[str]) -> DictConfig:
    """The real ``slam_eval.yaml`` (``uss-slam``'s config) composed with ``overrides``, its
    structured configs registered first (as ``uss_slam.slam_eval.run`` does on import)."""
    from uss_slam.slam_eval.config import register_configs

    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("slam_eval", overrides=list(overrides))


def slam_run_config(sequence: Path, out: Path, *overrides: str) -> DictConfig:
    """:func:`compose_slam_eval` of a run on the ``sequence`` folder into ``out``, without
    progress bars, and ``overrides``."""
    return compose_slam_eval(
        [f"sequence.path={sequence}", f"out_dir={out}", "progress=false", *overrides]
    )


def colour_segmenter(path: Path, bias: float = 128.0) -> Path:
    """An ONNX segmenter of the project's contract (the four classes) whose label is the argmax
    of ``(bias, R, G, B)`` per pixel (:func:`colour_labels`)."""
    from uss_slam.core.classes import CLASS_NAMES

    metadata = segmenter_metadata(CLASS_NAMES, experiment="colour")
    return colour_model(path, metadata.to_props(), bias=bias)


def colour_model(
    path: Path,
    props: Mapping[str, str] | None,
    *,
    bias: float = 128.0,
    input_type: int = TensorProto.UINT8,
    input_shape: Sequence[int | str] = ("N", "H", "W", 3),
    label_map: Sequence[int] | None = None,
    logits_channels: int | str = 4,
) -> Path:
    """Write the ``(bias, R, G, B)``-logits model to ``path`` with ``props`` as its
    metadata_props (None: none); ``input_type`` / ``input_shape`` make contract violations.

    Models that break the contract between outputs and metadata: ``label_map`` (the label
    written for argmax 0, 1, 2, 3; e.g. ``(0, 1, 2, 7)`` labels blue pixels 7, a class id no
    metadata lists), ``logits_channels`` (the declared channel dimension of ``logits``: a name
    such as ``"C"`` hides the 4 channels until the model runs: a reshape to a shape computed
    from the input's, which shape inference cannot follow)."""
    hidden = isinstance(logits_channels, str)
    nodes = [
        helper.make_node("Cast", ["image"], ["x"], to=TensorProto.FLOAT),
        helper.make_node("Transpose", ["x"], ["nchw"], perm=[0, 3, 1, 2]),
        helper.make_node("Conv", ["nchw", "w", "b"], ["conv" if hidden else "logits"]),
        helper.make_node("ArgMax", ["logits"], ["idx"], axis=1, keepdims=0),
    ]
    weight = np.zeros((4, 3, 1, 1), np.float32)
    weight[1, 0] = weight[2, 1] = weight[3, 2] = 1.0
    initializer = [
        helper.make_tensor("w", TensorProto.FLOAT, weight.shape, weight.ravel()),
        helper.make_tensor("b", TensorProto.FLOAT, [4], [bias, 0.0, 0.0, 0.0]),
    ]
    if hidden:  # logits = reshape(conv, [N, -1, H, W]) with N, H, W read from the input
        nodes[3:3] = [
            helper.make_node("Shape", ["image"], ["in_shape"]),
            helper.make_node("Slice", ["in_shape", "i0", "i1"], ["n"]),
            helper.make_node("Slice", ["in_shape", "i1", "i3"], ["hw"]),
            helper.make_node("Concat", ["n", "minus_one", "hw"], ["out_shape"], axis=0),
            helper.make_node("Reshape", ["conv", "out_shape"], ["logits"]),
        ]
        initializer += [
            helper.make_tensor(name, TensorProto.INT64, [1], [value])
            for name, value in (("i0", 0), ("i1", 1), ("i3", 3), ("minus_one", -1))
        ]
    if label_map is None:
        nodes.append(helper.make_node("Cast", ["idx"], ["labels"], to=TensorProto.UINT8))
    else:
        initializer.append(helper.make_tensor("map", TensorProto.UINT8, [4], list(label_map)))
        nodes.append(helper.make_node("Gather", ["map", "idx"], ["labels"], axis=0))
    graph = helper.make_graph(
        nodes,
        "colour",
        [helper.make_tensor_value_info("image", input_type, list(input_shape))],
        [
            helper.make_tensor_value_info(
                "logits", TensorProto.FLOAT, ["N", logits_channels, "H", "W"]
            ),
            helper.make_tensor_value_info("labels", TensorProto.UINT8, ["N", "H", "W"]),
        ],
        initializer=initializer,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 9
    if props:
        helper.set_model_props(model, dict(props))
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def segmenter_metadata(
    class_names: Sequence[str],
    dynamic: Sequence[str] = ("person",),
    *,
    head: str = "main",
    experiment: str = "test",
) -> SegmenterMetadata:
    """The metadata of an exported segmenter with ``class_names`` (ImageNet normalisation, a
    checkpoint digest of zeros: test values)."""
    from uss_slam.core.onnx_contract import SegmenterMetadata

    return SegmenterMetadata(
        class_names=tuple(class_names),
        dynamic_classes=tuple(dynamic),
        mean=(0.485, 0.456, 0.406),
        std=(0.229, 0.224, 0.225),
        head=head,
        experiment=experiment,
        checkpoint_sha256="0" * 64,
        version="0.1.0",
    )


def segmenter_props(class_names: Sequence[str], dynamic: Sequence[str] = ("person",)) -> dict:
    """The metadata_props of an exported segmenter with ``class_names`` (test values)."""
    return segmenter_metadata(class_names, dynamic).to_props()


def tiny_net(seed: int = 0) -> DeepLabV2:
    """The CI / demo segmenter as configured (``configs/model/net/deeplab_small.yaml``), with
    non-trivial BatchNorm statistics (so the exported graph must carry them), in eval mode."""
    import torch
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from uss_slam.models import DeepLabV2

    torch.manual_seed(seed)
    net = instantiate(OmegaConf.load(NET_YAML))
    assert isinstance(net, DeepLabV2) and net.backbone_name == "resnet_small"
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
    return net.eval()


def fake_run(
    root: Path,
    net: nn.Module,
    run_name: str = "fake",
    *,
    net_yaml: Path = NET_YAML,
    iteration: int = 7,
) -> Path:
    """A run folder as uss-train writes it: ``.hydra/config.yaml`` (``run_name`` and the net
    config of ``net_yaml``, the one ``net`` was built from) + ``checkpoints/last.ckpt``
    (segmenter and discriminator weights, at ``iteration``); returns the checkpoint."""
    import torch
    import yaml

    from uss_slam.core.classes import CLASS_NAMES

    (root / ".hydra").mkdir(parents=True)
    (root / "checkpoints").mkdir()
    config = {"run_name": run_name, "model": {"net": yaml.safe_load(net_yaml.read_text())}}
    (root / ".hydra" / "config.yaml").write_text(yaml.safe_dump(config))
    state = {f"segmenter.{k}": v for k, v in net.state_dict().items()}
    state["d_main.layers.0.weight"] = torch.ones(2, 4, 4, 4)
    ckpt = root / "checkpoints" / "last.ckpt"
    torch.save(
        {
            "state_dict": state,
            "hyper_parameters": {"class_names": list(CLASS_NAMES)},
            "iteration": iteration,
        },
        ckpt,
    )
    return ckpt


def colour_labels(rgb: np.ndarray, bias: float = 128.0) -> np.ndarray:
    """What :func:`colour_model` predicts for ``rgb`` (H, W, 3) uint8 (first maximum wins)."""
    logits = np.concatenate([np.full(rgb.shape[:2] + (1,), bias), rgb.astype(np.float64)], axis=2)
    return np.argmax(logits, axis=2).astype(np.uint8)


def full_disk(
    monkeypatch, names: Sequence[str] | Callable[[Path], bool] | None = None
) -> list[Path]:
    """Make the disk full for the outputs the project writes through ``core/files.py`` whose
    final name is in ``names`` (or for which ``names(path)`` is true; None: every output):
    their writes fail with ``ENOSPC``, as the kernel reports it, because the file being
    written is ``/dev/full``. Returns the final paths hit, in order (empty if none was hit).

    The temporary sibling of an atomic write (``atomic_path``) becomes a symbolic link to
    ``/dev/full``; an in-place write (``write_file``) opens ``/dev/full`` instead of its file.
    """
    from uss_slam.core import files

    hit: list[Path] = []
    create_sibling, open_new = files._create_sibling, files._open_new

    def chosen(path: Path) -> bool:
        return names is None or (names(path) if callable(names) else path.name in names)

    def sibling(path: Path, prefix: str) -> Path:
        tmp = create_sibling(path, prefix)
        if chosen(path):
            hit.append(path)
            tmp.unlink()
            tmp.symlink_to("/dev/full")
        return tmp

    def opened(path: Path):
        if chosen(path):
            hit.append(path)
            return open("/dev/full", "wb")  # noqa: SIM115
        return open_new(path)

    monkeypatch.setattr(files, "_create_sibling", sibling)
    monkeypatch.setattr(files, "_open_new", opened)
    return hit


def outside_staging(files: Mapping[str, str]) -> dict[str, str]:
    """A ``{relative path: digest}`` snapshot of a run folder without the files of its
    ``uss-slam`` staging folders (``.uss-slam-new.<random>/``), which a running run fills."""
    return {k: v for k, v in files.items() if not k.startswith(".uss-slam-new.")}


def drop_in_weakref_callback(error: BaseException) -> None:
    """Make Python drop ``error`` (report it to ``sys.unraisablehook`` and carry on) by raising
    it in a weakref callback: what a Ctrl-C landing during an import's module lock does."""
    import gc
    import weakref

    class Thing:
        pass

    def callback(_ref: object) -> None:
        raise error

    thing = Thing()
    ref = weakref.ref(thing, callback)
    del thing
    gc.collect()
    assert ref() is None


class ImportLine(NamedTuple):
    """One ``import`` / ``from ... import`` statement: its line, the absolute module it reads
    and the names it takes from it (empty for ``import x``)."""

    line: int
    module: str
    names: tuple[str, ...]

    def modules(self) -> set[str]:
        """The module and ``module.<name>`` for each name (a name may be a sub-module)."""
        return {self.module} | {f"{self.module}.{name}" for name in self.names}


def read_imports(source: str, module: str, is_package: bool = False) -> list[ImportLine]:
    """The one import reader of the architecture tests: every import of ``source`` (those
    inside functions and ``TYPE_CHECKING`` blocks included), relative ones made absolute.

    Args:
        source: the file's text.
        module: the file's module name (``uss_slam.core.tum_io``; for a package's
            ``__init__.py`` the package, with ``is_package``).
        is_package: the file is the package's ``__init__.py`` (``from . import x`` stays in it).
    """
    package = module if is_package else module.rpartition(".")[0]
    found: list[ImportLine] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [ImportLine(node.lineno, alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                parts = package.split(".")
                kept = parts[: len(parts) - node.level + 1]
                base = ".".join(kept + ([node.module] if node.module else []))
            found.append(ImportLine(node.lineno, base, tuple(a.name for a in node.names)))
    return sorted(found)


def import_cycle(graph: Mapping[str, set[str]]) -> list[str] | None:
    """One cycle of an import graph (its modules in order, the first repeated), or None."""
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def write_csv(path: Path, rows: Sequence[Mapping[str, object]]) -> Path:
    """``rows`` (dicts with the keys of the first) as a CSV file with a header; returns ``path``."""
    import csv

    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path


STUDIES = Path(__file__).resolve().parents[1] / "studies"
"""The research scripts' folder."""


def study(name: str) -> ModuleType:
    """``studies/NAME.py`` as a module (:func:`~uss_slam.testing.scripts.load_script`), with
    ``studies/`` on ``sys.path`` while it loads: the held-out sets' scripts import their
    siblings (``from fresh_setups import ...``)."""
    import sys

    from uss_slam.testing.scripts import load_script

    sys.path.insert(0, str(STUDIES))
    try:
        return load_script(STUDIES / f"{name}.py")
    finally:
        sys.path.remove(str(STUDIES))


def made_up_split(main: Callable[[list[str]], int], tmp_path: Path, capsys, line: str) -> str:
    """What a held-out set's split (``studies/fresh_pointed*.py``'s ``main``) prints for a
    made-up run of two cases: ``line`` (id ``a``, poor) and a valid ``uss-synth voc`` (id
    ``b``, good); the split's totals are checked here, the family named is the caller's."""
    import json

    cases = tmp_path / "cases.txt"
    cases.write_text(f"# header\n{line}\nb | uss-synth | ok | - | - | - | voc\n", encoding="utf-8")
    results = tmp_path / "results.json"
    outcomes = [{"id": "a", "verdict": "poor"}, {"id": "b", "verdict": "good"}]
    results.write_text(json.dumps({"outcomes": outcomes}), encoding="utf-8")
    assert main([str(cases), str(results)]) == 0
    out = capsys.readouterr().out
    assert "named to the fixer: 1 counted, 0 good, 1 poor, 0 bad (0.0% good)" in out
    assert "not named to the fixer: 1 counted, 1 good, 0 poor, 0 bad (100.0% good)" in out
    return out
