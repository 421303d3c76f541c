"""Frame reading and ORB extraction in a worker process (``slam.prefetch_mode=process``).

In the default thread mode the prefetch threads read PNGs and extract ORB features in the main
process, beside the thread that tracks and runs the back end: they share one GIL, and the Python
part of the extraction (grid bucketing, orientation, the per-keypoint OpenCV objects) and
GTSAM's optimiser (which holds the GIL for a whole optimisation) take turns with tracking. Here
one worker process does the reading and the extraction, ``workers`` threads of its own
``prefetch`` frames ahead, and hands each frame to the main process:

- the images (``rgb``, ``gray``, and ``labels`` and ``depth`` where the worker read them)
  through a ring of slots of shared memory (:func:`ring_slots`: 32 frames of 640x480; a frame
  is 2.9 MB: through a pipe it would cost the main process a copy and an unpickling each); a
  prefetch thread of the main process copies a slot out and gives it back
  (:meth:`FrontendProcess.take`);
- the :class:`~.orb.Features`, extracted without depth, and the timings through a queue.

The depth and label images (a third of a frame's reading) are read by whichever side has
time: the main process's prefetch threads, unless the ring is (nearly) full of frames it has not
taken; then the worker, which would otherwise wait for a slot, reads them (:func:`_main_is_behind`).
The main process samples the depth at the keypoints (:meth:`~.orb.OrbExtractor.with_depth`).
The worker computes what the threads compute (the same code on the same inputs): features and
trajectory are bit-identical in both modes, wherever the depth was read.

Starting: the worker is a child of Python's fork server (started once per process with this
module imported, so that each run's worker starts in milliseconds), or a spawned interpreter
where there is no fork server; never a plain fork of this process, which runs threads. The
worker does not import the main script (:func:`_without_main`): its target and arguments are
this package's, so a script needs no ``if __name__ == "__main__":`` guard for it.

Ending: the main process stops and joins the worker when the run ends, fails or is interrupted
(Ctrl-C, SIGTERM: the pipeline's ``finally``); the worker ignores Ctrl-C (the terminal sends it
to the whole process group; the parent ends it) and ends itself when the main process has ended
without cleaning up (``kill -9``: a thread waits on the parent's sentinel). An error while
reading or extracting a frame reaches the main process and is raised there as one line naming
the frame's file, as in thread mode. Where a worker process cannot be started (inside a
daemonic process such as a ``multiprocessing.Pool`` worker, no shared memory), :func:`start`
prints one warning line and returns None: the pipeline uses its threads.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from multiprocessing import shared_memory, spawn
from multiprocessing.connection import wait
from typing import Any

import numpy as np

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.processes import die_with_parent

from ..sequence import TumSequence, ahead
from .auto import FREE_CORES, SAMPLE_S, free_cores, resolve_mode  # noqa: F401 (re-exported)
from .orb import Features, OrbConfig, OrbExtractor
from .pools import one_thread_pools_for_life

PREFETCH_MODES = ("auto", "thread", "process")
"""Values of ``slam.prefetch_mode`` (``auto``: :func:`resolve_mode`)."""

POLL_S = 0.2
"""How often a blocked side looks whether the other one has gone, seconds."""

_warned: set[str] = set()
"""Fallback reasons warned about already (one line per reason and process)."""


@dataclass(frozen=True)
class _Layout:
    """Where each image of a frame lies in a slot of the shared ring (byte offsets)."""

    height: int
    width: int
    labels: bool

    @property
    def parts(self) -> list[tuple[str, tuple[int, ...], np.dtype]]:
        h, w = self.height, self.width
        parts = [
            ("rgb", (h, w, 3), np.dtype(np.uint8)),
            ("gray", (h, w), np.dtype(np.uint8)),
            ("depth", (h, w), np.dtype(np.float32)),
        ]
        if self.labels:
            parts.append(("labels", (h, w), np.dtype(np.uint8)))
        return parts

    @property
    def slot_bytes(self) -> int:
        return sum(int(np.prod(shape)) * dtype.itemsize for _, shape, dtype in self.parts)

    def views(self, buffer: memoryview, slot: int) -> dict[str, np.ndarray]:
        """The arrays of ``slot`` as views into the shared ``buffer``."""
        out, offset = {}, slot * self.slot_bytes
        for name, shape, dtype in self.parts:
            count = int(np.prod(shape))
            out[name] = np.frombuffer(buffer, dtype, count, offset).reshape(shape)
            offset += count * dtype.itemsize
        return out


@dataclass
class Extracted:
    """One frame as the worker process prepared it (its depth and labels only where it read
    them, else the main process does): frame ``index`` at ``stamp`` (s), its images as in
    :class:`~..sequence.Frame`, the features extracted without depth (completed by
    :meth:`~.orb.OrbExtractor.with_depth`), the wall and CPU seconds of reading and ORB."""

    index: int
    stamp: float
    rgb: np.ndarray
    gray: np.ndarray
    labels: np.ndarray | None
    """As ``depth``: None where the main process reads them (or the sequence has none)."""
    depth: np.ndarray | None
    """``(H, W)`` float32 metres where the worker read it (the main process was behind), else
    None: the main process reads it."""
    read_time: tuple[float, float]
    features: Features
    orb_time: tuple[float, float]


@dataclass
class Received:
    """A frame the worker process has sent, its images still in slot ``slot`` of the ring:
    :meth:`take` copies them out and gives the slot back (in a prefetch thread of the main
    process, off the main thread's path)."""

    source: FrontendProcess
    slot: int
    meta: dict[str, Any]
    features: Features
    orb_time: tuple[float, float]

    def take(self) -> Extracted:
        return self.source.take(self)


class FrontendProcess:
    """The worker process and its shared ring; iterate once for the frames in order.

    Use :func:`start` (which falls back to None where a process cannot be used); always
    :meth:`close` (the iterator's end and the pipeline's ``finally`` do).
    """

    def __init__(
        self,
        sequence: TumSequence,
        orb: OrbConfig,
        prefetch: int,
        workers: int,
        behind: int | None = None,
        slots: int | None = None,
    ) -> None:
        """``behind``: the worker reads a frame's depth and labels itself when at most this
        many slots are free (None: :data:`BEHIND`; -1: never); ``slots``: :func:`ring_slots`."""
        self.sequence = sequence
        self._closed = False
        self._lock = threading.Lock()
        self._untaken = 0
        """Frames received whose images are still in the ring (:meth:`take` not called yet)."""
        self._received_all = False
        self.worker_cpu = 0.0
        """CPU seconds the worker process had used when it sent the last frame received."""
        width, height = sequence.image_size
        self.layout = _Layout(height, width, sequence.load_labels)
        if slots is None:
            slots = ring_slots(prefetch, self.layout.slot_bytes, shared_memory_free())
        slots = self.slots = max(1, slots)
        context = _context()
        self._shm: shared_memory.SharedMemory | None = shared_memory.SharedMemory(
            create=True, size=slots * self.layout.slot_bytes
        )
        self._ready: Any = context.Queue()
        self._free: Any = context.Queue()
        self._stop = context.Event()
        for slot in range(slots):
            self._free.put(slot)
        self._proc = context.Process(
            target=_serve,
            args=(
                sequence,
                orb,
                max(1, prefetch),
                max(1, workers),
                self._shm.name,
                self.layout,
                self._ready,
                self._free,
                self._stop,
                BEHIND if behind is None else behind,
            ),
            name="uss-slam-frontend",
            daemon=True,
        )
        try:
            with _starting():
                self._proc.start()
        except BaseException:  # a Ctrl-C held back while starting may arrive after the start
            self.close()
            raise
        # The worker has its copy of the queue's write end: without this one, a worker that dies
        # in the middle of a message leaves the reader at end-of-file instead of waiting forever.
        self._ready._writer.close()

    def __iter__(self) -> Iterator[Received]:
        """Every frame in order; the worker and the ring are freed once the last one is taken
        (or at once when the caller stops early or fails: :meth:`close`)."""
        try:
            for index in range(len(self.sequence)):
                yield self._receive(index)
        except BaseException:
            self.close()
            raise
        with self._lock:
            self._received_all = True
            done = self._untaken == 0
        if done:
            self.close()

    def _receive(self, index: int) -> Received:
        message = self._get(index)
        kind = message[0]
        if kind == "error":
            raise _rebuild_error(message[1:])
        _, slot, meta, features, orb_time = message
        self.worker_cpu = meta["cpu"]
        with self._lock:
            self._untaken += 1
        return Received(self, slot, meta, features, orb_time)

    def take(self, received: Received) -> Extracted:
        """The images of ``received`` copied out of its slot, which goes back to the worker
        (from any thread)."""
        meta = received.meta
        with self._lock:
            if self._shm is None:
                raise UssSlamError(
                    f"{self.sequence.records[meta['index']].rgb_path}: the frame reader "
                    "process was closed before this frame was taken"
                )
            views = self.layout.views(self._shm.buf, received.slot)
            images = {name: view.copy() for name, view in views.items() if meta.get(name, True)}
            del views  # no view may outlive the slot (nor keep the buffer from closing)
            self._untaken -= 1
            done = self._received_all and self._untaken == 0
            self._free.put(received.slot)
        if done:
            self.close()
        return Extracted(
            meta["index"],
            meta["stamp"],
            images["rgb"],
            images["gray"],
            images["labels"] if meta["labels"] else None,
            images["depth"] if meta["depth"] else None,
            meta["read_time"],
            received.features,
            received.orb_time,
        )

    def _get(self, index: int) -> tuple:
        """The worker's next message, waiting as long as the worker lives."""
        while True:
            try:
                return self._ready.get(timeout=POLL_S)
            except queue.Empty:
                if self._proc.is_alive():
                    continue
            except (EOFError, OSError):  # it died while sending
                self._proc.join(timeout=2.0)
            record = self.sequence.records[index]
            raise UssSlamError(
                f"{record.rgb_path}: the frame reader process ended (exit code "
                f"{self._proc.exitcode}) before this frame was read and extracted"
            )

    def close(self) -> None:
        """Stop the worker (at once: frames it prepared ahead are dropped) and free the ring."""
        with self._lock:  # once, whichever thread asks first
            if self._closed:
                return
            self._closed = True
        proc = self._proc
        self._stop.set()
        if proc.is_alive():
            proc.join(timeout=2 * POLL_S + 0.5)
        if proc.is_alive():
            proc.terminate()
            proc.join(timeout=2.0)
        if proc.is_alive():
            proc.kill()
            proc.join()
        self._release()

    def _release(self) -> None:
        with self._lock:  # not while a prefetch thread takes a frame (take)
            for q in (self._ready, self._free):
                q.cancel_join_thread()  # nobody reads them any more: never block on feeders
                q.close()
            if self._shm is not None:
                self._shm.close()
                with contextlib.suppress(FileNotFoundError):
                    self._shm.unlink()
                self._shm = None


def _context() -> Any:
    """Where the worker comes from: Python's fork server (started once per process, with this
    module imported: a worker then starts in milliseconds instead of the second a fresh
    interpreter takes to import it), else a spawned interpreter. Never a plain fork of this
    process, which runs threads."""
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload([__name__])
        return context
    return multiprocessing.get_context("spawn")


@contextlib.contextmanager
def _without_main() -> Iterator[None]:
    """Start a child that does not import the main script.

    multiprocessing has every child run the parent's main script again (as ``__mp_main__``)
    so that it can unpickle what the script defined, and Python 3.11's fork server never
    preloads it (it looks for a ``main_path`` its preparation data does not have): each worker
    re-ran ``uss-slam``'s imports (Hydra, GTSAM, the whole harness), 0.2 CPU s and 0.3-0.8 s
    before its first frame, per run, and a script without a ``__main__`` guard ran again in
    it. The worker's target and arguments are this package's: the main script is left out of
    the preparation data while it starts."""
    real = spawn.get_preparation_data

    def prepared(name: str) -> dict[str, Any]:
        data = real(name)
        data.pop("init_main_from_path", None)
        data.pop("init_main_from_name", None)
        return data

    spawn.get_preparation_data = prepared
    try:
        yield
    finally:
        spawn.get_preparation_data = real


@contextlib.contextmanager
def _starting() -> Iterator[None]:
    """The conditions for starting the worker.

    Ctrl-C is blocked meanwhile (delivered to this process afterwards): the child inherits the
    mask and sets Ctrl-C aside before unblocking it, so that a Ctrl-C while its interpreter
    starts does not end it with a traceback (as multiprocessing's resource tracker does). The
    default start method is a standard one: a spawned child sets the parent's default method
    before anything else, and inside joblib's workers that is ``loky``, which a fresh
    interpreter does not know (it would fail before running any code)."""
    method = multiprocessing.get_start_method(allow_none=True)
    swap = method not in (None, *multiprocessing.get_all_start_methods())
    if swap:
        multiprocessing.set_start_method("spawn", force=True)
    mask = hasattr(signal, "pthread_sigmask")
    if mask:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        with _without_main():
            yield
    finally:
        if mask:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        if swap:
            multiprocessing.set_start_method(method, force=True)


def start(
    sequence: TumSequence, orb: OrbConfig, prefetch: int, workers: int
) -> FrontendProcess | None:
    """The worker process for ``sequence``, or None (after one warning line on stderr, once per
    reason) where this process cannot start one; the caller then reads and extracts in threads."""
    try:
        return FrontendProcess(sequence, orb, prefetch, workers)
    except (AssertionError, OSError, ValueError, RuntimeError) as err:
        # AssertionError: multiprocessing's "daemonic processes are not allowed to have
        # children"; OSError: no shared memory, no process; RuntimeError: not allowed here.
        reason = str(err) or type(err).__name__
        if reason not in _warned:
            _warned.add(reason)
            print(
                f"uss-slam: warning: slam.prefetch_mode=process: cannot start the frame reader "
                f"process ({reason}); reading and ORB extraction run in threads",
                file=sys.stderr,
            )
        return None


# ------------------------------------------------------------------------ the worker process


def _serve(
    sequence: TumSequence,
    orb: OrbConfig,
    prefetch: int,
    workers: int,
    shm_name: str,
    layout: _Layout,
    ready: Any,
    free: Any,
    stop: Any,
    behind: int,
) -> None:
    """The worker process: read and extract every frame in order into the ring, until done,
    told to stop, or the parent is gone; its depth too when at most ``behind`` slots are free."""
    for sig in (signal.SIGINT, signal.SIGQUIT):  # Ctrl-C and Ctrl-\ are the parent's to handle
        signal.signal(sig, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by _starting
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _end_with_parent()
    one_thread_pools_for_life()
    shm = _attach(shm_name)
    index = 0
    try:
        extractor = OrbExtractor(orb, sequence.camera)

        def prepare(k: int) -> tuple[_Images, Features, tuple[float, float]]:
            wall, cpu = time.perf_counter(), time.thread_time()
            images = _Images(k, *sequence.load_colour(k))
            if _main_is_behind(free, behind):  # else the main process reads them
                images.depth, images.labels = sequence.load_depth_and_labels(k)
            images.read_time = (time.perf_counter() - wall, time.thread_time() - cpu)
            wall, cpu = time.perf_counter(), time.thread_time()
            features = extractor(images.gray, None)  # the depth: sampled in the main process
            return images, features, (time.perf_counter() - wall, time.thread_time() - cpu)

        items = ahead(prepare, iter(range(len(sequence))), prefetch, workers)
        try:
            while not stop.is_set():
                item = next(items, None)
                if item is None:
                    return
                frame, features, orb_time = item
                slot = _free_slot(free, stop)
                if slot is None:
                    return
                _write_slot(layout, shm.buf, slot, frame)
                meta = {
                    "index": frame.index,
                    "stamp": sequence.records[frame.index].stamp,
                    "read_time": frame.read_time,
                    "labels": frame.labels is not None,
                    "depth": frame.depth is not None,
                    "cpu": time.process_time(),
                }
                ready.put(("frame", slot, meta, features, orb_time))
                index += 1
        finally:
            items.close()
    except Exception as err:  # noqa: BLE001 (every failure goes to the parent, as one line)
        ready.put(("error", *_describe_error(err, sequence, index)))
    finally:
        shm.close()
        if stop.is_set():  # the parent reads no more: do not wait to flush the queue at exit
            ready.cancel_join_thread()


def _attach(name: str) -> shared_memory.SharedMemory:
    """The main process's ring, attached without telling multiprocessing's resource tracker.

    The ring is the main process's to create, register and unlink. Before Python 3.13 attaching
    registers the name again with the tracker this worker shares with the main process; a
    worker that attaches just after the main process (stopped early) unlinked the ring would
    leave the tracker a name it then reports, at exit, as a leaked object it cannot find."""
    try:
        return shared_memory.SharedMemory(name=name, track=False)  # type: ignore[call-arg]
    except TypeError:  # Python < 3.13: no ``track``
        pass
    from multiprocessing import resource_tracker

    register = resource_tracker.register
    resource_tracker.register = lambda *_: None  # nothing else in this worker creates shared memory
    try:
        return shared_memory.SharedMemory(name=name)
    finally:
        resource_tracker.register = register


def _end_with_parent() -> None:
    """End this worker (SIGTERM) as soon as the main process has ended, however it ended. The
    kernel's parent-death signal is not enough: a fork server's child has the server as its
    parent, and the server lives as long as any of its children."""
    parent = multiprocessing.parent_process()
    if parent is None:
        die_with_parent(os.getppid())
        return

    def watch() -> None:
        wait([parent.sentinel])
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="uss-slam-frontend-watch", daemon=True).start()


@dataclass
class _Images:
    """What the worker reads of frame ``index`` (:meth:`~..sequence.TumSequence.load_colour`)."""

    index: int
    rgb: np.ndarray
    gray: np.ndarray
    labels: np.ndarray | None = None
    depth: np.ndarray | None = None
    read_time: tuple[float, float] = (0.0, 0.0)


RING_FRAMES = 32
"""Frames the ring holds (:func:`ring_slots`): the main thread's work comes in bursts (a new
keyframe's local BA or loop closing, GTSAM holding the GIL), and with ``prefetch`` (4) slots
the worker stopped in each one (benchmarks/frame_ring_model.py)."""
RING_BYTES = 96 * 2**20
"""At most this much shared memory for the ring (~34 frames of 640x480)."""


def ring_slots(prefetch: int, slot_bytes: int, free: int | None = None) -> int:
    """Frames of ``slot_bytes`` in the ring: :data:`RING_FRAMES`, in at most :data:`RING_BYTES`
    and half of ``free`` bytes (None: no bound), never fewer than ``prefetch`` (nor than 1)."""
    most = RING_BYTES if free is None else min(RING_BYTES, free // 2)
    return max(1, prefetch, min(RING_FRAMES, most // max(1, slot_bytes)))


def ring_bytes(height: int, width: int, prefetch: int) -> int:
    """The most shared memory a ring of ``width`` x ``height`` frames takes (with labels)."""
    slot = _Layout(height, width, labels=True).slot_bytes
    return ring_slots(prefetch, slot) * slot


def shared_memory_free() -> int | None:
    """Bytes free in ``/dev/shm`` (Docker: 64 MB; past it a worker dies of SIGBUS), or None."""
    try:
        stat = os.statvfs("/dev/shm")
    except OSError:
        return None
    return stat.f_bavail * stat.f_frsize


BEHIND = 1
"""The worker reads a frame's depth and labels itself when at most this many slots of the ring
are free as it starts reading the frame (:func:`_main_is_behind`)."""


def _main_is_behind(free: Any, behind: int) -> bool:
    """Whether the main process is the slower side now: at most ``behind`` slots of the ring
    are free (:data:`BEHIND` by default), the rest hold frames it has not taken yet. Then the
    worker, which would otherwise wait for a free slot, reads the next frame's depth and labels
    too; else the main process's prefetch threads read them (:meth:`FrontendProcess.take`'s
    caller). Which side reads them changes nothing else: the trajectory is the same."""
    try:
        return free.qsize() <= behind
    except NotImplementedError:  # no sem_getvalue (macOS): the main process reads every depth
        return False


def _write_slot(layout: _Layout, buffer: memoryview, slot: int, frame: _Images) -> None:
    """Copy the frame's images into ``slot`` (the views end with the call: the shared memory
    cannot be closed while one exists)."""
    for name, view in layout.views(buffer, slot).items():
        image = getattr(frame, name)
        if image is not None:
            view[...] = image


def _free_slot(free: Any, stop: Any) -> int | None:
    """A slot the main process has given back, or None once told to stop."""
    while not stop.is_set():
        try:
            return free.get(timeout=POLL_S)
        except queue.Empty:
            continue
    return None


def _describe_error(err: BaseException, sequence: TumSequence, index: int) -> tuple:
    """A picklable description of a worker's error (project errors keep their type)."""
    if isinstance(err, DataFormatError):
        return ("data", err.path, err.detail, err.line)
    if isinstance(err, UssSlamError):
        return ("project", str(err))
    path = sequence.records[index].rgb_path if index < len(sequence) else sequence.path
    return ("project", f"{path}: {type(err).__name__}: {err} (in the frame reader process)")


def _rebuild_error(description: tuple) -> UssSlamError:
    if description[0] == "data":
        return DataFormatError(description[1], description[2], description[3])
    return UssSlamError(description[1])
