"""What the synthetic dataset contains: :class:`SyntheticConfig` and its named profiles."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from scrppl.datasets.core import DEFAULT_SPLIT_PROPORTIONS
from scrppl.datasets.synthetic.domain import PRESET_NAMES, Domain
from scrppl.views import ViewGrid

__all__ = ["SyntheticConfig", "PROFILES", "PRESET_NAMES", "DEFAULT_PRESETS", "default_preset"]

#: Profiles of :meth:`SyntheticConfig.for_profile`.
PROFILES = ("full", "book", "quick", "tiny")
#: The imaging preset each profile renders when none is given. The full profile -- `make reproduce` --
#: renders the paper's regime: detectors trained on catalogue images and run on a room's images, a
#: preset chosen by detector criteria stated before any experiment (held-out DPM mean AP 0.55-0.75,
#: a random-view baseline needing at least 3 views to p(true) > 0.95; see `scrppl.report`). The
#: smaller profiles keep the clean images: the book's chapters teach each step where its effect is
#: plain to see, and the tests' expectations are about those images (chapter 9 sweeps the harder ones).
DEFAULT_PRESETS = {"full": "paper", "book": "clean", "quick": "clean", "tiny": "clean"}


def default_preset(profile: str, preset: str | None = None) -> str:
    """``preset`` if given, else the profile's default (:data:`DEFAULT_PRESETS`)."""
    if preset is not None:
        return preset
    if profile not in DEFAULT_PRESETS:
        raise ValueError(f"unknown profile {profile!r}; expected one of {', '.join(PROFILES)}")
    return DEFAULT_PRESETS[profile]


def _all_categories() -> tuple[str, ...]:
    from scrppl.datasets.synthetic.shapes import CATEGORIES

    return tuple(CATEGORIES)


