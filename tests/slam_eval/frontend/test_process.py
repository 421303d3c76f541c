"""Reading and ORB extraction in a worker process (``slam.prefetch_mode=process``): the same
frames, features and trajectories as the threads; errors as one line naming the frame file; no
worker left behind after the end, an error, an interrupt or the parent's death; a clean fallback
to threads where no process can be started."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import slam_run_config

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend import auto as frontend_auto
from uss_slam.slam_eval.frontend import process as frontend_process
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.frontend.process import RING_BYTES, FrontendProcess, ring_slots
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems import harness
from uss_slam.slam_eval.systems.harness import RunResult, SlamPipeline


def _pipeline(path: Path, mode: str, **kwargs) -> SlamPipeline:
    seq = TumSequence(path, load_labels=True)
    return SlamPipeline(
        seq,
        LabelsSegmenter(),
        build_filters(["semantic"]),
        prefetch_mode=mode,
        progress=False,
        **kwargs,
    )


def _assert_same_run(a: RunResult, b: RunResult) -> None:
    np.testing.assert_array_equal(a.trajectory.stamps, b.trajectory.stamps)
    np.testing.assert_array_equal(a.trajectory.positions, b.trajectory.positions)
    np.testing.assert_array_equal(a.trajectory.quaternions, b.trajectory.quaternions)
    assert a.keypoints == b.keypoints
    assert a.log == b.log
    assert a.keyframes == b.keyframes and a.map_points == b.map_points
    np.testing.assert_array_equal(a.cloud.points, b.cloud.points)


def _workers() -> list:
    """This process's frame reader workers still running (joblib's pool may keep its own)."""
    return [p for p in multiprocessing.active_children() if p.name == "uss-slam-frontend"]


def _no_worker_left() -> None:
    deadline = time.monotonic() + 5.0
    while _workers() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _workers() == []


@pytest.fixture
def started(monkeypatch: pytest.MonkeyPatch) -> list:
    """The values :func:`frontend_process.start` returned during the test."""
    calls: list = []
    real = frontend_process.start

    def recording(*args, **kwargs):
        worker = real(*args, **kwargs)
        calls.append(worker)
        return worker

    monkeypatch.setattr(frontend_process, "start", recording)
    return calls


def test_reader_threads_sizes_the_worker_process_alone(synthetic_sequence, monkeypatch) -> None:
    """``reader_threads`` is the worker process's thread count; this process's prefetch threads
    (depth, labels, segmentation) stay ``workers``; the run is the same."""
    path = synthetic_sequence(frames=12)
    counts: list[tuple[str, int]] = []
    real_start, real_ahead = frontend_process.start, harness.ahead
    monkeypatch.setattr(frontend_process, "start",
                        lambda *a: counts.append(("reader", a[3])) or real_start(*a))  # fmt: skip
    monkeypatch.setattr(harness, "ahead",
                        lambda *a: counts.append(("prefetch", a[3])) or real_ahead(*a))  # fmt: skip
    default = _pipeline(path, "process", workers=3).run()  # one reading thread by default
    assert counts == [("reader", 1), ("prefetch", 3)]
    as_workers = _pipeline(path, "process", workers=3, reader_threads=None).run()
    assert counts[2:] == [("reader", 3), ("prefetch", 3)]
    _assert_same_run(default, as_workers)
    _no_worker_left()


@pytest.mark.parametrize("behind", [-1, 3])
def test_the_worker_yields_the_frames_and_features_of_the_threads(
    synthetic_sequence, behind: int
) -> None:
    """Every frame's images and features as the threads read and extract them, whether the
    main process reads the depth and labels (``behind=-1``) or the worker does (``behind`` =
    the ring's slots: always)."""
    seq = TumSequence(synthetic_sequence(frames=12), load_labels=True)
    config = OrbConfig(n_features=700)
    extractor = OrbExtractor(config, seq.camera)
    worker = FrontendProcess(seq, config, prefetch=3, workers=2, behind=behind, slots=3)
    got = [r.take() for r in worker]
    assert [e.index for e in got] == list(range(len(seq)))
    for extracted in got:
        frame = seq.load(extracted.index)
        assert (extracted.depth is None) == (extracted.labels is None) == (behind < 0)
        if behind < 0:  # what the main process reads
            extracted.depth, extracted.labels = seq.load_depth(extracted.index), frame.labels
        for name in ("rgb", "gray", "depth", "labels"):
            expected, actual = getattr(frame, name), getattr(extracted, name)
            assert actual.dtype == expected.dtype and actual.flags.writeable
            np.testing.assert_array_equal(actual, expected)
        assert extracted.stamp == frame.stamp
        reference = extractor(frame.gray, frame.depth)
        features = extractor.with_depth(extracted.features, extracted.depth)
        for field in fields(reference):
            np.testing.assert_array_equal(
                getattr(features, field.name), getattr(reference, field.name)
            )
        assert extracted.orb_time[0] > 0 and extracted.read_time[0] > 0
    _no_worker_left()


def test_the_worker_reads_the_depth_when_the_main_process_is_behind(synthetic_sequence) -> None:
    """A consumer slower than the worker leaves the ring full: the worker then reads depths too;
    the default leaves them to a consumer that keeps up."""
    seq = TumSequence(synthetic_sequence(frames=12), load_labels=True)
    slow = []
    for received in FrontendProcess(seq, OrbConfig(), prefetch=3, workers=1, slots=3):
        time.sleep(0.2)  # the worker fills the ring meanwhile
        slow.append(received.take().depth is not None)
    assert sum(slow) >= 6
    _no_worker_left()


def test_the_ring_holds_32_frames_within_its_memory_bound() -> None:
    """The ring absorbs the main thread's bursts (local BA, loop closing): 32 frames of
    640x480, fewer of larger frames or where /dev/shm is small, never fewer than ``prefetch``."""
    frame = 9 * 640 * 480
    assert ring_slots(4, frame) == 32
    assert ring_slots(40, frame) == 40
    assert ring_slots(4, 4 * frame) == RING_BYTES // (4 * frame) < 32
    assert ring_slots(2, RING_BYTES + 1) == 2
    docker = 64 * 2**20  # a container's default /dev/shm: half of it at most
    assert ring_slots(4, frame, free=docker) == docker // 2 // frame == 12
    assert ring_slots(4, frame, free=0) == 4


def test_process_mode_gives_the_threads_run_with_the_back_end(synthetic_sequence, started) -> None:
    path = synthetic_sequence(frames=30)
    backend = {"local_ba": True, "loop_closing": True}
    threads = _pipeline(path, "thread", **backend).run()
    processes = _pipeline(path, "process", **backend).run()
    assert len(started) == 1 and started[0] is not None  # it did run in a worker process
    assert processes.tracked == 30 and processes.keyframes > 1
    _assert_same_run(threads, processes)
    assert processes.segmented_frames == 30 and processes.cpu_ms["orb"] > 0
    _no_worker_left()


def test_uss_slam_repeats_and_a_comparison_in_process_mode(
    synthetic_sequence, tmp_path: Path, started
) -> None:
    path = synthetic_sequence(frames=12)
    common = ["segmenter=labels", "slam.repeats=2", "compare=[[semantic]]"]
    a = run(slam_run_config(path, tmp_path / "a", *common, "slam.prefetch_mode=thread"))
    b = run(slam_run_config(path, tmp_path / "b", *common, "slam.prefetch_mode=process"))
    assert len(started) == 4 and all(w is not None for w in started)  # 2 sets x 2 repeats
    for name in ("baseline", "semantic"):
        assert (tmp_path / "a" / name / "trajectory.txt").read_text() == (
            tmp_path / "b" / name / "trajectory.txt"
        ).read_text()
        assert a["comparison"][name]["ate"] == b["comparison"][name]["ate"]
    _no_worker_left()


def test_a_bad_frame_is_one_line_naming_its_file(synthetic_sequence, tmp_path: Path) -> None:
    source = synthetic_sequence(frames=8)
    path = tmp_path / "seq"
    subprocess.run(["cp", "-r", str(source), str(path)], check=True)
    seq = TumSequence(path, load_labels=True)
    broken = seq.records[5].rgb_path
    broken.write_bytes(b"not a png")
    worker = FrontendProcess(seq, OrbConfig(), prefetch=2, workers=2)
    seen = []
    with pytest.raises(DataFormatError) as caught:
        for received in worker:
            seen.append(received.take().index)
    assert seen == [0, 1, 2, 3, 4]
    assert str(caught.value) == (
        f"{broken}: not a readable image; expected a colour image (PNG or JPEG)"
    )
    _no_worker_left()
    # Through the pipeline: the same error, raised at that frame; and a broken depth image,
    # which this process or the worker reads.
    with pytest.raises(DataFormatError, match="not a readable image"):
        _pipeline(path, "process").run()
    _no_worker_left()
    subprocess.run(["cp", str(source / "rgb" / broken.name), str(broken)], check=True)
    depth = seq.records[5].depth_path
    depth.write_bytes(b"not a png")
    with pytest.raises(DataFormatError) as caught:
        _pipeline(path, "process").run()
    assert str(caught.value) == f"{depth}: not a readable image; expected a 16-bit depth PNG"
    _no_worker_left()


def test_an_interrupt_ends_the_worker_and_frees_its_memory(synthetic_sequence) -> None:
    seq = TumSequence(synthetic_sequence(frames=12), load_labels=True)
    worker = FrontendProcess(seq, OrbConfig(), prefetch=2, workers=1)
    name = worker._shm.name
    with pytest.raises(KeyboardInterrupt):
        for received in worker:
            if received.take().index == 2:
                raise KeyboardInterrupt
    _no_worker_left()
    assert not Path("/dev/shm", name).exists()


def test_the_worker_ends_with_a_killed_parent(synthetic_sequence, tmp_path: Path) -> None:
    if not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal is Linux's")
    path = synthetic_sequence(frames=12)
    script = textwrap.dedent(f"""
        import multiprocessing, sys, time
        from uss_slam.slam_eval.frontend.orb import OrbConfig
        from uss_slam.slam_eval.frontend.process import FrontendProcess
        from uss_slam.slam_eval.sequence import TumSequence
        if __name__ == "__main__":
            worker = FrontendProcess(TumSequence({str(path)!r}), OrbConfig(), 2, 1)
            frames = iter(worker)
            next(frames)
            print(worker._proc.pid, flush=True)
            time.sleep(60)
    """)
    (tmp_path / "parent.py").write_text(script)
    parent = subprocess.Popen(
        [sys.executable, str(tmp_path / "parent.py")], stdout=subprocess.PIPE, text=True
    )
    try:
        child = int(parent.stdout.readline())
        os.kill(child, 0)  # running
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and Path(f"/proc/{child}").exists():
            state = Path(f"/proc/{child}/stat").read_text().split()[2]
            if state == "Z":
                break  # ended, waiting for init to reap it
            time.sleep(0.05)
        else:
            assert not Path(f"/proc/{child}").exists(), "the worker outlived its parent"
    finally:
        if parent.poll() is None:
            parent.kill()


def test_a_script_without_a_main_guard_runs_once(synthetic_sequence, tmp_path: Path) -> None:
    """The worker never imports the main script (a script without the ``__main__`` guard
    would run again in it), and starts without its imports."""
    path = synthetic_sequence(frames=12)
    script = textwrap.dedent(f"""
        import sys
        from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
        from uss_slam.slam_eval.sequence import TumSequence
        from uss_slam.slam_eval.systems.harness import SlamPipeline
        print("script ran", flush=True)
        seq = TumSequence({str(path)!r}, load_labels=True)
        result = SlamPipeline(seq, LabelsSegmenter(), [], progress=False,
                              prefetch_mode="process").run()
        print("tracked", result.tracked, flush=True)
    """)
    (tmp_path / "unguarded.py").write_text(script)
    done = subprocess.run([sys.executable, str(tmp_path / "unguarded.py")],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["script ran", "tracked 12"]
    assert "warning" not in done.stderr


def test_no_process_possible_is_one_warning_and_the_threads_run(
    synthetic_sequence, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    path = synthetic_sequence(frames=12)
    threads = _pipeline(path, "thread").run()

    def no_shared_memory(*args, **kwargs):
        raise OSError("[Errno 38] Function not implemented: '/dev/shm'")

    monkeypatch.setattr(frontend_process.shared_memory, "SharedMemory", no_shared_memory)
    monkeypatch.setattr(frontend_process, "_warned", set())
    fallback = _pipeline(path, "process").run()
    again = _pipeline(path, "process").run()
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [
        "uss-slam: warning: slam.prefetch_mode=process: cannot start the frame reader process "
        "([Errno 38] Function not implemented: '/dev/shm'); reading and ORB extraction run in "
        "threads"
    ]
    _assert_same_run(threads, fallback)
    _assert_same_run(threads, again)


def test_an_unknown_mode_is_refused(synthetic_sequence) -> None:
    with pytest.raises(UssSlamError, match="prefetch_mode='fork': choose auto, thread or process"):
        _pipeline(synthetic_sequence(frames=12), "fork")


@pytest.mark.parametrize(
    ("cpus", "pool_child", "free", "expected"),
    [
        ({0, 1}, False, 1.9, "process"),
        ({0, 1}, False, None, "process"),  # no /proc/stat: the CPU count decides
        ({0, 1}, False, 1.0, "thread"),  # another job takes a core
        ({0, 1, 2, 3}, False, 2.5, "process"),
        ({0}, False, 1.0, "thread"),
        ({0, 1, 2, 3}, True, 4.0, "thread"),
    ],
)
def test_auto_is_the_process_where_the_run_has_a_second_core(
    monkeypatch, cpus, pool_child, free, expected
) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: cpus, raising=False)
    parent = object() if pool_child else None
    monkeypatch.setattr(multiprocessing, "parent_process", lambda: parent)
    monkeypatch.setattr(frontend_auto, "free_cores", lambda: free)
    assert frontend_process.resolve_mode("auto") == expected
    assert frontend_process.resolve_mode("thread") == "thread"
    assert frontend_process.resolve_mode("process") == "process"
    if not pool_child and len(cpus) >= 2:  # the memory estimate counts the process it may start
        assert frontend_process.resolve_mode("auto", sample=False) == "process"


def test_free_cores_from_the_cpu_times(monkeypatch, tmp_path: Path) -> None:
    cpu_times = frontend_auto._cpu_times
    times = iter([([100, 0, 50, 800, 50, 0, 0, 0], 2), ([150, 0, 100, 850, 50, 0, 0, 0], 2)])
    monkeypatch.setattr(frontend_auto, "_cpu_times", lambda stat: next(times))
    free = frontend_auto.free_cores(0.01, samples=1)  # one core busy (not this test's own)
    assert 0.5 < free < 2 * 50 / 150 + 0.5
    monkeypatch.setattr(frontend_auto, "_cpu_times", cpu_times)
    stat = tmp_path / "stat"
    stat.write_text(
        "cpu  10 0 5 80 5 0 0 0 0 0\ncpu0 5 0 2 40 3 0 0 0 0 0\ncpu1 5 0 3 40 2 0 0 0 0 0\n"
    )
    assert frontend_auto._cpu_times(str(stat)) == ([10, 0, 5, 80, 5, 0, 0, 0], 2)
    assert frontend_auto._cpu_times(str(tmp_path / "missing")) is None
    if Path("/proc/stat").is_file():
        real = frontend_auto.free_cores(0.02)
        assert real is None or 0.0 <= real <= (os.cpu_count() or 1) + 0.01


class _FakeStat:
    """A ``/proc/stat`` of two CPUs whose ``cpu`` line advances by one look of the sampler at
    each of its sleeps (3 ticks of 10 ms per CPU), with ``busy[k]`` cores busy in look k; its
    clock stands for ``time`` in the sampler (this process's own CPU time: none)."""

    def __init__(self, path: Path, busy: list[float]) -> None:
        self.path, self.busy, self.now = path, iter(busy), 0.0
        self.times = [0, 0, 0, 0, 0, 0, 0, 0]  # user nice system idle iowait irq softirq steal
        self._write()

    def _write(self) -> None:
        cpu = " ".join(map(str, self.times))
        self.path.write_text(
            f"cpu  {cpu} 0 0\ncpu0 0 0 0 0 0 0 0 0 0 0\ncpu1 0 0 0 0 0 0 0 0 0 0\n"
        )

    def sleep(self, seconds: float) -> None:
        busy = round(3 * next(self.busy))
        self.times[0] += busy
        self.times[3] += 6 - busy
        self.now += seconds
        self._write()

    def perf_counter(self) -> float:
        return self.now

    def process_time(self) -> float:
        return 0.0


@pytest.mark.parametrize(
    ("busy", "expected"),
    [
        ([0, 0, 0, 0, 0], "process"),  # idle cores
        ([2, 0, 0, 0, 0], "process"),  # a moment of work as the run starts, then idle
        ([0, 0, 2, 0, 0], "process"),
        ([1, 1.33, 1, 0.67, 1], "thread"),  # another job takes a core, steadily
        ([1, 1, 0, 1, 1], "thread"),  # ... and pauses for a moment
        ([2, 2, 2, 2, 2], "thread"),  # two other jobs
    ],
)
def test_auto_looks_past_a_moment_of_work(monkeypatch, tmp_path: Path, busy, expected) -> None:
    """``auto`` decides from the median of several short looks at ``/proc/stat``: a burst of
    work on otherwise idle cores (one busy look) does not make it take the threads; a load that
    lasts (busy in most looks) does."""
    fake = _FakeStat(tmp_path / "stat", busy)
    monkeypatch.setattr(frontend_auto, "time", fake)
    free = frontend_auto.free_cores(stat=str(fake.path))
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(multiprocessing, "parent_process", lambda: None)
    monkeypatch.setattr(frontend_auto, "free_cores", lambda: free)
    assert frontend_auto.resolve_mode("auto") == expected
    assert fake.now == pytest.approx(0.15)  # the run starts 0.15 s later for it


def test_auto_runs_are_the_threads_run(synthetic_sequence, monkeypatch, started) -> None:
    path = synthetic_sequence(frames=12)
    threads = _pipeline(path, "thread").run()
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(frontend_auto, "free_cores", lambda: 2.0)
    auto = _pipeline(path, "auto")
    _assert_same_run(threads, auto.run())
    assert auto.mode_used == "process" and len(started) == 1  # the worker process ran
    monkeypatch.setattr(frontend_auto, "free_cores", lambda: 0.7)  # the cores are busy
    _assert_same_run(threads, auto.run())
    assert auto.mode_used == "thread" and len(started) == 1


def _job_in_a_pool_worker(path: str) -> tuple[bool, np.ndarray]:
    """Whether a worker process can be started here, and the process-mode run's positions."""
    seq = TumSequence(path, load_labels=True)
    worker = frontend_process.start(seq, OrbConfig(), 2, 1)
    if worker is not None:
        worker.close()
    return worker is not None, _pipeline(Path(path), "process").run().trajectory.positions


def test_process_mode_inside_joblib_jobs(synthetic_sequence) -> None:
    """uss-experiments runs its jobs in joblib's (loky) worker processes."""
    joblib = pytest.importorskip("joblib")
    cloudpickle = pytest.importorskip("cloudpickle")

    path = synthetic_sequence(frames=12)
    expected = _pipeline(path, "thread").run().trajectory.positions
    module = sys.modules[__name__]
    cloudpickle.register_pickle_by_value(module)  # the pool's workers cannot import tests
    try:
        done = joblib.Parallel(n_jobs=2, backend="loky")(
            joblib.delayed(_job_in_a_pool_worker)(str(path)) for _ in range(2)
        )
    finally:
        cloudpickle.unregister_pickle_by_value(module)
    for usable, positions in done:
        assert usable
        np.testing.assert_array_equal(positions, expected)
    # One of several parallel jobs: auto leaves the cores to the other jobs (threads).
    modes = joblib.Parallel(n_jobs=2, backend="loky")(
        joblib.delayed(frontend_process.resolve_mode)("auto") for _ in range(2)
    )
    assert modes == ["thread", "thread"]


def _descendants(pid: int) -> dict[int, int]:
    """``{pid: parent pid}`` of every process below ``pid``."""
    found: dict[int, int] = {}
    parents = [pid]
    while parents:
        parent = parents.pop()
        for task in Path(f"/proc/{parent}/task").glob("*"):
            with contextlib.suppress(OSError):
                for child in (task / "children").read_text().split():
                    found[int(child)] = parent
                    parents.append(int(child))
    return found


def _gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"
    except OSError:
        return True


def _tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in path.rglob("*") if p.is_file()}


@pytest.mark.slow  # three uss-slam runs: ~30 s
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_uss_slam_stopped_mid_run_leaves_no_worker(sig, synthetic_sequence, tmp_path: Path) -> None:
    """Ctrl-C (to the whole process group, as a terminal sends it) or SIGTERM (to uss-slam
    alone) while the worker runs: one line, the exit code of the signal, the earlier run's
    outputs as they were, and no process left."""
    if not Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").exists():
        pytest.skip("needs /proc/<pid>/task/<tid>/children")
    uss_slam = Path(sys.executable).parent / "uss-slam"
    path = synthetic_sequence(frames=30)
    out = tmp_path / "run"
    args = [str(uss_slam), f"sequence.path={path}", f"out_dir={out}", "progress=false",
            "segmenter=labels", "slam.prefetch_mode=process"]  # fmt: skip
    subprocess.run([*args, "filters=[semantic]"], check=True, capture_output=True)
    before = _tree(out)
    proc = subprocess.Popen(
        [*args, "compare=[[semantic]]", "slam.repeats=3"],
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        # The worker: a child of the fork server (a child of uss-slam), or spawned.
        deadline, workers = time.monotonic() + 60, []
        while time.monotonic() < deadline and not workers and proc.poll() is None:
            below = _descendants(proc.pid)
            workers = [c for c, parent in below.items() if parent != proc.pid]
            time.sleep(0.05)
        assert workers, "the worker process never started"
        everyone = list(_descendants(proc.pid))
        time.sleep(0.5)  # mid-run
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + sig, err
    named = "" if sig == signal.SIGINT else " (SIGTERM)"
    assert err.strip().splitlines() == [f"uss-slam: interrupted{named}"], err
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not all(_gone(c) for c in everyone):
        time.sleep(0.05)
    assert all(_gone(c) for c in everyone)
    assert _tree(out) == before


def test_inside_a_daemonic_process_the_threads_run(synthetic_sequence, capfd) -> None:
    """A multiprocessing.Pool worker may not have children: one warning line, None."""
    seq = TumSequence(synthetic_sequence(frames=12))
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        got = pool.apply(frontend_process.start, (seq, OrbConfig(), 2, 1))
    assert got is None
    assert capfd.readouterr().err.splitlines() == [
        "uss-slam: warning: slam.prefetch_mode=process: cannot start the frame reader process "
        "(daemonic processes are not allowed to have children); reading and ORB extraction run "
        "in threads"
    ]


@pytest.mark.parametrize(
    ("override", "named"),
    [("slam.parallel=false", "slam.parallel=false"), ("slam.prefetch=0", "slam.prefetch=0")],
)
def test_process_mode_that_changes_nothing_warns(
    override: str, named: str, synthetic_sequence, tmp_path: Path, capsys, started
) -> None:
    path = synthetic_sequence(frames=12)
    run(slam_run_config(path, tmp_path / "out", "slam.prefetch_mode=process", override))
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert warnings == [
        f"uss-slam: warning: slam.prefetch_mode=process does nothing with {named} (the worker "
        "process needs slam.parallel=true and slam.prefetch > 0): frames are read and "
        "ORB-extracted in this process"
    ]
    assert started == []  # no worker process


def test_a_worker_that_dies_is_one_line_naming_the_frame(synthetic_sequence) -> None:
    """A worker killed from outside (out of memory, kill -9): the frames it sent, then one
    line naming the first frame it did not send, and no hang."""
    seq = TumSequence(synthetic_sequence(frames=30), load_labels=True)
    worker = FrontendProcess(seq, OrbConfig(), prefetch=2, workers=1)
    seen = []
    with pytest.raises(UssSlamError) as caught:
        for received in worker:
            seen.append(received.take().index)
            if len(seen) == 1:
                os.kill(worker._proc.pid, signal.SIGKILL)
    missing = seq.records[len(seen)].rgb_path
    assert seen == list(range(len(seen))) and len(seen) < 30
    assert str(caught.value) == (
        f"{missing}: the frame reader process ended (exit code -9) before this frame was read "
        "and extracted"
    )
    _no_worker_left()


def test_the_worker_attaches_the_ring_without_registering_it(monkeypatch) -> None:
    """Only the main process registers the ring with the resource tracker (and unregisters it
    when it unlinks): a worker that attached after a stop would otherwise leave the tracker a
    name it reports at exit as a leaked object."""
    from multiprocessing import resource_tracker, shared_memory

    from uss_slam.slam_eval.frontend import process

    ring = shared_memory.SharedMemory(create=True, size=64)
    try:
        registered: list[str] = []

        def record(name: str, rtype: str) -> None:
            registered.append(name)

        monkeypatch.setattr(resource_tracker, "register", record)
        attached = process._attach(ring.name)
        attached.buf[0] = 7
        assert ring.buf[0] == 7
        attached.close()
        assert registered == []
        assert resource_tracker.register is record  # put back for the rest of the process
    finally:
        ring.close()
        ring.unlink()
