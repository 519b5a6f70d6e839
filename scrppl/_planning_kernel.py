"""The sampled planner's kernel, tuned for the CPU (private: read :mod:`scrppl.planning` first).

:func:`scrppl.planning.sampled_expected_entropy` states the paper's estimator (Meger et al. 2010, eq. 5)
in a few lines of plain JAX: draw a state from the current belief, a response from its Gaussian, update,
average the posterior entropy. This module computes the same numbers for all candidate views at once,
fast enough that the planning decision costs about as much as a filter update:

* :func:`_draws` -- ``jax.random``'s own uniforms and normals (bit for bit), with the Threefry-2x32 hash
  unrolled (:func:`_threefry2x32`) instead of JAX's rolled CPU loop;
* :func:`_components` -- the drawn mixture components, by inverse CDF;
* :func:`_sampled_entropies` -- the mean posterior entropy of every candidate, with common random
  numbers, one polynomial power of two (:func:`_exp2`) per component, sample and candidate, and fused
  scans that keep the work in the first-level cache;
* :func:`_sampled_expected_entropy` -- one candidate's value, for the extensions that score mixtures one
  at a time.

``tests/test_planning.py`` checks the draws against :mod:`jax.random`, :func:`_exp2` against NumPy and the
kernel against :func:`scrppl.planning.sampled_expected_entropy` and
:func:`scrppl.planning.posterior_entropy` on the very same responses.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from scrppl.belief import Mixture

#: Threefry-2x32 rotation constants (Salmon et al. 2011), as in :mod:`jax.random`.
_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def _threefry2x32(k1, k2, x1, x2):
    """The Threefry-2x32 hash (20 rounds) of counters ``(x1, x2)`` under key ``(k1, k2)``, unrolled.

    The same function :mod:`jax.random` uses for its default keys, written out so that it compiles to a
    few fused elementwise operations (JAX's CPU lowering is a rolled loop of dozens of small kernels,
    which costs more than the planning decision itself).
    """
    ks = (k1, k2, k1 ^ k2 ^ np.uint32(0x1BD11BDA))
    x1 = x1 + ks[0]
    x2 = x2 + ks[1]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x1 = x1 + x2
            x2 = (x2 << np.uint32(r)) | (x2 >> np.uint32(32 - r))
            x2 = x1 ^ x2
        x1 = x1 + ks[(i + 1) % 3]
        x2 = x2 + ks[(i + 2) % 3] + np.uint32(i + 1)
    return x1, x2


def _unit_floats(bits):
    """Float32 numbers in ``[0, 1)`` from 32 random bits, as :func:`jax.random.uniform` makes them."""
    one = np.array(1.0, np.float32).view(np.uint32)
    return jax.lax.bitcast_convert_type((bits >> np.uint32(9)) | one, jnp.float32) - 1.0


def _fast_draws_apply(key) -> bool:
    """Whether :func:`_draws` can compute ``jax.random``'s numbers itself (float32, default Threefry keys)."""
    if not jax.config.jax_threefry_partitionable:
        return False
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return str(jax.random.key_impl(key)) == "threefry2x32"
    return key.dtype == jnp.uint32 and key.shape[-1:] == (2,)


def _draws(key: jax.Array, n_samples: int, dtype) -> tuple[jax.Array, jax.Array]:
    """The sampled planner's ``2 M`` random numbers: a uniform (the component) and a normal per sample.

    ``u = uniform(k1)`` and ``eps = normal(k2)`` with ``k1, k2 = split(key)``, exactly as
    :mod:`jax.random` draws them. For float32 and Threefry keys the hash is evaluated here, unrolled
    (same numbers, a fraction of the cost on the CPU); otherwise :mod:`jax.random` is called.
    """
    key = jnp.asarray(key) if not isinstance(key, jax.Array) else key
    if jnp.dtype(dtype) != jnp.float32 or not _fast_draws_apply(key):
        k_comp, k_eps = jax.random.split(key)
        u = jax.random.uniform(k_comp, (n_samples,), dtype)
        eps = jax.random.normal(k_eps, (n_samples,), dtype)
        return u, eps
    data = jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key
    zero = np.zeros(2, np.uint32)
    s1, s2 = _threefry2x32(data[0], data[1], zero, np.arange(2, dtype=np.uint32))  # split
    counts = np.arange(n_samples, dtype=np.uint32)
    b1, b2 = _threefry2x32(s1[:, None], s2[:, None], np.zeros_like(counts), counts)
    floats = _unit_floats(b1 ^ b2)  # (2, M)
    u = jnp.maximum(0.0, floats[0])
    lo = np.nextafter(np.float32(-1.0), np.float32(0.0))
    v = jnp.maximum(lo, floats[1] * (np.float32(1.0) - lo) + lo)
    eps = np.float32(math.sqrt(2.0)) * jax.lax.erf_inv(v)
    # computed once: left to itself XLA would fuse (and so repeat) the hash into every consumer
    return jax.lax.optimization_barrier((u, eps))


