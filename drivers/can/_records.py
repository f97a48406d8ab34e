"""Fast positional construction of frozen slotted dataclasses, for records made on every CAN frame.

A frozen dataclass's generated ``__init__`` stores each field through ``object.__setattr__``,
which for the records of the live CAN path (a frame, its decoded roles) costs more than the
decoding itself. :func:`positional_constructor` builds the record as an instance of a plain class
with the same slots (CPython stores into those with a specialised instruction) and then gives it
its real class, which CPython allows between identical slot layouts. The result is an ordinary
instance of the dataclass: equality, hashing, ``repr``, ``dataclasses.replace`` and frozenness are
unchanged. Where the class layout does not allow it, the dataclass itself is returned.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["positional_constructor"]

_T = TypeVar("_T")


def positional_constructor(cls: type[_T]) -> Callable[..., _T]:
    """``cls(*fields)`` (every field, positionally, defaults not applied) without ``cls.__init__``.

    Only for slotted dataclasses without ``__post_init__``; otherwise (or if the interpreter refuses
    the class change) returns ``cls``.
    """
    if not dataclasses.is_dataclass(cls) or hasattr(cls, "__post_init__"):
        return cls
    names = [f.name for f in dataclasses.fields(cls)]
    slots = cls.__dict__.get("__slots__")
    bases = [b for b in cls.__mro__[1:-1] if b.__dict__.get("__slots__")]
    if bases or not isinstance(slots, tuple) or set(slots) != set(names) or not all(n.isidentifier() for n in names):
        return cls
    twin = type(f"_{cls.__name__}Builder", (), {"__slots__": slots, "__module__": cls.__module__})
    args = ", ".join(f"a{i}" for i in range(len(names)))
    lines = [f"def new({args}):", "    o = _new(_twin)"]
    lines += [f"    o.{n} = a{i}" for i, n in enumerate(names)]
    lines += ["    o.__class__ = _cls", "    return o"]
    ns: dict[str, Any] = {"_new": object.__new__, "_twin": twin, "_cls": cls}
    exec(compile("\n".join(lines), f"<constructor {cls.__name__}>", "exec"), ns)  # source: field names only
    new: Callable[..., _T] = ns["new"]
    try:
        probe = new(*range(len(names)))
    except TypeError:
        return cls
    return new if type(probe) is cls and probe == cls(*range(len(names))) else cls
