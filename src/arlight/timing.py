"""Per-stage wall-clock timings of a method: prepare, setup, trace, assemble, ...

    timer = StageTimer()
    with timer.stage("trace"):
        result = trace(...)
        dr.eval(result)              # evaluate what the stage computed (see below)
    layers.stats.update(timer.stats())   # {"time_trace": 0.0123, ...} in seconds

Stages are flat (no nesting) and named once each per timer; a stage entered twice adds up.
:meth:`StageTimer.stats` names them ``time_<stage>`` in seconds, the convention every method
follows in ``Layers.stats`` (``time_prepare`` for scene-level work, ``time_trace`` for the
Monte Carlo passes, ``time_assemble`` for the reduction to layers and the composite, ...),
so the CLI and ``arlight eval`` tabulate them without knowing the method.

**Dr.Jit is asynchronous.** Operations on Dr.Jit arrays are recorded lazily and compiled
kernels are launched without waiting for them, so the clock of a stage could stop before its
work is done and the cost would be billed to a later stage. A stage therefore ends with
``dr.sync_thread()`` (waits for every kernel the thread launched) before it reads the clock.
That cannot run work nobody asked for: a stage must ``dr.eval(...)`` the arrays it produced
(or convert them to NumPy, which evaluates them), otherwise their kernels run, and are
timed, wherever they are first used. Pure NumPy stages pay nothing for the synchronisation:
it is skipped while Dr.Jit is not imported.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

PREFIX = "time_"


def synchronize() -> None:
    """Wait for all Dr.Jit kernels launched by this thread (no-op without Dr.Jit)."""
    dr = sys.modules.get("drjit")
    if dr is not None:
        dr.sync_thread()


class StageTimer:
    """Wall-clock seconds per named stage (``time.perf_counter``, Dr.Jit synchronised).

    Attributes:
        seconds: stage name -> seconds spent in it (summed if entered more than once), in
            the order the stages were first entered.
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._open: str | None = None

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as stage ``name``; synchronises Dr.Jit before stopping the clock.

        Raises RuntimeError when another stage of this timer is still open (stages are
        flat, so that they add up to no more than the total). A block that raises records
        nothing.
        """
        if self._open is not None:
            raise RuntimeError(f"stage {name!r} started inside stage {self._open!r}; "
                               "stages do not nest")
        self._open = name
        try:
            synchronize()  # work queued before the stage is not billed to it
            t0 = time.perf_counter()
            yield
            synchronize()
            self.add(name, time.perf_counter() - t0)
        finally:
            self._open = None

    def add(self, name: str, seconds: float) -> None:
        """Record ``seconds`` measured elsewhere under stage ``name`` (adds up)."""
        self.seconds[name] = self.seconds.get(name, 0.0) + float(seconds)

    @property
    def total(self) -> float:
        """Sum of all stages, seconds."""
        return sum(self.seconds.values())

    def stats(self) -> dict[str, float]:
        """``{"time_<stage>": seconds}`` for ``Layers.stats``."""
        return {PREFIX + k: v for k, v in self.seconds.items()}


def stage_times(stats: dict[str, float]) -> dict[str, float]:
    """The ``time_<stage>`` entries of a stats dict as ``{stage: seconds}``, in order."""
    return {k[len(PREFIX):]: float(v) for k, v in stats.items()
            if k.startswith(PREFIX) and isinstance(v, int | float)}


def format_stages(stats: dict[str, float]) -> str:
    """``prepare 9.8 ms · trace 20.3 ms · ...`` from the ``time_<stage>`` entries of a stats
    dict (empty string if there are none)."""
    return " · ".join(f"{k} {v * 1e3:.1f} ms" for k, v in stage_times(stats).items())
