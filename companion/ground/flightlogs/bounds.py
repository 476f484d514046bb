"""What bounds the reading of one flight log — its size, its samples, a ULog's nesting, the time — and the
garbage collector's part in it: shared by the package's readers, which the package's registry imports when first
used (a module of its own, so that no reader imports the package that imports it)."""

from __future__ import annotations

import contextlib
import gc

MAX_BYTES = 1 << 30  # 1 GiB: about a day of a ground station's telemetry, hours of a PX4 log at full rate
MAX_SAMPLES = 5_000_000  # ops or packets of one log (≈ 5 h of a 250 message/s link)
MAX_DEPTH = 8  # nesting of a ULog's formats (PX4's deepest is 2)
MAX_FIELDS = 100_000  # fields of one ULog topic once its nested formats are flattened (PX4's largest: < 2 000)
MAX_SECONDS = 600.0  # reading and replaying one log


@contextlib.contextmanager
def gc_paused():
    """The block without the cyclic garbage collector: a reader builds a log's hundreds of thousands of
    long-lived objects (no cycles among them), which each full pass would walk again. Collected as usual after."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


@contextlib.contextmanager
def gc_frozen():
    """What is alive when the block starts (the read log) left out of the cyclic garbage collector's passes
    in it (`gc.freeze`); what the block makes is collected as usual."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
