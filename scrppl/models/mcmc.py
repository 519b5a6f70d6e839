"""NUTS over host devices, compiled once per model and data shape.

NumPyro's ``MCMC(chain_method="parallel")`` builds a fresh ``pmap`` for every ``run`` and so recompiles
for every fit, even with ``jit_model_args=True``. Fitting every detector x target of a response table
means dozens of fits of *the same shapes* (the ``fit`` split has the same instances for every target),
so here the NUTS kernel (NumPyro's functional :func:`numpyro.infer.hmc.hmc` with ``potential_fn_gen``)
is wrapped in a ``pmap`` (chains over host devices; several chains per device are ``vmap``-ed) that takes
the data as an *argument*; the compiled executable is cached per model and shapes and reused by every
later fit. The run is split into chunks so that a progress bar can advance between them.

What limits reuse: a different number of instances, views, non-target categories, chains or draws
compiles anew (once). Host devices must be configured before JAX initialises
(``numpyro.set_host_device_count``; the CLI does it first thing); with fewer devices than chains the
chains share devices through ``vmap`` (slower per chain).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from numpyro.distributions import biject_to
from numpyro.handlers import seed, trace
from numpyro.infer.hmc import hmc
from numpyro.infer.util import constrain_fn, potential_energy

__all__ = ["SamplerConfig", "DEFAULT_SAMPLER", "run_nuts", "latent_site_shapes"]


class SamplerConfig(NamedTuple):
    """Settings of a NUTS run.

    Attributes
    ----------
    num_warmup, num_samples
        Warm-up (adaptation) and kept iterations per chain.
    num_chains
        Number of chains.
    target_accept_prob
        Dual-averaging target of the step-size adaptation. 0.95: on the default table, 2-4 of the 30
        fits had a few divergences at 0.9 (which ones depended on the seed), none or one at 0.95, for
        about 10 % more leapfrog steps; :func:`scrppl.models.fit.fit_hierarchical` refits a failed fit
        at 0.99.
    max_tree_depth
        Maximum NUTS tree depth.
    warmup_tree_depth
        Maximum tree depth during warm-up (``None``: ``max_tree_depth``). Before the first metric
        update (iteration 100 of a 500-iteration warm-up) the sampler runs with a unit metric, and on the
        paper table's fits its trees then took 200-350 leapfrog steps per iteration (30 afterwards),
        about half of a fit's sampling time. At depth 7 (at most 127 steps) the step size and the metric
        still adapt from the same windows; on the 30 fits of the full profile the stage took 14 % fewer
        CPU-seconds with the same fits retried and the same bulk ESS (``benchmarks/results/fit.json``,
        ``warmup_tree_depth``).
    dense_mass
        Adapt a dense mass matrix (the class level, the reference-coded elevation/scale effects and the
        category shifts are linearly correlated a posteriori; a dense metric removes that).
    chunk
        Iterations per compiled call (the progress bar advances once per chunk).
    """

    num_warmup: int = 500
    num_samples: int = 500
    num_chains: int = 4
    target_accept_prob: float = 0.95
    max_tree_depth: int = 10
    chunk: int = 250
    dense_mass: bool = False
    warmup_tree_depth: int | None = 7


#: Chains start uniformly in ``[-INIT_RADIUS, INIT_RADIUS]`` on the unconstrained scale.
INIT_RADIUS = 0.5

#: Default settings: 4 chains x (500 warm-up + 500 kept) draws.
DEFAULT_SAMPLER = SamplerConfig()


def latent_site_shapes(model, args) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """Unconstrained shapes of the latent sample sites of ``model(*args)``, in trace order."""
    tr = trace(seed(model, 0)).get_trace(*args)
    out = []
    for name, site in tr.items():
        if site["type"] == "sample" and not site["is_observed"]:
            value = biject_to(site["fn"].support).inv(site["value"])
            out.append((name, tuple(jnp.shape(value))))
    return tuple(out)


class _Compiled(NamedTuple):
    init: object
    step: object


@functools.lru_cache(maxsize=16)
def _compiled(
    model,
    shapes,
    n_devices: int,
    per_device: int,
    num_warmup: int,
    target_accept: float,
    max_tree_depth: int,
    chunk: int,
    dense_mass: bool,
    warmup_tree_depth: int | None = None,
) -> _Compiled:
    # NUTS runs on one flat vector (one op per integrator step instead of one per site)
    _, unravel = ravel_pytree({name: jnp.zeros(shape) for name, shape in shapes})
    size = sum(int(np.prod(shape)) for _, shape in shapes)

    def pe_gen(*args):
        return lambda z: potential_energy(model, args, {}, unravel(z))

    init_kernel, sample_kernel = hmc(potential_fn_gen=pe_gen, algo="NUTS")

    def init_one(key, args):
        k_init, k_run = jax.random.split(key)
        # start near the prior centre of the standardised model (unconstrained 0: unit scales, zero
        # effects), jittered so that chains start apart (R-hat needs dispersed starts)
        z0 = jax.random.uniform(k_init, (size,), minval=-INIT_RADIUS, maxval=INIT_RADIUS)
        return init_kernel(
            z0,
            num_warmup,
            target_accept_prob=target_accept,
            # (warm-up depth, depth after warm-up): NumPyro's NUTS takes the pair
            max_tree_depth=(
                max_tree_depth if warmup_tree_depth is None else int(warmup_tree_depth),
                max_tree_depth,
            ),
            dense_mass=dense_mass,
            model_args=args,
            rng_key=k_run,
        )

    def step_one(state, args):
        def body(s, _):
            s = sample_kernel(s, model_args=args)
            params = constrain_fn(model, args, {}, unravel(s.z), return_deterministic=True)
            stats = {
                "diverging": s.diverging,
                "energy": s.energy,
                "n_steps": s.num_steps,
                "acceptance_rate": s.accept_prob,
                "step_size": s.adapt_state.step_size,
                "lp": -s.potential_energy,
            }
            return s, (params, stats)

        return jax.lax.scan(body, state, None, length=chunk)

    # the acceptance target must be a constant: NumPyro's kernel keeps it in a closure shared by
    # ``init`` and ``step``, so a different target compiles anew
    init = jax.pmap(jax.vmap(init_one, in_axes=(0, None)), in_axes=(0, None))
    step = jax.pmap(jax.vmap(step_one, in_axes=(0, None)), in_axes=(0, None))
    return _Compiled(init, step)


def _device_split(n_chains: int) -> tuple[int, int]:
    """``(devices, chains per device)``: the most host devices that divide the chains evenly."""
    n_dev = max(
        d for d in range(1, min(n_chains, jax.local_device_count()) + 1) if n_chains % d == 0
    )
    return n_dev, n_chains // n_dev


def _drive(compiled, keys, args, config: SamplerConfig, n_chains: int, progress: bool, desc: str):
    """Run ``compiled`` from ``keys`` (``(devices, per_device)``); samples ``(n_chains, draws, ...)``."""
    from tqdm.auto import tqdm

    state = compiled.init(keys, args)
    total = config.num_warmup + config.num_samples
    n_chunks = -(-total // config.chunk)
    kept_params, kept_stats = [], []
    with tqdm(total=n_chunks * config.chunk, desc=desc, disable=not progress, leave=False) as bar:
        for c in range(n_chunks):
            state, (params, stats) = compiled.step(state, args)
            start = c * config.chunk
            lo = max(config.num_warmup - start, 0)
            hi = min(total - start, config.chunk)
            if hi > lo:
                kept_params.append(
                    jax.tree.map(lambda x, lo=lo, hi=hi: np.asarray(x[:, :, lo:hi]), params)
                )
                kept_stats.append(
                    jax.tree.map(lambda x, lo=lo, hi=hi: np.asarray(x[:, :, lo:hi]), stats)
                )
            bar.update(config.chunk)

    def merge(parts):
        out = jax.tree.map(lambda *xs: np.concatenate(xs, axis=2), *parts)
        return {k: v.reshape((n_chains,) + v.shape[2:]) for k, v in out.items()}

    return merge(kept_params), merge(kept_stats)


def _compile_for(model, args, config: SamplerConfig, n_chains: int):
    if config.warmup_tree_depth is not None and int(config.warmup_tree_depth) < 1:
        raise ValueError(
            f"warmup_tree_depth must be at least 1 (or None for max_tree_depth), got "
            f"{config.warmup_tree_depth}"
        )
    n_dev, per_device = _device_split(n_chains)
    compiled = _compiled(
        model,
        latent_site_shapes(model, args),
        n_dev,
        per_device,
        config.num_warmup,
        float(config.target_accept_prob),
        config.max_tree_depth,
        config.chunk,
        bool(config.dense_mass),
        config.warmup_tree_depth,
    )
    return compiled, n_dev, per_device


def run_nuts(
    key: jax.Array,
    model,
    args: tuple,
    config: SamplerConfig = DEFAULT_SAMPLER,
    progress: bool = True,
    desc: str = "NUTS",
) -> tuple[dict, dict]:
    """Run NUTS chains of ``model(*args)`` in parallel over the host devices.

    Parameters
    ----------
    key
        JAX PRNG key (one per fit; chains get split keys).
    model
        A NumPyro model (use the cached callables of :func:`scrppl.models.hierarchical.make_model` so
        compiled samplers are reused).
    args
        The model's positional arguments (arrays; their shapes key the compilation cache).
    config
        Sampler settings.
    progress
        Show a tqdm progress bar over iterations (all chains advance together).
    desc
        Label of the progress bar.

    Returns
    -------
    samples
        Every latent and deterministic site, each of shape ``(chains, draws, ...)`` (NumPy).
    stats
        ``diverging``, ``energy``, ``n_steps``, ``acceptance_rate``, ``step_size``, ``lp``, each
        ``(chains, draws)``.
    """
    compiled, n_dev, per_device = _compile_for(model, args, config, config.num_chains)
    keys = jax.random.split(key, config.num_chains).reshape(n_dev, per_device)
    return _drive(compiled, keys, args, config, config.num_chains, progress, desc)
