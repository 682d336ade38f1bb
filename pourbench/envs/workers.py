"""Worker processes for the vector env: each holds a contiguous group of worlds.

Warp runs CPU kernels on one thread, so a vector env spreads its worlds over processes to use
every core. The parent process holds the first group itself; each further group lives in a
worker started as ``python -c "...serve(...)"`` (a fresh interpreter, as
multiprocessing's "spawn" would give, so no Warp, CUDA or OpenGL state is inherited through
``fork``, and the caller's ``__main__`` is not re-imported). Parent and worker talk over a
socket pair with :class:`multiprocessing.connection.Connection`; each worker loads Warp's
compiled kernels from the kernel cache. Every operation is sent to all workers before the
parent does its own group's share and then collects the answers, so the groups step at the
same time.

A world's results depend only on its own state (the solver's worlds are independent and each
world draws from its own generator), so world ``k`` gives the same numbers whichever group
holds it.
"""

from __future__ import annotations

import itertools
import os
import pickle
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

import mujoco
import numpy as np

from pourbench.envs.core import PourBatch, PourConfig, ResetDraw
from pourbench.envs.options import ResetOptions
from pourbench.envs.pour_v0 import RENDER_SIZE, render_world

_CLOSE_TIMEOUT_S = 10.0
_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_WORKER_MAIN = (
    "import sys; from multiprocessing.connection import Connection; "
    "from pourbench.envs.workers import serve; serve(Connection(int(sys.argv[1])))"
)


class WorkerError(RuntimeError):
    """A vector env's worker process died or stopped answering."""


class WorldGroup:
    """``num_worlds`` consecutive worlds of a vector env in one process (one :class:`PourBatch`).

    Its methods are what a worker serves; the parent calls its own group's directly.
    """

    def __init__(self, num_worlds: int, config: PourConfig) -> None:
        self.batch = PourBatch(num_worlds, config)
        self.drawn: list[tuple[int, ResetDraw]] = []

    def draw_resets(self, seeds: list[int | None], mask: np.ndarray, options: ResetOptions) -> None:
        """Check and draw the resets of the worlds in ``mask`` (seed ``seeds[k]``, the other
        ``options``) without changing any world (:meth:`PourBatch.draw_reset`); a refusal
        keeps none of them."""
        self.drawn = []
        self.drawn = [
            (int(k), self.batch.draw_reset(int(k), seeds[k], options)) for k in np.flatnonzero(mask)
        ]

    def apply_resets(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Apply the resets :meth:`draw_resets` drew; every world's observation and info
        (:meth:`PourBatch.reset_info`)."""
        for k, draw in self.drawn:
            self.batch.apply_reset(k, draw)
        self.drawn = []
        self.batch.flush()
        return self.batch.observe(), self.batch.reset_info()

    def step(
        self, actions: np.ndarray, resetting: np.ndarray, same_step: bool
    ) -> tuple[
        np.ndarray,
        np.ndarray,
        np.ndarray,
        np.ndarray,
        dict[str, np.ndarray],
        np.ndarray | None,
    ]:
        """One vector step of these worlds (see :class:`~pourbench.envs.vector.PourVectorEnv`).

        ``resetting`` worlds (next-step autoreset) hold still and are reset after the step,
        returning their first observation with reward 0. With ``same_step``, worlds whose
        episode ended are reset now: the returned observation and info are the new
        episode's for them, and ``final`` holds the step's observations and info (None when
        no world ended).
        """
        b = self.batch
        obs, rew, term, trunc, info = b.step(actions, active=~resetting)
        if resetting.any():
            for k in np.flatnonzero(resetting):
                b.reset_world(int(k))
            b.flush()
            obs = b.observe()
            for key, v in b.reset_info().items():
                info[key] = np.where(resetting, v, info[key])
        rew = np.where(resetting, 0.0, rew)
        term, trunc = term & ~resetting, trunc & ~resetting
        done = term | trunc
        final = None
        if same_step and done.any():
            final = obs.copy(), dict(info)
            for k in np.flatnonzero(done):
                b.reset_world(int(k))
            b.flush()
            obs = b.observe()
            info = {key: np.where(done, v, info[key]) for key, v in b.reset_info().items()}
        return obs, rew, term, trunc, info, final

    def set_lesson(self, k: int) -> None:
        """Draw liquids from curriculum lesson ``k`` at later resets."""
        self.batch.set_lesson(k)

    def render(self) -> list[np.ndarray]:
        """One RGB image per world."""
        if getattr(self, "_renderer", None) is None:
            self._renderer = mujoco.Renderer(self.batch.model, *RENDER_SIZE, max_geom=20000)
        return [render_world(self.batch, w, self._renderer) for w in range(self.batch.n)]

    def solver_seconds(self, synchronize: bool | None = None) -> float:
        """Seconds spent in the solver's steps so far (see :meth:`PourBatch.time_solver`;
        ``synchronize`` switches the device synchronisation on or off first)."""
        if synchronize is not None:
            self.batch.time_solver(synchronize)
        return self.batch.solver_seconds

    def call(self, world: int, fn: Callable[..., Any], args: tuple) -> Any:
        """``fn(batch, world, *args)`` (``world`` is the index within this group)."""
        return fn(self.batch, world, *args)

    def close(self) -> None:
        renderer = getattr(self, "_renderer", None)
        if renderer is not None:
            renderer.close()
            self._renderer = None


class LocalGroup:
    """The parent's own group, behind the same send / receive interface as a worker."""

    def __init__(self, num_worlds: int, config: PourConfig) -> None:
        self.group = WorldGroup(num_worlds, config)
        self._result: tuple[bool, Any] = (True, None)

    def send(self, method: str, *args: Any) -> None:
        try:
            self._result = (True, getattr(self.group, method)(*args))
        except Exception as exc:  # raised at receive(), after the workers have answered
            self._result = (False, exc)

    def receive(self) -> Any:
        ok, value = self._result
        self._result = (True, None)
        if not ok:
            raise value
        return value

    def close(self) -> None:
        self.group.close()


