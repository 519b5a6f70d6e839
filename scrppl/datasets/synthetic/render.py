"""Off-screen rendering of one procedural instance on a textured floor, with shadows and its mask.

One :class:`SceneRenderer` owns one VTK render window (a ``pyvista.Plotter(off_screen=True)``) and is
reused for every image a process renders -- creating a window costs seconds, rendering a frame
milliseconds. VTK picks its off-screen backend by itself (EGL or OSMesa; on machines without a GPU that
is Mesa's llvmpipe rasteriser, which may print a harmless "bad X server connection" line).

The scene
---------
* The object's parts (`scrppl.datasets.synthetic.shapes.Part`) with their colours, textures, specular
  finish and flat or smooth shading, rescaled to the canonical frame (standing on ``z = 0``, centred in
  ``x`` and ``y``, largest extent 1, front facing ``+x``).
* A square ground plane under it, textured with a seamlessly tiling floor
  (`scrppl.datasets.synthetic.floors`).
* A directional key light (direction, intensity and colour temperature from :class:`Lighting`) that
  casts **real shadows**: VTK's shadow-map render pass (``vtkShadowMapPass``), which works off-screen on
  llvmpipe. Ambient light fills the shadows.
* The camera of view ``(a, e, s)`` of a `scrppl.views.ViewGrid`
  (`scrppl.datasets.synthetic.camera.view_camera`, re-exported here): azimuth
  ``phi = a * 360 / A`` counter-clockwise from ``+x`` (azimuth 0 sees the front), elevation
  ``grid.elevations[e]`` and distance ``base * grid.scales[s]`` from the object's centre, where the
  base distance frames the object in every view of scale 1 (:func:`base_distance`).

Each :meth:`SceneRenderer.render` draws the frame once, in two layers: the base layer renders the
floor and the object with the shadow map (so the object casts its shadow on the floor), then an overlay
layer redraws the object without shadows into a cleared depth buffer (shadow maps on coarse, smoothly
shaded meshes show "terminator" acne; the overlay removes it, at the price of the object's shadows on
itself). The depth buffer read back afterwards holds the object alone, so the object's mask comes from
the renderer, never from colour thresholds; it agrees with a separate pass with the floor hidden
(:meth:`SceneRenderer.render_object_mask`). The floor's pixels and their distance from the object on
the ground come from the camera rays in closed form, so the compositor can fade the floor out into the
background photograph.

Anti-aliasing is off (multisampling costs 4x on a software rasteriser); the post-processing blur
(`scrppl.datasets.synthetic.compose`) softens the edges instead.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from scrppl.datasets.synthetic.camera import (
    VIEW_ANGLE,
    CameraPose,
    base_distance,
    object_extent,
    view_camera,
)

__all__ = [
    "CameraPose",
    "Lighting",
    "Frame",
    "SceneRenderer",
    "view_camera",
    "base_distance",
    "object_extent",
    "kelvin_to_rgb",
    "VIEW_ANGLE",
]

#: Half-side of the square ground plane, in object units.
FLOOR_HALF_SIZE = 6.0
_NEAR, _FAR = 0.2, 60.0


class Lighting(NamedTuple):
    """The lights of one scene.

    Attributes
    ----------
    direction : (3,) float array
        Unit vector from the scene towards the key light (a directional light; it casts the shadows).
    intensity : float
        Key light intensity.
    color : (3,) float array
        Key light RGB colour (see :func:`kelvin_to_rgb`).
    ambient : float
        Ambient coefficient of every surface: the light that reaches the shadows. (One light only:
        VTK's shadow-map pass renders once per light, so a second light would double the cost.)
    """

    direction: np.ndarray
    intensity: float = 1.0
    color: np.ndarray = np.ones(3)
    ambient: float = 0.3


class Frame(NamedTuple):
    """One rendered view.

    Attributes
    ----------
    rgb : (H, W, 3) uint8 array
        The rendered photograph; pixels that show neither the object nor the floor are black.
    object_mask : (H, W) bool array
        Pixels of the object (from the depth buffer, see :meth:`SceneRenderer.render`).
    floor_mask : (H, W) bool array
        Pixels of the floor not covered by the object.
    floor_radius : (H, W) float32 array
        Horizontal distance from the object's centre of the floor point seen in each pixel
        (``inf`` where no floor is seen).
    """

    rgb: np.ndarray
    object_mask: np.ndarray
    floor_mask: np.ndarray
    floor_radius: np.ndarray


def kelvin_to_rgb(kelvin: float) -> np.ndarray:
    """Approximate RGB colour (max channel 1) of a black body at ``kelvin`` (1000-40000 K).

    Uses Tanner Helland's fit of the CIE colour-matching data; good enough for light colour jitter.
    """
    t = float(np.clip(kelvin, 1000.0, 40000.0)) / 100.0
    r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
    g = (
        99.4708025861 * np.log(t) - 161.1195681661
        if t <= 66
        else 288.1221695283 * (t - 60) ** -0.0755148492
    )
    if t >= 66:
        b = 255.0
    elif t <= 19:
        b = 0.0
    else:
        b = 138.5177312231 * np.log(t - 10) - 305.0447927307
    rgb = np.clip(np.array([r, g, b]), 0, 255) / 255.0
    return rgb / rgb.max()


class SceneRenderer:
    """A reusable off-screen scene: floor, light and one instance at a time.

    Parameters
    ----------
    width, height
        Image size in pixels.
    shadow_resolution
        Side of the shadow map in texels.

    Attributes
    ----------
    vertices : (n, 3) float array
        The current instance's vertices in the canonical frame.
    radius, object_height : float
        Its bounding-sphere radius and height (:func:`object_extent`).

    Examples
    --------
    >>> r = SceneRenderer(320, 240)  # doctest: +SKIP
    >>> r.set_instance(build_instance("monitor", 0)); r.set_floor(make_floor(0))  # doctest: +SKIP
    >>> r.set_lighting(Lighting(direction=np.array([0.3, 0.4, 0.87])))  # doctest: +SKIP
    >>> d = base_distance(r.vertices, ViewGrid(), aspect=320 / 240)  # doctest: +SKIP
    >>> frame = r.render(view_camera(ViewGrid(), 0, 0, 0, distance=d, height=r.object_height))  # doctest: +SKIP
    """

    def __init__(self, width: int = 320, height: int = 240, *, shadow_resolution: int = 1024):
        if int(width) < 16 or int(height) < 16:
            raise ValueError(f"image size must be at least 16x16 pixels, got {width}x{height}")
        from scrppl._extras import require

        pv = require("render", "pyvista")
        vtk = require("render", "vtk")

        vtk.vtkLogger.SetStderrVerbosity(vtk.vtkLogger.VERBOSITY_ERROR)
        self._pv, self._vtk = pv, vtk
        self.width, self.height = int(width), int(height)
        self._pl = pv.Plotter(
            off_screen=True, window_size=(self.width, self.height), lighting="none"
        )
        self._win = self._pl.ren_win
        self._win.SetMultiSamples(0)
        self._pl.set_background("black")
        self._pl.enable_shadows()
        self._pl.renderer._render_passes._shadow_map_pass.GetShadowMapBakerPass().SetResolution(
            int(shadow_resolution)
        )
        self._floor_mesh = pv.Plane(
            center=(0.0, 0.0, 0.0),
            direction=(0.0, 0.0, 1.0),
            i_size=2 * FLOOR_HALF_SIZE,
            j_size=2 * FLOOR_HALF_SIZE,
            i_resolution=1,
            j_resolution=1,
        )
        self._floor_actor = None
        self._part_actors: list = []
        self._key = pv.Light(light_type="scene light")
        self._key.positional = False
        self._pl.add_light(self._key)
        # The object is drawn twice: in the shadow-mapped layer (so it casts shadows on the floor) and
        # again, unshadowed, in an overlay layer whose depth buffer starts cleared. Shadow maps on
        # coarse smoothly shaded meshes show "terminator" acne; the overlay removes it from the
        # object, and its depth buffer is exactly the object's mask.
        self._overlay = vtk.vtkRenderer()
        self._win.SetNumberOfLayers(2)
        self._overlay.SetLayer(1)
        self._overlay.SetInteractive(False)
        self._overlay.SetPreserveDepthBuffer(False)
        self._overlay.SetActiveCamera(self._pl.renderer.GetActiveCamera())
        self._overlay.AddLight(self._key)
        self._overlay.SetAutomaticLightCreation(False)
        self._win.AddRenderer(self._overlay)
        self._overlay_actors: list = []
        self._ambient = 0.3
        self.vertices = np.zeros((0, 3))
        self.radius = 1.0
        self.object_height = 1.0
        # camera rays through pixel centres, in camera coordinates (x right, y up, z forward = 1)
        tan_v = np.tan(np.deg2rad(VIEW_ANGLE / 2.0))
        tan_h = tan_v * self.width / self.height
        xs = ((np.arange(self.width) + 0.5) / self.width * 2.0 - 1.0) * tan_h
        ys = (1.0 - (np.arange(self.height) + 0.5) / self.height * 2.0) * tan_v
        self._ray_x = xs.astype(np.float32)[None, :]
        self._ray_y = ys.astype(np.float32)[:, None]
        self._closed = False

    # -- scene content -----------------------------------------------------------------------------
    def set_floor(self, floor) -> None:
        """Texture the ground with a `scrppl.datasets.synthetic.floors.Floor`."""
        pv = self._pv
        mesh = self._floor_mesh.copy()
        xy = np.asarray(mesh.points)[:, :2]
        mesh.active_texture_coordinates = (xy / float(floor.tile_size)).astype(np.float32)
        tex = pv.Texture(np.ascontiguousarray(floor.texture))
        tex.repeat = True
        tex.interpolate = True
        tex.mipmap = (
            False  # trilinear filtering costs 3x on llvmpipe; the compositor fades the far floor
        )
        if self._floor_actor is not None:
            self._pl.remove_actor(self._floor_actor, render=False)
        self._floor_actor = self._pl.add_mesh(
            mesh, texture=tex, ambient=self._ambient, diffuse=0.9, specular=0.05, render=False
        )

    def set_instance(self, parts) -> None:
        """Replace the object by a new instance (a list of ``Part``); see :func:`object_extent`."""
        pv = self._pv
        transform, self.radius, self.object_height = object_extent(parts)
        for actor in self._part_actors:
            self._pl.remove_actor(actor, render=False)
        for actor in self._overlay_actors:
            self._overlay.RemoveActor(actor)
        self._part_actors, self._overlay_actors = [], []
        all_verts = []
        for part in parts:
            verts = (
                np.asarray(part.mesh.vertices, dtype=float) @ transform[:3, :3].T + transform[:3, 3]
            )
            all_verts.append(verts)
            faces = np.asarray(part.mesh.faces, dtype=np.int64)
            mesh = pv.PolyData.from_regular_faces(verts, faces)
            kw = {}
            if part.texture is not None:
                mesh.active_texture_coordinates = np.asarray(part.uv, dtype=np.float32)
                tex = pv.Texture(np.ascontiguousarray(part.texture))
                tex.interpolate = True
                kw["texture"] = tex
            else:
                kw["color"] = tuple(float(c) for c in part.color)
            actor = self._pl.add_mesh(
                mesh,
                smooth_shading=bool(part.smooth),
                split_sharp_edges=bool(part.smooth),
                ambient=self._ambient,
                diffuse=0.9,
                specular=float(part.specular),
                specular_power=10.0 + 60.0 * float(part.specular),
                render=False,
                **kw,
            )
            self._part_actors.append(actor)
            mapper = self._vtk.vtkPolyDataMapper()
            mapper.SetInputData(actor.GetMapper().GetInput())
            mapper.ScalarVisibilityOff()
            twin = self._vtk.vtkActor()
            twin.SetMapper(mapper)
            twin.SetProperty(actor.GetProperty())
            if actor.GetTexture() is not None:
                twin.SetTexture(actor.GetTexture())
            self._overlay.AddActor(twin)
            self._overlay_actors.append(twin)
        self.vertices = np.concatenate(all_verts)

    def set_lighting(self, lighting: Lighting) -> None:
        """Set the key light and the ambient level."""
        direction = np.asarray(lighting.direction, dtype=float)
        direction = direction / np.linalg.norm(direction)
        self._key.position = tuple(20.0 * direction)
        self._key.focal_point = (0.0, 0.0, 0.0)
        self._key.intensity = float(lighting.intensity)
        self._key.diffuse_color = tuple(float(c) for c in lighting.color)
        self._key.specular_color = tuple(float(c) for c in lighting.color)
        self._ambient = float(lighting.ambient)
        for actor in [*self._part_actors, self._floor_actor]:
            if actor is not None:
                actor.prop.ambient = self._ambient

    # -- rendering ---------------------------------------------------------------------------------
    def _place_camera(self, camera: CameraPose) -> None:
        cam = self._pl.camera
        cam.position = tuple(float(v) for v in camera.position)
        cam.focal_point = tuple(float(v) for v in camera.focal_point)
        cam.up = (0.0, 0.0, 1.0)
        cam.view_angle = VIEW_ANGLE
        cam.OrthogonalizeViewUp()
        if camera.roll:
            cam.Roll(float(camera.roll))
        cam.clipping_range = (_NEAR, _FAR)

    def _read_rgb(self) -> np.ndarray:
        from scrppl._extras import require

        vtk_to_numpy = require("render", "vtkmodules.util.numpy_support").vtk_to_numpy

        arr = self._vtk.vtkUnsignedCharArray()
        self._win.GetRGBACharPixelData(0, 0, self.width - 1, self.height - 1, 0, arr)
        return vtk_to_numpy(arr).reshape(self.height, self.width, 4)[::-1, :, :3].copy()

    def _read_eye_depth(self) -> np.ndarray:
        """Distance along the viewing axis of the surface in each pixel (``inf``: nothing there)."""
        from scrppl._extras import require

        vtk_to_numpy = require("render", "vtkmodules.util.numpy_support").vtk_to_numpy

        arr = self._vtk.vtkFloatArray()
        self._win.GetZbufferData(0, 0, self.width - 1, self.height - 1, arr)
        zb = vtk_to_numpy(arr).reshape(self.height, self.width)[::-1].astype(np.float64)
        with np.errstate(divide="ignore"):
            z = _NEAR * _FAR / (_FAR - zb * (_FAR - _NEAR))
        return np.where(zb < 1.0, z, np.inf)

    def _floor_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Eye depth and radius of the floor point each pixel's ray meets (``inf`` if none)."""
        cam = self._pl.camera
        pos = np.asarray(cam.position, dtype=float)
        fwd = np.asarray(cam.focal_point, dtype=float) - pos
        fwd /= np.linalg.norm(fwd)
        up = np.asarray(cam.up, dtype=float)
        right = np.cross(fwd, up)
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        xs, ys = self._ray_x, self._ray_y
        # world direction of each pixel's ray, scaled to a unit component along the viewing axis
        d = [xs * right[k] + ys * up[k] + np.float32(fwd[k]) for k in range(3)]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.float32(-pos[2]) / d[2]  # eye depth of the hit
            hx = np.float32(pos[0]) + t * d[0]
            hy = np.float32(pos[1]) + t * d[1]
        ok = (t > 0) & (np.abs(hx) <= FLOOR_HALF_SIZE) & (np.abs(hy) <= FLOOR_HALF_SIZE)
        depth = np.where(ok, t, np.float32(np.inf))
        radius = np.where(ok, np.sqrt(hx * hx + hy * hy), np.float32(np.inf))
        return depth, radius

    def render(self, camera: CameraPose) -> Frame:
        """Render one view: the photograph, the object's mask and the floor's geometry.

        The base layer draws the floor and the object with the shadow map; the overlay layer redraws
        the object unshadowed into a cleared depth buffer, so the depth buffer read back afterwards holds
        the object alone: its finite pixels are the object's mask. It equals the mask of a separate pass
        with the floor hidden (:meth:`render_object_mask`). The floor's pixels and their radii come from
        the camera rays in closed form (the floor is the square ``|x|, |y| <= 6`` of the plane
        ``z = 0``).
        """
        if self._closed:
            raise RuntimeError("this SceneRenderer has been closed")
        if self._floor_actor is None or not self._part_actors:
            raise RuntimeError("set_floor and set_instance must be called before render")
        self._place_camera(camera)
        self._win.Render()
        rgb = self._read_rgb()
        object_mask = np.isfinite(self._read_eye_depth())
        floor_depth, floor_radius = self._floor_rays()
        floor_mask = np.isfinite(floor_depth) & ~object_mask
        floor_radius = np.where(floor_mask, floor_radius, np.inf).astype(np.float32)
        return Frame(rgb, object_mask, floor_mask, floor_radius)

    def render_object_mask(self, camera: CameraPose) -> np.ndarray:
        """The object's mask from a separate pass of the base layer alone with the floor hidden.

        Slower than :meth:`render`; an independent check of its mask.
        """
        self._place_camera(camera)
        self._floor_actor.SetVisibility(False)
        for twin in self._overlay_actors:
            twin.SetVisibility(False)
        self._overlay.SetPreserveDepthBuffer(True)
        try:
            self._win.Render()
            return np.isfinite(self._read_eye_depth())
        finally:
            self._overlay.SetPreserveDepthBuffer(False)
            for twin in self._overlay_actors:
                twin.SetVisibility(True)
            self._floor_actor.SetVisibility(True)

    def close(self) -> None:
        """Release the render window."""
        if not self._closed:
            self._pl.close()
            self._closed = True

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
