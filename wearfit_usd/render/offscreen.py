"""Offscreen OpenGL rendering of numpy meshes through pyrender (no GPU, no display).

Platform choice happens once, before OpenGL is first imported:

1. ``PYOPENGL_PLATFORM`` if the user set it, else ``osmesa`` (Mesa's software
   rasteriser, Debian ``libosmesa6``), with ``egl`` (Mesa's software EGL) as the
   fallback.
2. OSMesa through pyrender needs PyOpenGL >= 3.1.4 (``OSMesaCreateContextAttribs``);
   pyrender 0.1.45 pins 3.1.0. With an older PyOpenGL, or when context creation
   fails, the next platform is tried (the OpenGL/pyrender modules are re-imported
   for it, which is only possible because nothing else draws in this process).

:class:`Renderer` keeps one pyrender scene alive and, between frames, re-uploads
only the vertex buffers whose points changed (``glBufferSubData`` into the
interleaved position/normal/colour buffer that pyrender's ``Primitive`` created)
instead of rebuilding meshes, and draws with the light preview shader of
:mod:`.shading` instead of pyrender's PBR one. Inputs are internal-space
numpy arrays (Y up, metres); the row-vector camera matrices of :mod:`.camera` are transposed to
pyrender's column-vector poses only here.
"""
from __future__ import annotations

import ctypes.util
import os
import sys
from dataclasses import dataclass, field

import numpy as np

from ..progress import debug, info
from .camera import View
from .lighting import DEFAULT_RIG, LightRig, light_poses
from .shading import SHADINGS, make_cache

_PLATFORM: str | None = None   # the platform pyrender was imported for
_PYRENDER = None                # the imported module


def _shim_numpy() -> None:
    """numpy 2 removed ``np.infty``, which pyrender 0.1.45 still uses."""
    if not hasattr(np, "infty"):
        np.infty = np.inf


def _pyopengl_version() -> tuple[int, ...]:
    try:
        from importlib.metadata import version
        return tuple(int(x) for x in version("PyOpenGL").split(".")[:3] if x.isdigit())
    except Exception:
        return (0,)


def platform_usable(name: str) -> tuple[bool, str]:
    """Cheap check, without importing OpenGL, that ``name`` can work here."""
    if name == "osmesa":
        if not ctypes.util.find_library("OSMesa"):
            return False, "libOSMesa not found (Debian: apt-get install libosmesa6)"
        if _pyopengl_version() < (3, 1, 4):
            v = ".".join(map(str, _pyopengl_version()))
            return False, (f"PyOpenGL {v} cannot create OSMesa contexts (needs >= 3.1.4; "
                           f"run: {sys.executable} -m pip install 'PyOpenGL==3.1.10')")
        return True, ""
    if name == "egl":
        if not ctypes.util.find_library("EGL"):
            return False, "libEGL not found (Debian: apt-get install libegl1 libegl-mesa0)"
        return True, ""
    return True, ""  # pyglet or anything else the user asked for: just try it


def _candidates() -> list[str]:
    user = os.environ.get("PYOPENGL_PLATFORM")
    order = [user] if user else []
    for p in ("osmesa", "egl"):
        if p not in order:
            order.append(p)
    return order


def _purge_gl_modules() -> None:
    for name in list(sys.modules):
        if name == "OpenGL" or name.startswith("OpenGL.") or name == "pyrender" \
                or name.startswith("pyrender."):
            del sys.modules[name]


def _import_for(platform: str):
    global _PLATFORM, _PYRENDER
    if _PLATFORM == platform and _PYRENDER is not None:
        return _PYRENDER
    if "OpenGL" in sys.modules or "pyrender" in sys.modules:
        _purge_gl_modules()
    os.environ["PYOPENGL_PLATFORM"] = platform
    _shim_numpy()
    import pyrender  # noqa: WPS433  (import after the platform is set, on purpose)
    _PLATFORM, _PYRENDER = platform, pyrender
    return pyrender


