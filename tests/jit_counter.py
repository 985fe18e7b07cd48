"""Count FFCx compilations: a test and benchmark utility (it patches an FFCx internal).

Tests import it directly (``tests/`` is on ``sys.path`` under pytest); benchmarks add
``tests/`` to ``sys.path`` first. Not part of the package: a library must not patch FFCx.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator


@contextlib.contextmanager
def count_jit_compilations() -> Iterator[list[int]]:
    """Count FFCx C compilations (cache misses) inside a ``with`` block.

    Yields a one-element list holding the count so far.
    """
    import ffcx.codegeneration.jit as jit

    count = [0]
    original = jit._compile_objects

    def counting(*args, **kwargs):
        count[0] += 1
        return original(*args, **kwargs)

    jit._compile_objects = counting
    try:
        yield count
    finally:
        jit._compile_objects = original
