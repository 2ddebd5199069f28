"""Method variants for the evaluation: a registered method with some options fixed.

    arlight eval -m onepass,onepass+denoise=oidn,onepass+denoise=oidn+denoise_quality=fast

``NAME+key=value[+key=value…]`` is the method ``NAME`` with those options (as
``--option NAME.key=value``, but as its own column, so the plain method and the variant are
compared in one run). A variant's options are validated by the method's option table before
any cell runs; ``--option`` entries for the variant's name or bare keys apply on top.
"""

from __future__ import annotations

from arlight.methods.spec import parse_option_pairs

SEP = "+"


def split_variant(name: str) -> tuple[str, dict[str, str]]:
    """``(method, options)`` of a method or variant name (``options`` empty for a plain
    method); a malformed pair raises :class:`~arlight.errors.InputError`."""
    base, *pairs = name.split(SEP)
    return base, parse_option_pairs(pairs, "METHOD+key=value") if pairs else {}


def base_method(name: str) -> str:
    """The registered method behind a method or variant name."""
    return name.split(SEP, 1)[0]


__all__ = ["SEP", "base_method", "split_variant"]