def create_offscreen(width: int, height: int):
    """(pyrender module, OffscreenRenderer, platform name) on the first platform
    that works; raises RuntimeError listing why each one failed."""
    already = sys.modules.get("OpenGL.platform") is not None and _PLATFORM is None
    if already:  # someone imported OpenGL before us: we cannot switch any more
        plat = os.environ.get("PYOPENGL_PLATFORM", "")
        _shim_numpy()
        import pyrender
        return pyrender, pyrender.OffscreenRenderer(width, height), plat or "default"
    why = []
    order = _candidates()
    if _PLATFORM is not None:  # keep the working one first
        order = [_PLATFORM] + [p for p in order if p != _PLATFORM]
    for plat in order:
        ok, reason = platform_usable(plat)
        if not ok:
            why.append(f"{plat}: {reason}")
            continue
        try:
            pyrender = _import_for(plat)
            r = pyrender.OffscreenRenderer(width, height)
        except Exception as exc:  # context creation failed
            why.append(f"{plat}: {type(exc).__name__}: {exc}")
            continue
        if why:
            info("render: using " + plat + " (" + "; ".join(why) + ")")
        debug(f"render: OpenGL platform {plat}")
        return pyrender, r, plat
    raise RuntimeError("no offscreen OpenGL platform works: " + "; ".join(why)
                       + " (Debian/Ubuntu: apt-get install libosmesa6 libegl1, then "
                       + f"{sys.executable} -m pip install 'PyOpenGL==3.1.10'; ./install.sh does both)")


# --------------------------------------------------------------------------
# geometry helpers


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB 0-1 -> linear 0-1 (both shaders work in linear and write
    gamma 2.2, so colours given in sRGB come out as chosen)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


