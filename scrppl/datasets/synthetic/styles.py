"""The random choices behind each synthetic image, drawn from generators seeded by its identity.

Every choice comes from ``numpy.random.default_rng([seed, crc32(category), instance, ...])``: the
instance's generator (``..., 1``) fixes its shape seed, floor, light and floor fade; the view's
(``..., a, e, s, 2``) its camera jitter, light gain, background, camera development and noise. No choice
depends on the order in which images are rendered, so one image rendered alone, or by any worker, is
identical to the same image rendered in a full run.
"""

from __future__ import annotations

import zlib
from typing import Any, NamedTuple

import numpy as np

from scrppl.datasets.synthetic.config import SyntheticConfig

__all__ = ["InstanceStyle", "ViewStyle", "instance_style", "view_style"]


def _category_key(category: str) -> int:
    return zlib.crc32(category.encode())


class InstanceStyle(NamedTuple):
    """Everything random about one instance's photo session (drawn by :func:`instance_style`)."""

    shape_seed: int
    floor_seed: int
    light_direction: np.ndarray
    light_intensity: float
    light_kelvin: float
    ambient: float
    fade: tuple[float, float]


class ViewStyle(NamedTuple):
    """Everything random about one image (drawn by :func:`view_style`)."""

    camera_jitter: tuple[float, float, float, float, float, float]
    light_gain: float
    background: Any  # backgrounds.BackgroundChoice
    development: Any  # compose.Development
    noise_seed: int


def instance_style(seed: int, category: str, instance: int, jitter: float = 1.0) -> InstanceStyle:
    """The random choices of one instance, from ``default_rng([seed, crc32(category), instance, 1])``."""
    rng = np.random.default_rng([int(seed), _category_key(category), int(instance), 1])
    shape_seed = int(rng.integers(2**31))
    floor_seed = int(rng.integers(2**31))
    k = float(jitter)
    az = rng.uniform(0.0, 2.0 * np.pi)
    el = np.deg2rad(55.0 + k * rng.uniform(-15.0, 15.0))
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    intensity = float(1.15 * np.exp(k * rng.uniform(-0.12, 0.12)))
    kelvin = float(5500.0 + k * rng.uniform(-2000.0, 2000.0))
    ambient = float(0.32 + k * rng.uniform(-0.06, 0.06))
    r_in = float(1.9 + k * rng.uniform(-0.3, 0.4))
    fade = (r_in, r_in + float(1.6 + k * rng.uniform(-0.4, 0.6)))
    return InstanceStyle(shape_seed, floor_seed, direction, intensity, kelvin, ambient, fade)


def view_style(
    seed: int,
    category: str,
    instance: int,
    view: tuple[int, int, int],
    split: str,
    config: SyntheticConfig,
) -> ViewStyle:
    """The random choices of one image, from ``default_rng([seed, crc32(category), instance, a, e, s, 2])``."""
    from scrppl.datasets.synthetic.backgrounds import draw_background, pool_of_split
    from scrppl.datasets.synthetic.compose import draw_development

    a, e, s = (int(v) for v in view)
    rng = np.random.default_rng([int(seed), _category_key(category), int(instance), a, e, s, 2])
    k = config.jitter
    cam = (
        k * rng.uniform(-4.0, 4.0),  # azimuth, degrees (bins are 45 degrees wide)
        k * rng.uniform(-2.5, 2.5),  # elevation, degrees
        k * rng.uniform(-0.04, 0.04),  # log distance
        k * rng.uniform(-0.04, 0.04),  # look-at shift, in object radii
        k * rng.uniform(-0.04, 0.04),
        k * rng.uniform(-2.0, 2.0),  # roll, degrees
    )
    light_gain = float(np.exp(k * rng.uniform(-0.08, 0.08)))
    background = draw_background(rng, pool_of_split(split), int(seed), config.width, config.height)
    development = draw_development(rng, k)
    noise_seed = int(rng.integers(2**31))
    return ViewStyle(tuple(float(c) for c in cam), light_gain, background, development, noise_seed)
