"""Frozen records the daemon's cycle builds every loop period, built in one step. Pure, no I/O.

dataclasses' frozen `__init__` sets each field through `object.__setattr__` (about 0.3 µs a field on the 2-core
EPYC VM); the cycle builds a 26-field `Inputs`, a `Decision`, a `DodEstimate`, … every 20 ms, and a replay of a
20-minute log 60 000 times over (issue 14). `quick_init` gives such a class an `__init__` that fills the instance's
dict directly: the same instance, field for field and in the same order, as frozen afterwards (assigning a field
still raises `FrozenInstanceError`), built in about a third of the time.
"""

from __future__ import annotations

from dataclasses import MISSING, fields


def quick_init(cls):
    """`cls`, a frozen dataclass without slots, `__post_init__` or fields left out of its `__init__`, with an
    `__init__` of the same signature that stores the fields in the instance's dict."""
    fs = fields(cls)
    if not cls.__dataclass_params__.frozen or "__slots__" in cls.__dict__ or hasattr(cls, "__post_init__") or any(
            not f.init or f.kw_only for f in fs):
        raise TypeError(f"quick_init: {cls.__name__} is not a plain frozen dataclass")
    ns: dict = {"_FACTORY": _FACTORY}
    args, body = [], []
    for f in fs:
        if f.default is not MISSING:
            ns[f"_default_{f.name}"] = f.default
            args.append(f"{f.name}=_default_{f.name}")
        elif f.default_factory is not MISSING:  # as dataclasses does: a sentinel default, the factory called
            ns[f"_factory_{f.name}"] = f.default_factory
            args.append(f"{f.name}=_FACTORY")
            body.append(f"    if {f.name} is _FACTORY:\n        {f.name} = _factory_{f.name}()\n")
        else:
            args.append(f.name)
        body.append(f"    d[{f.name!r}] = {f.name}\n")
    exec(f"def __init__(self, {', '.join(args)}):\n    d = self.__dict__\n{''.join(body)}", ns)  # noqa: S102
    init = ns["__init__"]
    init.__qualname__, init.__module__ = f"{cls.__qualname__}.__init__", cls.__module__
    cls.__init__ = init
    return cls


_FACTORY = object()  # a field with a default factory was not given
