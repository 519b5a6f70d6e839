"""The synthetic multiview dataset: procedural instances of the Savarese categories, rendered off-screen.

* `scrppl.datasets.synthetic.shapes` -- the procedural instances (``build_instance``, ``CATEGORIES``);
* `scrppl.datasets.synthetic.camera` -- canonical placement, framing distance and the view cameras;
* `scrppl.datasets.synthetic.render` -- the off-screen renderer (floor, shadows, light, mask);
* `scrppl.datasets.synthetic.floors`, `~.backgrounds`, `~.compose` -- floor textures, background
  pools split between training and held-out instances, compositing and camera development;
* `scrppl.datasets.synthetic.domain`, `~.nuisances` -- imaging domains (presets ``clean``, ``robot``,
  ``hard``): catalogue training images versus robot images with clutter, occlusion, truncation, light,
  blur, noise, far-distance resolution and JPEG compression;
* `scrppl.datasets.synthetic.config`, `~.styles`, `~.generate` -- :class:`SyntheticConfig`, the
  seeded random choices of every image, and :func:`make_synthetic` / :func:`load_or_make`
  (re-exported here).

The generator's names are imported lazily, so importing a submodule (e.g. the shapes) stays cheap.
"""

from __future__ import annotations

from typing import Any

__all__ = ["SyntheticConfig", "make_synthetic", "load_or_make", "render_view", "PROFILES"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from scrppl.datasets.synthetic import generate

        return getattr(generate, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