class NormalComputer:
    """Area-weighted vertex normals for a fixed triangle list, fast enough to
    run every frame (a sparse vertex-face incidence product)."""

    def __init__(self, n_points: int, faces: np.ndarray):
        from scipy.sparse import csr_matrix
        faces = np.asarray(faces, dtype=np.int64)
        t = len(faces)
        rows = faces.ravel()
        cols = np.repeat(np.arange(t), 3)
        self.faces = faces
        self.incidence = csr_matrix((np.ones(3 * t, np.float32), (rows, cols)),
                                    shape=(n_points, t))

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) -> (N, 3) float32 unit normals."""
        p = np.asarray(points, dtype=np.float32)
        a, b, c = p[self.faces[:, 0]], p[self.faces[:, 1]], p[self.faces[:, 2]]
        fn = np.cross(b - a, c - a)
        vn = self.incidence @ fn
        n = np.sqrt(np.einsum("ij,ij->i", vn, vn))
        n[n < 1e-20] = 1.0
        return (vn / n[:, None]).astype(np.float32, copy=False)


@dataclass
class _Entry:
    name: str
    faces: np.ndarray
    normals: NormalComputer
    has_colors: bool
    color: np.ndarray
    double_sided: bool
    prim: object = None
    node: object = None
    data: np.ndarray | None = None          # interleaved (N, 6 or 10) float32
    dirty: bool = False
    points_obj: object = None               # last points array object (identity check)
    stats: dict = field(default_factory=dict)


class Renderer:
    """Offscreen renderer for a fixed set of triangle meshes whose vertices
    (and per-vertex colours) may change every frame.

    size: (width, height) pixels. background: sRGB 0-1.
    Use :meth:`add_mesh` once per mesh, then per frame :meth:`set_points`
    (and/or :meth:`set_colors`), :meth:`set_view` and :meth:`render`.
    ``antialias``: keep pyrender's 4x multisampling (EGL only; about 4x
    slower in software). Off by default: pyrender's multisampled renderbuffers
    are re-allocated single-sampled after the first frame.
    ``update="rebuild"`` makes :meth:`set_points` rebuild the pyrender mesh
    instead of updating its vertex buffer (the slow baseline, for benchmarks).
    ``shading``: ``"preview"`` (default) draws lit meshes with the light
    per-fragment Lambert/Blinn-Phong shader of :mod:`.shading`, about 2x
    faster than pyrender's PBR shader under llvmpipe; ``"pbr"`` keeps
    pyrender's metallic-roughness shader. Either way pyrender's shader
    program cache is replaced by one that actually hits under OSMesa (see
    :mod:`.shading`).
    """

    def __init__(self, size=(640, 480), background=(0.94, 0.94, 0.95),
                 lights: LightRig = DEFAULT_RIG, update: str = "buffer",
                 antialias: bool = False, shading: str = "preview"):
        self.width, self.height = int(size[0]), int(size[1])
        if self.width < 8 or self.height < 8:
            raise ValueError(f"image size {self.width}x{self.height} too small")
        if update not in ("buffer", "rebuild"):
            raise ValueError("update must be 'buffer' or 'rebuild'")
        self.update = update
        if shading not in SHADINGS:
            raise ValueError(f"shading must be one of {SHADINGS}, got {shading!r}")
        pr, self._osr, self.platform = create_offscreen(self.width, self.height)
        self._pr = pr
        self.shading = shading
        self._osr._renderer._program_cache = make_cache(pr, shading, "fragment")
        self.background = np.asarray(background, dtype=np.float64)
        bg = np.concatenate([self.background, [1.0]])  # glClearColor: no gamma applied
        self.scene = pr.Scene(bg_color=bg.astype(np.float32),
                              ambient_light=np.full(3, lights.ambient, np.float32))
        self.rig = lights
        self._lights = [self.scene.add(pr.DirectionalLight(color=np.ones(3, np.float32),
                                                           intensity=float(light.intensity)))
                        for light in lights.lights]
        self._camera = None
        self._cam_node = None
        self._entries: list[_Entry] = []
        self.antialias = bool(antialias)
        self._msaa_checked = False
        self.uploads = 0  # vertex buffers re-uploaded so far
        self.rebuilds = 0

    # ------------------------------------------------------------------ meshes
    def add_mesh(self, name: str, points: np.ndarray, faces: np.ndarray, color=(0.7, 0.7, 0.7),
                 vertex_colors: np.ndarray | None = None, double_sided: bool = True) -> int:
        """Add a triangle mesh. points (N, 3) metres, faces (T, 3) int,
        color (3,) sRGB 0-1, vertex_colors (N, 3) sRGB 0-1 (then drawn per
        vertex and updatable with :meth:`set_colors`). Returns a handle."""
        points = np.asarray(points, dtype=np.float32)
        faces = np.asarray(faces, dtype=np.int64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise ValueError(f"mesh {name}: points must be (N, 3), got {points.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise ValueError(f"mesh {name}: faces must be (T, 3), got {faces.shape}")
        e = _Entry(name=name, faces=faces, normals=NormalComputer(len(points), faces),
                   has_colors=vertex_colors is not None,
                   color=np.asarray(color, dtype=np.float64), double_sided=double_sided)
        width = 10 if e.has_colors else 6
        e.data = np.empty((len(points), width), dtype=np.float32)
        if e.has_colors:
            e.data[:, 9] = 1.0
            e.data[:, 6:9] = srgb_to_linear(np.asarray(vertex_colors)[:, :3])
        self._entries.append(e)
        self._fill(e, points)
        self._build(e)
        return len(self._entries) - 1

    def _material(self, e: _Entry):
        base = np.ones(4) if e.has_colors else np.concatenate([srgb_to_linear(e.color), [1.0]])
        return self._pr.MetallicRoughnessMaterial(
            baseColorFactor=base.astype(np.float32).tolist(), metallicFactor=0.0,
            roughnessFactor=0.75, doubleSided=bool(e.double_sided))

    def _build(self, e: _Entry):
        pr = self._pr
        prim = pr.Primitive(positions=e.data[:, 0:3], normals=e.data[:, 3:6],
                            color_0=e.data[:, 6:10] if e.has_colors else None,
                            indices=e.faces.astype(np.uint32), material=self._material(e),
                            mode=pr.constants.GLTF.TRIANGLES)
        if e.node is not None:
            self.scene.remove_node(e.node)
        e.prim = prim
        e.node = self.scene.add(pr.Mesh([prim], is_visible=True), name=e.name)
        e.dirty = False

    def _fill(self, e: _Entry, points: np.ndarray):
        e.data[:, 0:3] = points
        e.data[:, 3:6] = e.normals(points)

    def set_points(self, handle: int, points: np.ndarray) -> None:
        """New (N, 3) vertex positions for a mesh; skipped when ``points`` is
        the very array object given last time (unchanged frame)."""
        e = self._entries[handle]
        if points is e.points_obj:
            return
        points = np.asarray(points, dtype=np.float32)
        if points.shape != (len(e.data), 3):
            raise ValueError(f"mesh {e.name}: expected {(len(e.data), 3)} points, got {points.shape}")
        self._fill(e, points)
        e.points_obj = points
        self._changed(e)

    def set_colors(self, handle: int, vertex_colors: np.ndarray) -> None:
        """New (N, 3) sRGB per-vertex colours for a mesh added with vertex_colors."""
        e = self._entries[handle]
        if not e.has_colors:
            raise ValueError(f"mesh {e.name} was added without vertex colours")
        e.data[:, 6:9] = srgb_to_linear(np.asarray(vertex_colors)[:, :3])
        self._changed(e)

    def _changed(self, e: _Entry):
        if self.update == "rebuild":
            self._build(e)
            self.rebuilds += 1
        else:
            e.dirty = True

    def _upload(self):
        """Copy changed interleaved vertex data into the GL buffers pyrender
        allocated (buffer 0 of a Primitive = positions|normals|colours, the
        same float32 layout as ``_Entry.data``)."""
        dirty = [e for e in self._entries if e.dirty]
        if not dirty:
            return
        from OpenGL.GL import GL_ARRAY_BUFFER, glBindBuffer, glBufferSubData
        self._osr._platform.make_current()
        for e in dirty:
            if e.prim._vaid is None:  # not in the context yet: pyrender uploads its own
                e.prim.positions = e.data[:, 0:3]  # copies on the first draw
                e.prim.normals = e.data[:, 3:6]
                if e.has_colors:
                    e.prim.color_0 = e.data[:, 6:10]
                e.dirty = False
                continue
            glBindBuffer(GL_ARRAY_BUFFER, e.prim._buffers[0])
            glBufferSubData(GL_ARRAY_BUFFER, 0, e.data.nbytes, e.data)
            e.dirty = False
            self.uploads += 1
        glBindBuffer(GL_ARRAY_BUFFER, 0)

    # ------------------------------------------------------------------ view
    def set_view(self, view: View) -> None:
        """Place the camera (and the camera-relative light rig)."""
        pr = self._pr
        cam = pr.PerspectiveCamera(yfov=float(view.yfov), aspectRatio=self.width / self.height,
                                   znear=float(view.znear), zfar=float(view.zfar))
        pose = view.camera_to_world().T  # row-vector -> pyrender column-vector
        if self._cam_node is not None:
            self.scene.remove_node(self._cam_node)
        self._cam_node = self.scene.add(cam, pose=pose)
        for node, p in zip(self._lights, light_poses(view, self.rig)):
            self.scene.set_pose(node, p.T)

    def render(self, depth: bool = False):
        """(H, W, 3) uint8 image (and (H, W) float32 depth in metres, 0 = empty)."""
        if self._cam_node is None:
            raise RuntimeError("set_view() first")
        self._upload()
        color, d = self._osr.render(self.scene)
        if not self._msaa_checked:
            self._msaa_checked = True
            if not self.antialias and self._single_sample():
                color, d = self._osr.render(self.scene)
        color = np.ascontiguousarray(color[:, :, :3])
        return (color, d) if depth else color

    def _single_sample(self) -> bool:
        """Re-allocate pyrender's multisampled offscreen renderbuffers (EGL) as
        single-sampled ones: the same framebuffer objects, blit becomes a copy.
        Software rasterisation gets about 4x faster. False if not applicable."""
        rr = getattr(self._osr, "_renderer", None)
        cb, db = getattr(rr, "_main_cb_ms", None), getattr(rr, "_main_db_ms", None)
        if cb is None or db is None:
            return False  # OSMesa: draws into the default framebuffer, no MSAA
        from OpenGL.GL import GL_DEPTH_COMPONENT24, GL_RENDERBUFFER, GL_RGBA, glBindRenderbuffer, glRenderbufferStorage
        try:
            self._osr._platform.make_current()
            glBindRenderbuffer(GL_RENDERBUFFER, cb)
            glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA, self.width, self.height)
            glBindRenderbuffer(GL_RENDERBUFFER, db)
            glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, self.width, self.height)
            glBindRenderbuffer(GL_RENDERBUFFER, 0)
        except Exception as exc:  # keep multisampling if the driver refuses
            debug(f"render: could not drop multisampling: {exc}")
            return False
        return True

    def close(self) -> None:
        if self._osr is not None:
            try:
                self._osr.delete()
            except Exception as exc:  # e.g. EGL display already terminated by another renderer
                debug(f"render: releasing the GL context failed: {exc}")
            finally:
                self._osr = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def n_triangles(self) -> int:
        return int(sum(len(e.faces) for e in self._entries))
