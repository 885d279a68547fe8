"""Cold fits in a helper process beside the frame path: the tracking's refreshes (`tracking.refresh_*`).

A refresh fits a tracked person cold (the built-in initializer, the warm start one hypothesis among its
own) to catch a warm solve kept in a wrong minimum, e.g. a heading it inherited. Inline, that cold fit
holds up its frame for 3-5 frame periods at 10 Hz; a node that cannot keep up drops those frames. Here
it runs in a process of its own, at a lower scheduling priority (`tracking.refresh_nice`), on the core
the warm fits leave free: its frame is output warm, and the tracker takes the cold fit, when it is
better, as the start of a later warm solve (`frame_fitter.FrameFitter`).

The process is this module run as `python -m smplify3d_ros.tracking.background FD NICE`: it talks over
one end of a socket pair (`multiprocessing.connection.Connection`: pickled objects, both ends this
package's own; nothing read from a file or the network), builds its `Fitter` from the `FittingConfig`
it is sent first (and says `READY`), then answers each job `(id, people, K, lidar_origin, options)` with `(id, fits)` or
`(id, "error text")`. It exits when the connection closes. A separate interpreter, not a thread: the
fits are Python-heavy and would share the interpreter lock with the warm fits.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import weakref
from multiprocessing.connection import Connection
from typing import Any

from smplify3d_ros.fitting.config import FittingConfig
from smplify3d_ros.types import BodyFit

READY = "ready"  # the process's first message: its fitter is built


class BackgroundError(RuntimeError):
    """The helper process failed (it died, or a job did not finish within the timeout)."""


def _stop(proc: subprocess.Popen, conn: Connection) -> None:
    """Close the connection, which ends the process once it reads from it; one still loading its model
    (a loaded machine can take longer than the wait) is asked to end (SIGTERM: it exits quietly), then
    killed."""
    try:
        conn.close()
    except OSError:
        pass
    for escalate in (proc.terminate, proc.kill):
        try:
            proc.wait(timeout=5.0)
            return
        except subprocess.TimeoutExpired:
            escalate()
    proc.wait()


class BackgroundFitter:
    """A `Fitter` of `config` in a helper process: `submit` a frame's people, `result` waits for the fits.
    Jobs are answered in order. `close` (or garbage collection, or the interpreter's exit) ends it."""

    def __init__(self, config: FittingConfig, nice: int = 0) -> None:
        ours, theirs = socket.socketpair()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "smplify3d_ros.tracking.background", str(theirs.fileno()), str(nice)],
                pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL)
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        self._conn.send(config)
        self._next = 0
        self._done: dict[int, list[BodyFit] | str] = {}
        self._ready = False
        self._finalizer = weakref.finalize(self, _stop, self._proc, self._conn)

    @property
    def alive(self) -> bool:
        return self._finalizer.alive and self._proc.poll() is None

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait until the process has built its fitter (its body model loaded); False when it did not in
        `timeout_s` or exited."""
        if not self._ready:
            try:
                self._ready = self._conn.poll(timeout_s) and self._conn.recv() == READY
            except (EOFError, OSError):
                return False
        return self._ready

    def submit(self, people: list[Any], K: Any, lidar_origin: Any, options: Any) -> int:
        """Queue a fit of `people` (`Fitter.fit`'s arguments); returns the job's id."""
        job, self._next = self._next, self._next + 1
        try:
            self._conn.send((job, people, K, lidar_origin, options))
        except (OSError, ValueError) as e:
            raise BackgroundError(f"the background fitter is gone ({type(e).__name__}: {e})") from None
        return job

    def result(self, job: int, timeout_s: float) -> list[BodyFit]:
        """The fits of `job`, waiting up to `timeout_s`. Raises BackgroundError when the process died, the
        job failed in it, or the time ran out."""
        if not self.wait_ready(timeout_s):
            raise BackgroundError(f"the background fitter was not ready within {timeout_s:g} s")
        while job not in self._done:
            try:
                if not self._conn.poll(timeout_s):
                    raise BackgroundError(f"no result within {timeout_s:g} s")
                done, fits = self._conn.recv()
            except (EOFError, OSError) as e:
                raise BackgroundError(f"the background fitter exited ({type(e).__name__})") from None
            self._done[done] = fits
        fits = self._done.pop(job)
        if isinstance(fits, str):
            raise BackgroundError(f"the background fit failed: {fits}")
        return fits

    def close(self) -> None:
        self._finalizer()


def _serve(conn: Connection) -> None:
    from smplify3d_ros.fitting.fitter import Fitter

    try:
        fitter = Fitter(conn.recv())
        conn.send(READY)
    except (EOFError, OSError):  # the frame path closed its end (its run ended) before this was ready
        return
    while True:
        try:
            job, people, K, origin, options = conn.recv()
        except (EOFError, OSError):
            return
        try:
            answer = fitter.fit(people, K, origin, options)
        except Exception as e:  # noqa: BLE001 - one job's failure goes back as text; the process serves on
            answer = f"{type(e).__name__}: {e}"
        try:
            conn.send((job, answer))
        except OSError:  # the frame path closed its end (its run ended) while this job ran
            return


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: os._exit(0))  # asked to end (its run is over): quietly
    fd, nice = int(sys.argv[1]), int(sys.argv[2])
    if nice:
        try:
            os.nice(nice)
        except OSError:
            pass
    try:
        _serve(Connection(fd))
    except KeyboardInterrupt:
        pass
    # no interpreter shutdown: it puts the default SIGTERM action back and, with torch loaded, can take
    # seconds on a loaded machine, so that the frame path's SIGTERM (its 5 s wait over) killed the process
    # (-15) instead of ending it quietly; this process has nothing to flush
    os._exit(0)