def _components(u, log_weight) -> jax.Array:
    """Components drawn by inverse CDF from flattened log weights ``(K,)``, one per uniform in ``u`` ``(M,)``.

    Counting (``#{k: cdf[k] <= u cdf[-1]}``) vectorises better than a binary search over a few dozen
    components; components of weight zero are never drawn.
    """
    cdf = jnp.cumsum(jnp.exp(log_weight))
    comp = jnp.sum(cdf[:, None] <= u * cdf[-1], axis=0)
    return jax.lax.optimization_barrier(jnp.minimum(comp, log_weight.shape[0] - 1))


def _sample_responses(key: jax.Array, mixture: Mixture, n_samples: int) -> jax.Array:
    """``M`` responses from the predictive mixture: a component by inverse CDF, then its Gaussian.

    Uses ``2 M`` random numbers (a uniform and a normal per sample), the same for every candidate
    when called with the same key: these are the responses that
    :func:`scrppl.planning.sampled_expected_entropy` scores.
    """
    u, eps = _draws(key, n_samples, mixture.mean.dtype)
    comp = _components(u, mixture.log_weight.ravel())
    return mixture.mean.ravel()[comp] + jnp.sqrt(mixture.var.ravel()[comp]) * eps


#: Mixture axes ``(N, O, A)`` of each objective's groups (whose masses enter the entropy) and of the
#: components summed within a group.
_GROUPS = {"joint": ((1, 2), (0,)), "class": ((1,), (0, 2)), "pose": ((2,), (0, 1))}

#: Exponents are taken relative to a reference at most this many nats below the largest component
#: constant, so that no exponential overflows (``e^60`` times the number of components stays finite
#: in float32); the drawn component's own term is then at least ``e^-60``, unless its weight is so
#: small (below ``e^-80`` of the largest) that inverse-CDF sampling in float32 does not draw it.
_MAX_SHIFT = 60.0

#: Minimax coefficients of ``2^r`` on ``[-1/2, 1/2]`` (degree 6, relative error 1e-7 in float32).
_EXP2_COEFFS = (
    1.0,
    0.6931471824645996,
    0.24022646248340607,
    0.055503278970718384,
    0.009618488140404224,
    0.001340025570243597,
    0.00015346636064350605,
)


def _exp2(x):
    """``2^x`` for float32 ``x <= 127``: a power of two times a polynomial (zero below ``-126.5``).

    A third cheaper than ``jnp.exp`` on the CPU (no special cases: the planner's exponents are finite
    and bounded above) with a relative error of about ``1e-7``, float32's own resolution. Other
    precisions use ``jnp.exp2``.
    """
    x = jnp.clip(x, -127.0, 127.0)
    n = jnp.round(x)
    r = x - n
    p = jnp.float32(_EXP2_COEFFS[-1])
    for coef in _EXP2_COEFFS[-2::-1]:
        p = p * r + jnp.float32(coef)
    # 2^n from its exponent bits; n = -127 gives the bit pattern of 0.0 (underflow to zero)
    scale = jax.lax.bitcast_convert_type((n.astype(jnp.int32) + 127) << 23, jnp.float32)
    return p * scale


