"""Procedural 3-D instances of the ten Savarese object categories.

Each category is a small generative program: a seed fixes its proportions, part shapes, colours,
materials and textures, so ``build_instance(category, seed)`` returns the same object every time and
different seeds give visibly different instances of the same category.

The object coordinate frame (the contract the renderer relies on): the object stands on the ground
plane ``z = 0``, its bounding box is centred on the origin in ``x`` and ``y``, its **front faces +x**,
its left side is +y, +z is up, and its largest bounding-box extent is 1. Viewed from the azimuths of
`scrppl.views.ViewGrid`, azimuth 0 sees the front, azimuth 2 the left side, azimuth 4 the back.

The categories keep the viewpoint structure that makes viewpoint detection models (Meger et al. 2010,
Sec. III) necessary: a monitor's or cellphone's screen only faces +x, a bicycle is thin seen from the
front and wide from the side, a car's front and back look alike but unlike its side, an iron's cord and a
toaster's lever sit on one side, a head's face looks along +x, and a shoe's toe (+x) differs from its
heel (-x).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the meshes are built by the categories' modules (the render extra)
    import trimesh

__all__ = [
    "CATEGORIES",
    "Part",
    "build_instance",
    "instance_bounds",
    "normalize_parts",
]

CATEGORIES: tuple[str, ...] = (
    "bicycle",
    "car",
    "cellphone",
    "head",
    "iron",
    "monitor",
    "mouse",
    "shoe",
    "stapler",
    "toaster",
)


@dataclass
class Part:
    """One material region of an instance: a mesh with a colour, an optional texture and a finish.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Triangles in object coordinates (front +x, up +z), outward-facing winding.
    color : tuple of 3 floats
        Base RGB in [0, 1]; a textured part shows its texture instead (the colour is its average,
        a fallback for renderers without textures).
    texture : (H, W, 3) uint8 array or None
        RGB image mapped onto the mesh by ``uv``.
    uv : (n_vertices, 2) float array or None
        Texture coordinates in [0, 1], present exactly when ``texture`` is: ``u`` runs left to right
        across the image, ``v`` from its bottom row (``v = 0``) to its top row (``v = 1``) — the
        OpenGL/VTK convention (``pyvista.Texture(image)`` maps it this way).
    specular : float
        0 (matte) to 1 (shiny).
    smooth : bool
        Smooth (interpolated normals) rather than flat shading.
    name : str
        What the part is ("screen", "tyre", "face", ...), for tests and debugging.
    """

    mesh: trimesh.Trimesh
    color: tuple[float, float, float]
    texture: np.ndarray | None = None
    uv: np.ndarray | None = None
    specular: float = 0.2
    smooth: bool = False
    name: str = ""

    def __post_init__(self) -> None:
        if (self.texture is None) != (self.uv is None):
            raise ValueError(f"part {self.name!r}: texture and uv must be given together")
        if self.uv is not None:
            self.uv = np.asarray(self.uv, dtype=np.float64)
            if self.uv.shape != (len(self.mesh.vertices), 2):
                raise ValueError(
                    f"part {self.name!r}: uv has shape {self.uv.shape}, expected "
                    f"({len(self.mesh.vertices)}, 2)"
                )
        if self.texture is not None:
            tex = np.asarray(self.texture)
            if tex.ndim != 3 or tex.shape[2] != 3 or tex.dtype != np.uint8:
                raise ValueError(
                    f"part {self.name!r}: texture must be an (H, W, 3) uint8 array, got "
                    f"{tex.shape} {tex.dtype}"
                )
        self.color = tuple(float(np.clip(c, 0.0, 1.0)) for c in self.color)


def instance_bounds(parts: list[Part]) -> np.ndarray:
    """Axis-aligned bounds of all parts together.

    Returns
    -------
    (2, 3) float array
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.
    """
    if not parts:
        raise ValueError("an instance needs at least one part")
    verts = np.concatenate([np.asarray(p.mesh.vertices)[p.mesh.faces.ravel()] for p in parts])
    return np.stack([verts.min(0), verts.max(0)])


def normalize_parts(parts: list[Part]) -> list[Part]:
    """Place an instance in the canonical frame: on ``z = 0``, centred in x and y, largest extent 1.

    The meshes are transformed in place (uniform scale, so shapes and normals keep their directions)
    and the same list is returned.
    """
    lo, hi = instance_bounds(parts)
    scale = 1.0 / float(np.max(hi - lo))
    shift = -np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
    for p in parts:
        p.mesh.apply_translation(shift)
        p.mesh.apply_scale(scale)
    return parts


# category -> (module under scrppl.datasets.synthetic.categories, builder function)
_BUILDERS: dict[str, tuple[str, str]] = {
    "bicycle": ("vehicles", "bicycle"),
    "car": ("vehicles", "car"),
    "cellphone": ("devices", "cellphone"),
    "head": ("body", "head"),
    "iron": ("appliances", "iron"),
    "monitor": ("devices", "monitor"),
    "mouse": ("devices", "mouse"),
    "shoe": ("body", "shoe"),
    "stapler": ("appliances", "stapler"),
    "toaster": ("appliances", "toaster"),
}


def _builder(category: str) -> Callable[[np.random.Generator, int], list[Part]]:
    module_name, function = _BUILDERS[category]
    module = importlib.import_module(f"scrppl.datasets.synthetic.categories.{module_name}")
    return getattr(module, function)


def build_instance(category: str, seed: int) -> list[Part]:
    """Build one procedural instance of ``category``, deterministically from ``seed``.

    Parameters
    ----------
    category : str
        One of `CATEGORIES`.
    seed : int
        Non-negative integer; the same seed gives identical vertices, colours and textures.

    Returns
    -------
    list of Part
        The instance in the canonical object frame (see the module docstring).

    Raises
    ------
    ValueError
        If ``category`` is not one of `CATEGORIES` or ``seed`` is negative.
    """
    if category not in CATEGORIES:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")
    seed = int(seed)
    if seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    # Mix the category into the stream so that e.g. car 3 and shoe 3 do not share choices.
    rng = np.random.default_rng([seed, CATEGORIES.index(category), 0x5C2])
    tex_seed = int(rng.integers(2**31))
    parts = _builder(category)(rng, tex_seed)
    return normalize_parts(parts)
