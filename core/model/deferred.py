"""A model's re-optimisation run beside the instrument: started when new data land, collected at the next fit.

Re-optimising the two-fidelity model's hyperparameters after a fast array lands takes seconds at thousands of
fast indents (docs/two-fidelity.md, "Scale"); the instrument's next block takes minutes (≥ 40 s per CSM
indent). So the decision after the array is made on the model conditioned with the hyperparameters it had,
and the re-optimisation, a pure function of the data at the landing, runs on a thread started once that
decision is made, while the block runs. Its result is installed at the next fit whether the thread has
finished or not (then the fit waits for it; never started, the fit runs it), so a run's plans do not depend
on how fast the machine is.
"""

from __future__ import annotations

import copy
import threading
from collections.abc import Callable
from typing import Generic, TypeVar

import torch

T = TypeVar("T")


class Deferred(Generic[T]):
    """``work`` on a thread once ``start``ed (torch on the caller's ``threads``); ``result``
    waits for it, or runs it in the caller where it was never started."""

    def __init__(self, work: Callable[[], T], threads: int) -> None:
        self._work = work
        self._threads = threads
        self._value: T | None = None
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._ran = False  # run in the caller (never started), or copied finished

    def start(self) -> None:
        if self._thread is None and not self._ran:
            # not a daemon: an interpreter that exits mid-fit waits for it (seconds) rather than tearing torch
            # down under a running thread, which aborts the process
            self._thread = threading.Thread(target=self._run, name="aeni-reoptimise")
            self._thread.start()

    def _run(self) -> None:
        # held to the caller's torch thread count when the work was made: with this build's count process-wide
        # (a new thread reads what the main thread set: checked) this changes nothing, and with an OpenMP
        # build whose count is per thread it keeps the result the synchronous fit's, bit for bit
        torch.set_num_threads(self._threads)
        self._call()

    def _call(self) -> None:
        try:
            self._value = self._work()
        except BaseException as exc:  # handed to the caller at ``result``: the run, not the thread, decides
            self._error = exc

    def __deepcopy__(self, memo: dict[int, object]) -> Deferred[T]:
        """A copy with its own work: not started, a deep copy of the work (a bound method copies its object);
        started, the result (waited for), copied."""
        if self._thread is None and not self._ran:
            return Deferred(copy.deepcopy(self._work, memo), self._threads)
        finished: Deferred[T] = Deferred(self._work, self._threads)
        finished._value = copy.deepcopy(self.result(), memo)
        finished._ran = True
        return finished

    @property
    def done(self) -> bool:
        return self._ran or (self._thread is not None and not self._thread.is_alive())

    def result(self) -> T:
        """The work's value; its exception is raised here, in the caller's thread."""
        if self._thread is None and not self._ran:
            self._ran = True
            self._call()
        elif self._thread is not None:
            self._thread.join()
        if self._error is not None:
            raise self._error
        assert self._value is not None
        return self._value
