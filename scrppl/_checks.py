"""When the input checks of the public entry points can look at values.

The public functions of :mod:`scrppl.belief`, :mod:`scrppl.planning`, :mod:`scrppl.sim` and
:mod:`scrppl.extensions` check their inputs before calling compiled code. Shapes are known even while
JAX traces a function (inside ``jit``, ``vmap`` or ``scan``), so shape checks always run -- under tracing,
once per compilation. Values (a view index, a NaN in a model) are known only for concrete arrays: those
checks run when :func:`is_concrete` says so and are skipped for tracers, so that the same functions
keep working inside compiled trial runners.
"""

from __future__ import annotations

import jax

__all__ = ["is_concrete"]


def is_concrete(*xs) -> bool:
    """Whether none of ``xs`` is a JAX tracer (their values can then be checked)."""
    for x in xs:
        if isinstance(x, jax.core.Tracer):
            return False
    return True
