"""One content hash for arlight's caches and resume checks: a canonical, type-tagged encoding.

``content_hash(value)`` is the SHA-256 of an encoding in which two values share bytes only when
they are equal *and of the same kind*:

* every value starts with a one-letter type tag, and every variable-length part (a string,
  a number's text, an array's bytes, a container's item count) is length-prefixed, so no
  two different sequences of values encode to the same bytes;
* ``None``, ``bool``, ``int`` (exact, any size), ``float`` (``repr``: round-trips exactly;
  ``-0.0``, ``nan`` and ``inf`` are distinct values), ``str`` (UTF-8), ``bytes``;
* ``list`` and ``tuple`` alike (a sequence, item by item);
* ``dict``: items sorted by their keys' encodings (any hashable key kind; ``{"1": x}`` and
  ``{1: x}`` differ);
* ``numpy.ndarray`` and numpy scalars: dtype, shape and the C-order bytes (no ``str()``
  elision of large arrays, no float64 conversion: a float32 and a float64 array differ);
* a path only when the caller says how: :class:`ByContent` (the SHA-256 of the file's bytes)
  or :class:`ByName` (its string); a bare :class:`pathlib.PurePath` is a ``TypeError``;
* anything else is a ``TypeError`` — never ``str(obj)``, which can make different inputs
  collide (an object whose ``str`` is ``"1"`` and the string ``"1"``).

The former hasher of :mod:`arlight.sequence.job` (``json.dumps(x, default=str)``) had both
collisions; this module replaces it.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

CHUNK = 1 << 20  # bytes read at a time when hashing a file's content


@dataclass(frozen=True)
class ByContent:
    """A file hashed by its bytes (its name and location do not count)."""

    path: str | PurePath


@dataclass(frozen=True)
class ByName:
    """A path hashed by its string as given (the file is not read)."""

    path: str | PurePath


def file_digest(path: str | PurePath) -> bytes:
    """SHA-256 of the bytes of the file at ``path``."""
    d = hashlib.sha256()
    with open(Path(path), "rb") as f:
        while chunk := f.read(CHUNK):
            d.update(chunk)
    return d.digest()


def _part(tag: bytes, payload: bytes) -> bytes:
    return tag + str(len(payload)).encode() + b":" + payload


def encode(value: Any) -> bytes:
    """The canonical encoding of ``value`` (see the module docstring)."""
    out: list[bytes] = []
    _encode(value, out)
    return b"".join(out)


def _encode(value: Any, out: list[bytes]) -> None:
    import sys

    np = sys.modules.get("numpy")  # numpy values can only exist if numpy is imported
    if value is None:
        out.append(b"N")
    elif value is True or value is False:
        out.append(b"T" if value else b"F")
    elif np is not None and isinstance(value, np.ndarray | np.generic):
        a = np.asarray(value)
        if a.dtype.hasobject:
            raise TypeError("content_hash: numpy arrays of Python objects have no canonical "
                            "bytes")
        a = np.ascontiguousarray(a)
        out.append(_part(b"a", f"{a.dtype.str}{list(a.shape)}".encode()))
        out.append(_part(b"", a.tobytes()))
    elif isinstance(value, int):
        out.append(_part(b"i", str(int(value)).encode()))
    elif isinstance(value, float):
        out.append(_part(b"f", repr(float(value)).encode()))
    elif isinstance(value, str):
        out.append(_part(b"s", value.encode("utf-8", "surrogatepass")))
    elif isinstance(value, bytes | bytearray | memoryview):
        out.append(_part(b"b", bytes(value)))
    elif isinstance(value, list | tuple):
        out.append(_part(b"l", str(len(value)).encode()))
        for x in value:
            _encode(x, out)
    elif isinstance(value, dict):
        items = sorted((encode(k), encode(v)) for k, v in value.items())
        out.append(_part(b"d", str(len(items)).encode()))
        for k, v in items:
            out += (k, v)
    elif isinstance(value, ByContent):
        out.append(_part(b"C", file_digest(value.path)))
    elif isinstance(value, ByName):
        out.append(_part(b"P", str(value.path).encode("utf-8", "surrogatepass")))
    elif isinstance(value, PurePath):
        raise TypeError(f"content_hash: say how the path {str(value)!r} counts: "
                        "ByContent(path) (its bytes) or ByName(path) (its string)")
    else:
        raise TypeError(f"content_hash: no canonical encoding for {type(value).__name__} "
                        "(convert it to plain data first)")


def content_hash(*values: Any, length: int = 64) -> str:
    """Hex SHA-256 of the canonical encoding of ``values`` (as one sequence), cut to
    ``length`` hex digits."""
    return hashlib.sha256(encode(list(values))).hexdigest()[:length]


__all__ = ["ByContent", "ByName", "content_hash", "encode", "file_digest"]
