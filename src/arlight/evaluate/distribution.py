"""Numbers over many worlds: per-method distributions and the equal-time comparison with
``onepass`` (issue #30).

A method's quality on generated worlds is a distribution, not a number: :func:`spread` gives
its median, its 10th-percentile world (the value 90 % of the worlds do better than) and its
worst world. :func:`method_rows` tabulates them per method (and per world class) for PSNR,
FLIP, PSNR on the pixels the insertion changes and frame time.

**Equal time.** For every world the harness times ``onepass`` on a ladder of sample counts
(:data:`LADDER_SPP`, one warm-up and one timed frame each, the world prepared once, as every
method's frames are timed). A method that renders a frame in ``t`` seconds is compared with
the best ``onepass`` frame of that world that took at most ``t``: the *step* rule
:func:`onepass_at`, which never gives ``onepass`` more time than the method had. Where even
one sample per pixel takes longer than ``t``, ``onepass`` has no frame in that time; the
comparison counts as a win of the method and the Δ is left out of the spread.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

LADDER_SPP = (1, 2, 4, 8, 16, 32, 64, 128, 256)
"""Sample counts of the ``onepass`` time ladder (stopped once a frame takes longer than the
slowest method of the world)."""
LADDER_METHOD = "onepass"


@dataclass
class LadderPoint:
    """One timed ``onepass`` frame of a world: spp, seconds, and its metrics (``psnr``,
    ``changed_psnr``, ``flip``)."""

    spp: int
    seconds: float
    metrics: dict[str, float]


@dataclass
class Spread:
    """A distribution over worlds: ``n`` values, their median, the 10th-percentile world
    (``p10``: 90 % of the worlds are better) and the worst world."""

    n: int
    median: float
    p10: float
    worst: float


def spread(values: Iterable[float], higher_is_better: bool = True) -> Spread:
    """:class:`Spread` of the finite ``values`` (NaN fields when there are none). The
    percentile is NumPy's linear interpolation; "worst" is the minimum, or the maximum
    when lower is better."""
    import numpy as np  # here: the command line imports LADDER_SPP without NumPy

    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if v.size == 0:
        return Spread(0, math.nan, math.nan, math.nan)
    q = 10.0 if higher_is_better else 90.0
    return Spread(int(v.size), float(np.median(v)), float(np.percentile(v, q)),
                  float(v.min() if higher_is_better else v.max()))


def onepass_at(ladder: Sequence[LadderPoint], seconds: float) -> LadderPoint | None:
    """The ``onepass`` frame of ``ladder`` with the most samples among those that took at
    most ``seconds`` (None when every frame took longer)."""
    fit = [p for p in ladder if p.seconds <= seconds]
    return max(fit, key=lambda p: p.spp) if fit else None


@dataclass
class MethodRow:
    """One method's distribution over the worlds of a group (all, or one class)."""

    method: str
    group: str
    ran: int
    skipped: int
    failed: int
    psnr: Spread
    changed_psnr: Spread
    flip: Spread
    seconds: Spread
    equal_time_delta: Spread
    """PSNR(method) − PSNR(onepass at the method's time), dB, over the worlds where onepass
    had a frame in that time."""
    equal_time_changed_delta: Spread
    wins: int
    """Worlds where the method's PSNR beats onepass at its time (or onepass had no frame)."""
    compared: int
    no_onepass_frame: int
    """Worlds where even onepass's 1-spp frame took longer than the method's frame."""


def method_rows(cells, classes: dict[str, str], groups: bool = True) -> list[MethodRow]:
    """Per method (and per world class when ``groups``): the spreads of its cells' metrics.

    ``cells`` are :class:`~arlight.evaluate.harness.CellResult` with, for equal time, the
    metrics ``onepass_at_time_psnr`` / ``onepass_at_time_changed_psnr`` (NaN: onepass had
    no frame in the method's time) and ``onepass_at_time_spp``; ``classes`` maps a scene to
    its world class.
    """
    methods = list(dict.fromkeys(c.method for c in cells))
    names = ["all", *sorted(set(classes.values()))] if groups else ["all"]
    rows = []
    for group in names:
        for m in methods:
            mine = [c for c in cells if c.method == m
                    and (group == "all" or classes.get(c.scene) == group)]
            ok = [c for c in mine if c.ok]
            eq = [c for c in ok if "onepass_at_time_spp" in c.metrics]
            delta = [c.metrics["psnr"] - c.metrics["onepass_at_time_psnr"] for c in eq]
            cdelta = [c.metrics["changed_psnr"] - c.metrics["onepass_at_time_changed_psnr"]
                      for c in eq]
            wins = sum(not d <= 0 for d in delta)  # NaN (onepass had no frame) is a win
            rows.append(MethodRow(
                method=m, group=group, ran=len(ok),
                skipped=sum(bool(c.skipped) for c in mine),
                failed=sum(bool(c.error) for c in mine),
                psnr=spread(c.metrics["psnr"] for c in ok),
                changed_psnr=spread(c.metrics["changed_psnr"] for c in ok),
                flip=spread((c.metrics["flip"] for c in ok), higher_is_better=False),
                seconds=spread((c.seconds for c in ok), higher_is_better=False),
                equal_time_delta=spread(delta), equal_time_changed_delta=spread(cdelta),
                wins=wins, compared=len(eq),
                no_onepass_frame=sum(c.metrics["onepass_at_time_spp"] == 0 for c in eq)))
    return rows