@dataclass(frozen=True)
class SyntheticConfig:
    """What to render.

    Parameters
    ----------
    categories
        Category names (a subset of `scrppl.datasets.synthetic.shapes.CATEGORIES`), no repeats.
    n_instances
        Instances per category.
    grid
        The view grid (azimuths, elevations in degrees, scales as distance multipliers).
    width, height
        Image size in pixels.
    split_proportions
        Shares of ``(train, fit, test)`` instances per category (`scrppl.datasets.core.assign_splits`).
    jitter
        Strength of the nuisance variation: camera pose within its view bin, lighting, floor, camera
        development and noise (1: the default dataset; 0: exact grid views, a neutral camera).
    fill
        Share of the half-frame the object spans in its tightest view at scale 1.
    domain
        The imaging domain of each split (`scrppl.datasets.synthetic.domain.Domain`): the default,
        ``"clean"``, renders every split alike; the ``"robot"`` and ``"hard"`` presets render the train
        split as catalogue images and the fit and test splits with a real room's nuisances.
    """

    categories: tuple[str, ...] = field(default_factory=_all_categories)
    n_instances: int = 10
    grid: ViewGrid = field(default_factory=ViewGrid)
    width: int = 320
    height: int = 240
    split_proportions: tuple[float, float, float] = DEFAULT_SPLIT_PROPORTIONS
    jitter: float = 1.0
    fill: float = 0.9
    domain: Domain = field(default_factory=Domain)

    def __post_init__(self) -> None:
        cats = self.categories
        if isinstance(cats, str) or not isinstance(cats, Sequence):
            raise ValueError(f"categories must be a sequence of names, got {cats!r}")
        object.__setattr__(self, "categories", tuple(str(c) for c in cats))
        known = _all_categories()
        if not self.categories:
            raise ValueError("a synthetic dataset needs at least one category")
        unknown = [c for c in self.categories if c not in known]
        if unknown:
            raise ValueError(
                f"unknown categories {unknown}; expected names from {', '.join(known)}"
            )
        if len(set(self.categories)) != len(self.categories):
            raise ValueError(f"categories repeat: {list(self.categories)}")
        if int(self.n_instances) != self.n_instances or self.n_instances < 1:
            raise ValueError(f"n_instances must be a positive integer, got {self.n_instances!r}")
        object.__setattr__(self, "n_instances", int(self.n_instances))
        if not isinstance(self.grid, ViewGrid):
            raise ValueError(
                f"grid must be a scrppl.views.ViewGrid, got {type(self.grid).__name__}"
            )
        for name in ("width", "height"):
            v = getattr(self, name)
            if int(v) != v or not 32 <= v <= 4096:
                raise ValueError(
                    f"{name} must be an integer number of pixels in 32..4096, got {v!r}"
                )
            object.__setattr__(self, name, int(v))
        if not all(0.0 < el < 90.0 for el in self.grid.elevations):
            raise ValueError(
                f"elevations must lie strictly between 0 and 90 degrees, got {self.grid.elevations}"
            )
        if not all(s > 0 for s in self.grid.scales):
            raise ValueError(
                f"scales must be positive distance multipliers, got {self.grid.scales}"
            )
        p = tuple(float(x) for x in self.split_proportions)
        if len(p) != 3 or min(p) < 0 or not np.isclose(sum(p), 1.0):
            raise ValueError(
                f"split_proportions must be three non-negative shares summing to 1, got {self.split_proportions}"
            )
        object.__setattr__(self, "split_proportions", p)
        if not 0.0 <= float(self.jitter) <= 2.0:
            raise ValueError(f"jitter must lie in [0, 2], got {self.jitter!r}")
        if not 0.1 <= float(self.fill) <= 1.0:
            raise ValueError(f"fill must lie in [0.1, 1], got {self.fill!r}")
        object.__setattr__(self, "jitter", float(self.jitter))
        object.__setattr__(self, "fill", float(self.fill))
        if isinstance(self.domain, str):
            object.__setattr__(self, "domain", Domain.preset(self.domain))
        if not isinstance(self.domain, Domain):
            raise ValueError(
                f"domain must be a Domain or a preset name ({', '.join(PRESET_NAMES)}), got {self.domain!r}"
            )

    @property
    def n_images(self) -> int:
        """Number of images: categories x instances x views."""
        return len(self.categories) * self.n_instances * self.grid.n_views

    @classmethod
    def for_profile(cls, name: str, preset: str | None = None) -> SyntheticConfig:
        """A named configuration, in the imaging domain of a preset.

        The profile fixes what is rendered; ``preset`` (``"clean"``, ``"robot"``, ``"paper"`` or ``"hard"``, see
        `scrppl.datasets.synthetic.domain`) how the splits are photographed, by default the profile's
        (:data:`DEFAULT_PRESETS`). ``"clean"`` gives the profile's original images.

        * ``"full"``: all ten categories x 10 instances x the Savarese grid (8 x 3 x 3) = 7,200 images.
        * ``"quick"``: four categories x 6 instances x 8 azimuths at one height and scale (192 images,
          well under a minute) -- a pipeline that runs end to end in a few minutes.
        * ``"book"``: six categories x 10 instances x 8 azimuths at one height and scale (480 images) --
          what the book's chapters are executed against when no full run exists (a few minutes end to end).
        * ``"tiny"``: three categories x 2 instances x 8 azimuths at one height and scale (48 images,
          seconds) -- for tests.
        """
        profile = cls._profile(name)
        domain = Domain.preset(default_preset(name, preset))
        return dataclasses.replace(profile, domain=domain)

    @classmethod
    def _profile(cls, name: str) -> SyntheticConfig:
        if name == "full":
            return cls()
        if name == "quick":
            return cls(
                categories=("bicycle", "car", "monitor", "shoe"),
                n_instances=6,
                grid=ViewGrid(8, (25.0,), (1.4,)),
            )
        if name == "book":
            return cls(
                categories=("bicycle", "car", "cellphone", "monitor", "mouse", "shoe"),
                n_instances=10,
                grid=ViewGrid(8, (25.0,), (1.4,)),
            )
        if name == "tiny":
            return cls(
                categories=("bicycle", "cellphone", "mouse"),
                n_instances=2,
                grid=ViewGrid(8, (25.0,), (1.0,)),
            )
        raise ValueError(f"unknown profile {name!r}; expected one of {', '.join(PROFILES)}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable description (inverse: :meth:`from_dict`)."""
        return {
            "categories": list(self.categories),
            "n_instances": self.n_instances,
            "grid": self.grid.to_dict(),
            "width": self.width,
            "height": self.height,
            "split_proportions": list(self.split_proportions),
            "jitter": self.jitter,
            "fill": self.fill,
            "domain": self.domain.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SyntheticConfig:
        """Inverse of :meth:`to_dict`."""
        d = dict(d)
        d["grid"] = ViewGrid.from_dict(d["grid"])
        d["categories"] = tuple(d["categories"])
        d["split_proportions"] = tuple(d["split_proportions"])
        d["domain"] = Domain.from_dict(d.get("domain", {}))  # folders made before domains: clean
        return cls(**d)
