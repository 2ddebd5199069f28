"""The light server of Rohmer et al. 2015 (§4): fisheye HDR images in, NearFieldLight out.

    from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings
    server = NearFieldServer(world, rig, NearFieldSettings(tau=0.9, vals=16))
    light = server.update(images)        # one HDR image (H, W, 3) per rig camera
    light = server.update(images2)       # k-means warm-starts from the last centres
    server.stats                         # ms per stage of the last update (Table 1 rows)

``world`` is the proxy world: its **real** shapes are the reconstructed model the atlas is
laid over, its **virtual** shapes the objects that get an SH block each (in the order of
``world.virtual_shapes``). ``rig`` is a list of :class:`~arlight.nearfield.cameras.
RigCamera` (:func:`~arlight.nearfield.cameras.load_rig` reads ``cams.toml``).

Stages of one update (``server.stats``, milliseconds; Rohmer's Table 1 names in brackets):
``visibility`` (render depth: the camera→texel weights, visibility and pixel taps of every
camera; only when the rig or the proxy is new, see below), ``project_<camera>`` (project
into atlas: the image sampled at the cached taps), ``combine`` (combine radiance atlas),
``threshold`` + ``split`` (find separating threshold; split), ``dilate`` (dilatation),
``sampling``, ``kmeans``, ``integrate`` (integrating cluster radiances), ``sh`` (cube maps
and their projection). The atlas geometry (position / normal / area) is
computed once in the constructor (``stats_static['atlas_geometry']``).

**Cached projection.** The camera→texel weights ``w_i``, the visibility of every texel from
every camera and the pixels it projects to depend on the rig and the proxy only, never on
the images: they are kept in :attr:`NearFieldServer.projections`
(:class:`~arlight.nearfield.projection_cache.ProjectionCache`) under a content hash of the
rig (every camera's model and centre, read at each update: cameras replaced or moved in
place count), the proxy's triangles and the atlas settings. An update then samples the
images at the cached taps and merges (bitwise the result of projecting from scratch). A new
``world`` whose real shapes differ (:meth:`NearFieldServer.set_world`, a real shape moved
by :meth:`~NearFieldServer.set_object_transforms`) lays the atlas out anew and so gets a
new key.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from arlight.errors import InputError
from arlight.nearfield.atlas import (
    AtlasGeometry,
    AtlasLayout,
    ProxyMesh,
    _canonical,
    dilate,
    layout_charts,
    proxy_mesh,
    rasterize,
)
from arlight.nearfield.cameras import RigCamera
from arlight.nearfield.indirect import IndirectProbes, VirtualObject
from arlight.nearfield.projection import accumulate, camera_taps, check_image, combine
from arlight.nearfield.projection_cache import ProjectionCache, proxy_key, rig_key
from arlight.nearfield.raytrace import mesh_scene
from arlight.nearfield.split import DEFAULT_TAU, SplitAtlas, check_tau, split
from arlight.nearfield.state import SH_BLOCK_BYTES, VAL_RECORD_BYTES, NearFieldLight
from arlight.nearfield.vals import VALSet, extract_vals
from arlight.scene.mesh import vertex_normals
from arlight.scene.model import World
from arlight.timing import StageTimer


@dataclass
class NearFieldSettings:
    """Server settings (Rohmer's values where the paper gives them).

    Attributes:
        atlas_resolution: atlas side, texels (Rohmer: 1024).
        supersample: sub-samples per texel side for texel area / position.
        dilation: dilation range, texels (2).
        tau: direct share of the total radiant intensity, in [0, 1] (Rohmer's examples:
            0.75–0.98; default :data:`~arlight.nearfield.split.DEFAULT_TAU`, 0.6, measured
            best on cornell-near-field and kept after the generated rooms of issue #30).
        vals: number of VALs M (8–64; 16 in Table 1).
        samples: importance samples for the clustering (4096).
        iterations: k-means iterations per update (20).
        normal_weight: weight of the normal against the position (scaled by the proxy's
            diagonal) in the k-means distance.
        cube_resolution: SH cube-map side (32).
        seed: sampling / initialisation seed (fixed: temporal coherence).
    """

    atlas_resolution: int = 256
    supersample: int = 4
    dilation: int = 2
    tau: float = DEFAULT_TAU
    vals: int = 16
    samples: int = 4096
    iterations: int = 20
    normal_weight: float = 0.3
    cube_resolution: int = 32
    seed: int = 0

    def check(self) -> None:
        """Raise InputError naming the first bad field."""
        check_tau(self.tau)
        if int(self.vals) < 1:
            raise InputError(f"the number of VALs M must be >= 1, got {self.vals}",
                             field="vals")
        for name, lo in (("atlas_resolution", 16), ("supersample", 1), ("samples", 1),
                         ("iterations", 0), ("cube_resolution", 2), ("dilation", 0)):
            if int(getattr(self, name)) < lo:
                raise InputError(f"must be >= {lo}, got {getattr(self, name)}", field=name)
        if not np.isfinite(self.normal_weight) or self.normal_weight < 0:
            raise InputError(f"must be >= 0, got {self.normal_weight}", field="normal_weight")


@dataclass
class ServerState:
    """Intermediate results of the last update (for inspection and tests).

    Attributes:
        radiance: (N, 3) merged radiance of the covered texels, W/(sr·m²).
        weight: (N,) Σ_i w_i per texel (0: no camera saw it).
        split: the direct / indirect split.
        vals: the clustering.
        indirect_atlas: (R, R, 3) dilated indirect atlas.
        direct_atlas: (R, R, 3) dilated direct atlas.
    """

    radiance: np.ndarray
    weight: np.ndarray
    split: SplitAtlas
    vals: VALSet
    indirect_atlas: np.ndarray
    direct_atlas: np.ndarray


def virtual_objects(world: World) -> list[VirtualObject]:
    """The world's virtual shapes as world-space meshes with smooth unit normals."""
    out = []
    for s in world.virtual_shapes:
        v, f = _canonical(s)
        m = np.asarray(s.to_world, np.float64)
        vw = v @ m[:3, :3].T + m[:3, 3]
        if np.linalg.det(m[:3, :3]) < 0:
            f = f[:, ::-1]
        if s.mesh is not None and s.mesh.normals is not None:
            n = np.asarray(s.mesh.normals, np.float64) @ np.linalg.inv(m[:3, :3])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        else:
            n = vertex_normals(vw, f)
        p = s.material.params
        alb = p.get("albedo", p.get("kd", [0.5, 0.5, 0.5]))
        out.append(VirtualObject(s.name, vw, np.asarray(f, np.int64), n,
                                 np.asarray(alb, np.float64).reshape(3)))
    return out


class NearFieldServer:
    """Fisheye images → :class:`NearFieldLight` (module docstring).

    Raises (constructor): InputError for bad settings, a world without real shapes or an
    empty rig.
    """

    def __init__(self, world: World, cameras: Sequence[RigCamera],
                 settings: NearFieldSettings | None = None) -> None:
        self.settings = settings or NearFieldSettings()
        self.settings.check()
        if not cameras:
            raise InputError("the rig has no camera", field="cameras")
        self.world = world
        self.cameras = list(cameras)
        self.projections = ProjectionCache()
        timer = StageTimer()
        with timer.stage("atlas_geometry"):
            self._set_proxy(proxy_mesh(world))
        with timer.stage("objects"):
            self.set_world(world)
        self.stats_static = {k: 1e3 * v for k, v in timer.seconds.items()}
        self.stats: dict[str, float] = {}
        self.sequence = 0
        self.centres: np.ndarray | None = None
        self.last: ServerState | None = None
        self.light: NearFieldLight | None = None

    # ------------------------------------------------------------------ proxy
    def _set_proxy(self, mesh: ProxyMesh) -> None:
        """Lay the atlas over ``mesh`` (the real shapes): layout, per-texel geometry, the
        ray-tracing scene and :attr:`proxy_key`."""
        s = self.settings
        self.mesh = mesh
        self.proxy_key = proxy_key(mesh.vertices, mesh.faces, s.atlas_resolution,
                                   s.supersample)
        self.layout: AtlasLayout = layout_charts(mesh, s.atlas_resolution)
        self.geometry: AtlasGeometry = rasterize(mesh, self.layout, s.supersample)
        self.proxy_scene = mesh_scene([(mesh.vertices, mesh.faces)])
        self.scale = float(np.linalg.norm(mesh.vertices.max(0) - mesh.vertices.min(0)))
        self._texels = np.flatnonzero(self.geometry.covered.reshape(-1))
        self.position = self.geometry.position.reshape(-1, 3)[self._texels]
        self.normal = self.geometry.normal.reshape(-1, 3)[self._texels]
        self.area = self.geometry.area.reshape(-1)[self._texels]

    def projection_key(self) -> str:
        """The key of the current rig and proxy in :attr:`projections` (module docstring)."""
        return f"{self.proxy_key}:{rig_key(self.cameras)}"

    # ------------------------------------------------------------------ objects
    def set_world(self, world: World) -> None:
        """Take the virtual objects (and their poses) from ``world``; when its real shapes
        differ from the proxy's, the atlas is laid over them anew (the k-means warm start
        is dropped: its centres lie on the old proxy)."""
        mesh = proxy_mesh(world)
        s = self.settings
        if proxy_key(mesh.vertices, mesh.faces, s.atlas_resolution,
                     s.supersample) != self.proxy_key:
            self._set_proxy(mesh)
            self.centres = None
        self.world = world
        self.objects = virtual_objects(world)
        self.probes = IndirectProbes(self.mesh.vertices, self.mesh.faces, self.layout,
                                     self.objects, self.settings.cube_resolution,
                                     self.proxy_scene)
        self._sh = np.zeros((len(self.objects), 9, 3))

    def set_object_transforms(self, transforms: Mapping[str, np.ndarray]) -> None:
        """Move virtual objects (4×4 world transforms applied to their rest pose, as
        ``FrameView.object_transforms``)."""
        self.set_world(self.world.posed(dict(transforms)))

    # ------------------------------------------------------------------ update
    def _atlas_image(self, values: np.ndarray) -> np.ndarray:
        R = self.settings.atlas_resolution
        img = np.zeros((R * R, 3), np.float32)
        img[self._texels] = values
        return img.reshape(R, R, 3)

    def _camera_taps(self, timer: StageTimer) -> list:
        """Every camera's weights, visibility and taps (the ``visibility`` stage)."""
        with timer.stage("visibility"):
            return [camera_taps(self.geometry, cam, self.proxy_scene) for cam in self.cameras]

    def update(self, images: Sequence[np.ndarray] | Mapping[str, np.ndarray],
               timestamp: float | None = None, settings: NearFieldSettings | None = None
               ) -> NearFieldLight:
        """One server iteration: project, merge, split, cluster, SH (module docstring).

        Args:
            images: one linear HDR image ``(H, W, 3)`` per camera, in rig order (or by
                camera name).
            timestamp: seconds since the epoch (default: now).
            settings: replaces τ / M / … for this and later updates (the atlas resolution,
                supersampling and cube-map side stay those of the constructor; the caller's
                object is not modified).

        Raises:
            InputError: wrong number of images, an image that does not match its camera, a
                camera that sees nothing of the proxy.
        """
        if settings is not None:
            settings.check()
            self.settings = replace(settings, atlas_resolution=self.settings.atlas_resolution,
                                    supersample=self.settings.supersample,
                                    cube_resolution=self.settings.cube_resolution)
        s = self.settings
        if isinstance(images, Mapping):
            missing = [c.name for c in self.cameras if c.name not in images]
            if missing:
                raise InputError(f"no image for camera {missing[0]!r}", field="images")
            imgs = [images[c.name] for c in self.cameras]
        else:
            imgs = list(images)
        if len(imgs) != len(self.cameras):
            raise InputError(f"{len(imgs)} images for {len(self.cameras)} cameras",
                             field="images")
        imgs = [check_image(img, cam) for cam, img in zip(self.cameras, imgs, strict=True)]
        timer = StageTimer()
        taps = self.projections.get(self.projection_key(),
                                    lambda: self._camera_taps(timer))
        acc = np.zeros((len(self.area), 3))  # Σ w_i L_i, cameras in rig order
        for cam, img, t in zip(self.cameras, imgs, taps, strict=True):
            with timer.stage(f"project_{cam.name}"):
                accumulate(acc, t, img, cam.name)
        with timer.stage("combine"):
            radiance, weight = combine(acc, [t.weight for t in taps])
        with timer.stage("threshold"):
            sp = split(radiance, self.area, s.tau)
        with timer.stage("split"):
            direct_img = self._atlas_image(sp.direct)
            indirect_img = self._atlas_image(sp.indirect)
        with timer.stage("dilate"):  # both atlases in one pass (6 channels)
            both = dilate(np.concatenate([direct_img, indirect_img], axis=2),
                          self.geometry.covered, s.dilation)
            direct_img, indirect_img = both[..., :3], both[..., 3:]
        vals = extract_vals(self.position, self.normal, self.area, sp.direct, sp.any_direct,
                            s.vals, self.scale, s.samples, s.iterations, s.normal_weight,
                            self.centres, s.seed, timer)
        if len(vals.centres):
            self.centres = vals.centres
        with timer.stage("sh"):
            vtuple = (vals.positions, vals.normals, vals.intensity, vals.area)
            self._sh = self.probes.coefficients(indirect_img, self._sh, vtuple)
        self.sequence += 1
        self.light = NearFieldLight(vals.positions, vals.normals, vals.intensity, vals.area,
                                    self._sh.copy(), self.sequence,
                                    time.time() if timestamp is None else float(timestamp))
        self.last = ServerState(radiance, weight, sp, vals, indirect_img, direct_img)
        self.stats = {k: 1e3 * v for k, v in timer.seconds.items()}
        self.stats["cube_maps"] = float(self.probes.cube_maps)
        return self.light


def payload_bytes(light: NearFieldLight) -> int:
    """Bytes of one update on Rohmer's wire format: 32 per VAL + 108 per object."""
    return VAL_RECORD_BYTES * light.count + SH_BLOCK_BYTES * light.n_objects


__all__ = ["NearFieldServer", "NearFieldSettings", "ServerState", "payload_bytes",
           "virtual_objects"]
