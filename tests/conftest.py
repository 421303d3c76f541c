"""Session-wide fixtures shared by every test area.

``synthetic_sequence`` and ``synthetic_voc`` are factories: each distinct argument set is rendered
once per test session (into pytest's temporary folder) and the same path is returned on every
later call. Treat the returned folders as read-only; copy them to ``tmp_path`` before changing
anything. Keep sizes and frame counts small (rendering takes tens of milliseconds per frame).
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig

from uss_slam.synthetic import render_sequence, render_voc

# A shell starts a background job (`make test &`, `nohup ...`) with Ctrl-C and Ctrl-\ ignored,
# and the console scripts the tests start inherit that: the interrupt tests would then see no
# interrupt. Python's own handler is reset to the default in every child, as in a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
if signal.getsignal(signal.SIGQUIT) is signal.SIG_IGN:
    signal.signal(signal.SIGQUIT, signal.SIG_DFL)

# pytest-xdist's workers (``make test``: one per core) share the cores: each runs torch, and
# the console scripts it starts run torch and OpenMP, on one thread. Two threads per worker
# made OpenMP's threads spin-wait for a core the other worker held: the training tests took
# several times their CPU on two busy cores. In one process (``-n 0``) tests use two threads.
WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
TORCH_THREADS = 1 if WORKERS > 1 else 2
if WORKERS > 1:
    os.environ.setdefault("OMP_NUM_THREADS", "1")

SequenceFactory = Callable[..., Path]
VocFactory = Callable[..., Path]


def pytest_runtest_setup(item: pytest.Item) -> None:
    """``@pytest.mark.gpu`` tests need CUDA: skipped where ``torch.cuda.is_available()`` is false
    (torch is imported only for them)."""
    if item.get_closest_marker("gpu") is None:
        return
    import torch

    if not torch.cuda.is_available():
        pytest.skip("needs a CUDA GPU (torch.cuda.is_available() is false)")


@pytest.fixture(scope="session")
def synthetic_sequence(tmp_path_factory: pytest.TempPathFactory) -> SequenceFactory:
    """``synthetic_sequence(preset="walking_xyz", frames=30, size=(320, 240), style="target",
    seed=0) -> Path`` of a TUM RGB-D sequence folder (see ``uss-synth sequence --help``)."""
    cache: dict[tuple, Path] = {}

    def make(
        preset: str = "walking_xyz",
        frames: int = 30,
        size: tuple[int, int] = (320, 240),
        style: str = "target",
        seed: int = 0,
    ) -> Path:
        key = (preset, int(frames), tuple(int(v) for v in size), style, int(seed))
        if key not in cache:
            name = f"{preset}_{frames}_{size[0]}x{size[1]}_{style}_{seed}"
            out = tmp_path_factory.mktemp("synthetic_sequence") / name
            cache[key] = render_sequence(
                out, preset=preset, frames=frames, size=size, style=style, seed=seed
            )
        return cache[key]

    return make


@pytest.fixture(scope="session")
def synthetic_voc(tmp_path_factory: pytest.TempPathFactory) -> VocFactory:
    """``synthetic_voc(images=24, size=(160, 120), seed=0) -> Path`` of a ``VOC2012`` folder
    (``JPEGImages/``, ``SegmentationClass/``, ``ImageSets/Segmentation/{train,val}.txt``)."""
    cache: dict[tuple, Path] = {}

    def make(images: int = 24, size: tuple[int, int] = (160, 120), seed: int = 0) -> Path:
        key = (int(images), tuple(int(v) for v in size), int(seed))
        if key not in cache:
            out = tmp_path_factory.mktemp("synthetic_voc")
            cache[key] = render_voc(out / "data", images=images, size=size, seed=seed)
        return cache[key]

    return make


@pytest.fixture(autouse=True)
def _forget_hydra_state() -> Iterator[None]:
    """Tests that compose a Hydra app set the process-wide ``HydraConfig`` (``uss-train``'s and
    ``uss-slam``'s output folders come from it) and the global Hydra instance: clear both after
    every test so a later test's app writes where its own config says."""
    yield
    HydraConfig.instance().cfg = None
    GlobalHydra.instance().clear()


@pytest.fixture(autouse=True)
def _signal_handlers_as_they_were() -> Iterator[None]:
    """A test that runs a console script's launcher in this process leaves its handler of the
    stopping signals in place (a script's process ends after it, so the launcher does not put
    the default back): give every later test the handlers the session started with."""
    from uss_slam.core.launch import TERMINATING

    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, *TERMINATING)}
    yield
    for sig, handler in before.items():
        if handler is not None and signal.getsignal(sig) is not handler:
            signal.signal(sig, handler)


@pytest.fixture(scope="session")
def uda_data(synthetic_voc: VocFactory, synthetic_sequence: SequenceFactory) -> dict[str, Path]:
    """The data of a tiny ``uss-train`` run (training, export and pipeline tests): source VOC
    tree, a target training sequence and a labelled target validation sequence (another seed)."""
    return {
        "voc": synthetic_voc(),
        "target": synthetic_sequence(),
        "val": synthetic_sequence(frames=6, size=(160, 120), seed=1),
    }


@pytest.fixture(autouse=True)
def _torch_threads() -> Iterator[None]:
    """Tests that use torch run it on :data:`TORCH_THREADS` threads; torch-free test areas
    never import it."""
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(TORCH_THREADS)
    yield
    torch.set_num_threads(threads)