def _sampled_entropies(u, eps, log_weight, mean, var, objective: str) -> jax.Array:
    """Mean posterior entropy over ``M`` sampled responses for candidates sharing their weights.

    The kernel of the sampled planner, written for the CPU. ``log_weight`` ``(N, O, A)`` are the
    mixture weights, the same for every candidate (they are the current belief over draw and state);
    ``mean`` and ``var`` are ``(C, N, O, A)``. Each sample ``m`` draws one component (shared by the
    candidates: common random numbers) and a response ``f[c, m]`` for each candidate ``c``. For each
    group ``g`` (a state ``(o, theta)`` for the joint objective, a class or a pose otherwise) with
    components ``j`` (the ``N`` draws, and the poses or classes summed over):

    ``q[g] = sum_j 2^(c[j] + a[j] (f - mean[j])^2 - ref)``, ``c = (log w - log(var) / 2) / log 2``,
    ``a = -1 / (2 var log 2)``, and ``H = log 2 (log2 Z - sum_g q[g] log2 q[g] / Z)``,
    ``Z = sum_g q[g]`` (exponents in bits, so that the exponential is a power of two).

    ``H`` does not depend on ``ref``; it is the drawn component's own log density (known without an
    exponential), raised where needed to at most :data:`_MAX_SHIFT` nats below ``max_j c[j]``, which
    bounds every exponent above. So there is one exponential per component, sample and candidate and
    no pass for a maximum. The drawn components' parameters are whole rows of a ``(K, 3, C)`` table,
    gathered once; then the groups are visited by a ``scan``, and the members of a group summed by an
    inner ``scan``, each step one fused elementwise loop over ``(C, M)`` (samples contiguous): nothing
    of size ``(K, C, M)`` is in memory and the work stays in the first-level cache. For the joint
    objective with one draw, ``log2 q[g]`` is the exponent itself (no logarithm).

    Returns ``(C,)`` expected entropies in nats.
    """
    n_c, n, n_o, n_a = mean.shape
    log2e = 1.0 / math.log(2.0)
    # impossible states (log weight -inf) get a very negative finite constant: no NaN arises
    c = jnp.maximum(log_weight - 0.5 * jnp.log(var), -1e30) * log2e
    a = -0.5 * log2e / var
    comp = _components(u, log_weight.ravel())  # (M,)
    table = jnp.stack([x.reshape(n_c, -1).T for x in (mean, jnp.sqrt(var), c)], axis=1)  # (K, 3, C)
    drawn = jnp.transpose(table[comp], (1, 2, 0))  # (3, C, M)
    f = drawn[0] + drawn[1] * eps
    c_max = c.reshape(n_c, -1).max(axis=1, keepdims=True)
    ref = jnp.maximum(drawn[2] - 0.5 * log2e * eps**2, c_max - _MAX_SHIFT * log2e)
    group_axes, member_axes = _GROUPS[objective]
    perm = tuple(1 + i for i in group_axes + member_axes) + (0,)

    def grouped(x):  # (C, N, O, A) -> (G, R, C, 1)
        x = jnp.transpose(x, perm)
        n_g = math.prod(x.shape[: len(group_axes)])
        return x.reshape(n_g, -1, n_c, 1)

    direct = objective == "joint" and n == 1
    exp2 = _exp2 if mean.dtype == jnp.float32 else jnp.exp2

    def exponent(mean, a, c):  # (C, 1) constants of one component -> (C, M) exponents, in bits
        return c - ref + a * (f - mean) ** 2

    def add_member(q, x):
        return q + exp2(exponent(*x)), None

    def body(carry, x):
        z, t = carry
        if x[0].shape[0] == 1:  # one component in the group
            d = exponent(*(v[0] for v in x))
            # materialised once: otherwise XLA fuses (and so repeats) it into both accumulations
            q = jax.lax.optimization_barrier(exp2(d))
            if direct:
                return (z + q, t + q * d), None
        else:  # members summed one at a time: every step is one fused loop over (C, M)
            q, _ = jax.lax.scan(add_member, jnp.zeros_like(f), x)
        qlogq = jnp.where(q > 0, q * jnp.log2(jnp.where(q > 0, q, 1.0)), 0.0)
        return (z + q, t + qlogq), None

    zero = jnp.zeros_like(f)
    xs = (grouped(mean), grouped(a), grouped(c))
    (z, t), _ = jax.lax.scan(body, (zero, zero), xs)
    return math.log(2.0) * (jnp.log2(z) - t / z).mean(axis=1)


@partial(jax.jit, static_argnames=("n_samples", "objective"))
def _sampled_expected_entropy(
    key: jax.Array, mixture: Mixture, n_samples: int, objective: str
) -> jax.Array:
    """:func:`scrppl.planning.sampled_expected_entropy` of one mixture ``(N, O, A)``, by the kernel.

    The same draws (``key``), so the same value to float32 rounding; a scalar in nats.
    """
    u, eps = _draws(key, n_samples, mixture.mean.dtype)
    lw, mean, var = mixture
    return _sampled_entropies(u, eps, lw, mean[None], var[None], objective)[0]
