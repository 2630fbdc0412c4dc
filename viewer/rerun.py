"""The viewer's re-runs in one child process kept between them.

The pipeline runs outside the window's process (its compiled loops hold the
GIL for seconds). A new process per re-run would pay, every time, for the
interpreter, the imports (NumPy, SciPy, numba, libigl: about half a second)
and the loading of the compiled kernels from numba's cache (about a third of
a second), more than a preview's refinement itself. So one child, started
when a parameter is first edited (or by the first re-run), imports the
pipeline once and serves the re-runs in turn:
a re-run with only psi changed then costs what the run costs (the stage
cache supplies the rest, :mod:`fracture.pipeline.cache`). A child that died
is started again for the next re-run.
"""

from __future__ import annotations

import multiprocessing as mp
import time

# Seconds between the idle child's checks that the window's process is still there.
_PARENT_CHECK = 0.5
# Seconds a child cut short has to remove its staging directory before it is killed.
_TERM_GRACE = 2.5


class RerunWorker:
    """One child process that runs configs into run directories, one at a time, and reports
    ``(event, data)`` on :attr:`events`: ``("stage", {"name"})``, ``("iteration", {...})`` (at most
    four a second), then ``("done", {})`` or ``("error", text)`` for each job."""

    def __init__(self):
        self._ctx = mp.get_context("spawn")  # the window's process holds GUI threads: never fork it
        self._proc = None
        self._jobs = None
        self.events = None

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.is_alive()

    @property
    def exitcode(self) -> int | None:
        return None if self._proc is None else self._proc.exitcode

    def start(self) -> None:
        """Start the child (again, if it died); it imports the pipeline while the window goes on."""
        if self.alive:
            return
        self._jobs, self.events = self._ctx.Queue(), self._ctx.Queue()
        self._proc = self._ctx.Process(target=_serve, args=(self._jobs, self.events), name="fracref-rerun",
                                       daemon=True)
        self._proc.start()

    def submit(self, cfg: dict, out: str) -> None:
        """Run ``cfg`` into the run directory ``out`` after the jobs before it."""
        self.start()
        self._jobs.put((cfg, out))

    def close(self, timeout: float = 0.0) -> None:
        """Let the child end after its current job; wait up to ``timeout`` seconds for it."""
        if self.alive:
            self._jobs.put(None)
            self._proc.join(timeout)

    def stop(self, timeout: float = 1.0) -> None:
        """End the child: after its current job if that ends within ``timeout`` seconds, else cut short
        (SIGTERM: the run's staging directory is removed, :func:`~fracture.io.atomic.staged_directory`),
        killed if it has not ended :data:`_TERM_GRACE` seconds later (a compiled loop keeps the signal
        waiting; the next run into the same place removes what a killed one left)."""
        self.close(timeout)
        if self.alive:
            self._proc.terminate()
            self._proc.join(_TERM_GRACE)
            if self.alive:
                self._proc.kill()
                self._proc.join(timeout)


def _cut_short(signum, frame) -> None:
    """The child's SIGTERM (from :meth:`RerunWorker.stop`): unwind, so that the run's staging directory goes;
    inside a callback from the compiler's C code, where the exception would be printed and dropped and the
    run go on until it is killed (its staging left behind), a moment later
    (:func:`fracture.process.later_if_compiling`)."""
    from fracture.process import later_if_compiling

    if later_if_compiling(signum, frame):
        return
    raise KeyboardInterrupt


def _serve(jobs, events) -> None:
    """The child: import the pipeline once, then run the jobs until told to stop (``None``) or until the
    window's process is gone (however it ended: the child must not outlive it)."""
    import importlib
    import queue
    import signal

    from fracture.process import prepare_process

    signal.signal(signal.SIGTERM, _cut_short)  # this process's own handler (a child of its own)

    importlib.import_module("fracture.pipeline.runner")  # the pipeline's imports now, while nobody waits

    prepare_process()
    parent = mp.parent_process()
    try:
        while True:
            try:
                job = jobs.get(timeout=_PARENT_CHECK)
            except queue.Empty:
                if parent is not None and not parent.is_alive():
                    return
                continue
            if job is None:
                return
            run_job(*job, events)
    except KeyboardInterrupt:  # cut short by stop(): a run's staging directory is gone already
        return


def run_job(cfg: dict, out: str, events) -> None:
    """Run the pipeline into ``out`` with its stages and iterations sent to ``events``; stages whose inputs
    did not change are taken from the stage cache (:mod:`fracture.pipeline.cache`)."""
    from fracture.pipeline import runner
    from fracture.pipeline.cache import StageCache

    last = [0.0]

    def listener(event, data):
        if event == "iteration":  # at most four surfaces a second, the first at once
            now = time.monotonic()
            if now - last[0] < 0.25:
                return
            last[0] = now
        events.put((event, data))

    try:
        runner.run(cfg, out, progress=False, listener=listener, cache=StageCache())
        events.put(("done", {}))

    except Exception as exc:  # noqa: BLE001 - sent to the window
        events.put(("error", f"{type(exc).__name__}: {exc}"))