class RemoteGroup:
    """A worker process holding one group of worlds.

    Args:
        index: the worker's number (for messages).
        first: index of its first world in the vector env (for messages).
    """

    def __init__(self, index: int, first: int, num_worlds: int, config: PourConfig) -> None:
        self.name = f"worker {index} (worlds {first}-{first + num_worlds - 1})"
        ours, theirs = socket.socketpair()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
        for var in _THREAD_VARS:  # a worker is one core's share: no BLAS/OpenMP thread pools
            env.setdefault(var, "1")
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", _WORKER_MAIN, str(theirs.fileno())],
                pass_fds=(theirs.fileno(),),
                env=env,
                close_fds=True,
            )
        finally:
            theirs.close()
        self.conn = Connection(ours.detach())
        self.conn.send((num_worlds, config))
        self._pending = True

    def send(self, method: str, *args: Any) -> None:
        self._check_alive()
        try:
            self.conn.send((method, args))
        except OSError as exc:
            raise self._died() from exc
        self._pending = True

    def receive(self, timeout: float | None = None) -> Any:
        start = time.monotonic()
        try:
            while not self.conn.poll(0.2):
                self._check_alive()
                if timeout is not None and time.monotonic() - start > timeout:
                    raise WorkerError(f"{self.name} did not answer within {timeout:g} s")
            ok, value = self.conn.recv()
        except (EOFError, OSError) as exc:
            raise self._died() from exc
        finally:
            self._pending = False
        if not ok:
            raise value
        return value

    def _check_alive(self) -> None:
        if self.proc.poll() is not None:
            raise self._died()

    def _died(self) -> WorkerError:
        code = self.proc.poll()
        if code is None:
            try:
                code = self.proc.wait(1.0)
            except subprocess.TimeoutExpired:
                code = None
        how = "stopped answering" if code is None else f"died (exit status {code})"
        return WorkerError(f"Pour-v0 vector env: {self.name} {how}; the vector env is closed")

    def close(self) -> None:
        """Ask the worker to finish, then end it if it does not."""
        if self.proc.poll() is None:
            try:
                if self._pending:  # an unanswered call (after an error elsewhere)
                    self.conn.poll(_CLOSE_TIMEOUT_S)
                    self.conn.recv()
                self.conn.send(("close", ()))
                self.proc.wait(_CLOSE_TIMEOUT_S)
            except (OSError, EOFError, subprocess.TimeoutExpired):
                pass
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.conn.close()


def serve(conn: Connection) -> None:
    """A worker's loop: build the group from the first message, then answer calls until
    "close" or until the parent goes away."""
    try:
        num_worlds, config = conn.recv()
        group = WorldGroup(num_worlds, config)
    except EOFError:
        return
    except Exception as exc:
        conn.send((False, _portable(exc)))
        return
    conn.send((True, None))
    while True:
        try:
            method, args = conn.recv()
        except (EOFError, OSError):
            return
        if method == "close":
            group.close()
            return
        try:
            out = getattr(group, method)(*args)
        except Exception as exc:
            conn.send((False, _portable(exc)))
            continue
        conn.send((True, out))


def _portable(exc: Exception) -> Exception:
    """``exc`` if it survives pickling (the parent re-raises it as is), else a
    ``RuntimeError`` carrying its type and message."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"in a Pour-v0 worker: {type(exc).__name__}: {exc}")
    return exc


def default_workers(num_envs: int) -> int:
    """Every core this process may use, at most one worker per world."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, num_envs))


def split(num_envs: int, workers: int) -> list[tuple[int, int]]:
    """``workers`` contiguous (first, count) groups of ``num_envs`` worlds, sizes within one."""
    base, extra = divmod(num_envs, workers)
    counts = [base + (1 if i < extra else 0) for i in range(workers)]
    return list(zip(itertools.accumulate(counts[:-1], initial=0), counts, strict=True))
