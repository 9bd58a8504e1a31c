"""Plain-numpy data model shared by every pipeline stage (no USD here).

Internal space: world coordinates, Y up, metres. Matrices are 4x4 acting on
row vectors (``p' = [p, 1] @ M``), like USD's Gf; see :mod:`transforms`.

A :class:`Character` is what :func:`wearfit_usd.usd_io.read_character`
returns for one stage: its :class:`Skeleton`, the skinned body
:class:`Mesh` and every other mesh as a wearable item.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from .transforms import invert, transform_points

#: name suffix of an item's skinned copy written beside its point copy
#: (``wearfit dress --items both``); readers and the renderer take one of the two
SKINNED_SUFFIX = "_skinned"


def without_skinned_copies(names) -> list[bool]:
    """Per name, whether to keep it: ``<item>_skinned`` is dropped when
    ``<item>`` is among ``names`` (the same item written twice)."""
    plain = set(names)
    return [not (n.endswith(SKINNED_SUFFIX) and n[:-len(SKINNED_SUFFIX)] in plain) for n in names]

@dataclass
class Primvar:
    """A mesh primvar carried through unchanged (UVs, colours...).

    ``type_name`` is the Sdf value type token (e.g. ``"texCoord2f[]"``),
    ``values`` the raw array, ``indices`` the optional index array.
    """
    name: str
    type_name: str
    interpolation: str
    values: np.ndarray
    indices: np.ndarray | None = None
    element_size: int = 1


@dataclass
class Mesh:
    """A polygon mesh in internal space.

    points: (N, 3) float64, world space, metres, Y up (for a skinned mesh:
        the bind pose, i.e. ``points @ geomBindTransform`` mapped to world).
    faces: (T, 3) int64 triangles (polygons fan-triangulated, wound
        counter-clockwise seen from outside, whatever the source orientation).
    face_vertex_counts, face_vertex_indices: the original polygon layout, to
        write the same topology back.
    tri_to_poly: (T,) polygon index of each triangle.
    joint_indices, joint_weights: (N, K) influences into the skeleton's joint
        order (weights normalised to sum 1), or None for an unskinned mesh.
    parts: the separate meshes this one was merged from (a body made of one
        skinned mesh per body part), in vertex order; empty for a single
        mesh. Writers author them apart again (:meth:`split_parts`).
    """
    name: str
    points: np.ndarray
    faces: np.ndarray
    face_vertex_counts: np.ndarray
    face_vertex_indices: np.ndarray
    tri_to_poly: np.ndarray
    path: str = ""
    primvars: list[Primvar] = field(default_factory=list)
    normals_interpolation: str | None = None  # normals authored on the source
    left_handed: bool = False
    double_sided: bool = False
    joint_indices: np.ndarray | None = None
    joint_weights: np.ndarray | None = None
    display_color: np.ndarray | None = None  # (3,) float 0-1 if authored
    parts: list = field(default_factory=list)  # [Mesh] merged into this one

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def is_skinned(self) -> bool:
        return self.joint_indices is not None

    def copy_with_points(self, points: np.ndarray) -> Mesh:
        """Same topology and attributes, new (N, 3) points."""
        m = copy.copy(self)
        m.points = np.asarray(points, dtype=np.float64)
        return m

    def split_parts(self) -> list[Mesh]:
        """The meshes this one was merged from (:func:`merge_meshes`), with
        this mesh's current points and influences; ``[self]`` when it was
        not merged."""
        if len(self.parts) < 2:
            return [self]
        out, start = [], 0
        for part in self.parts:
            stop = start + part.n_points
            m = part.copy_with_points(self.points[start:stop])
            if self.joint_indices is not None:
                m.joint_indices = self.joint_indices[start:stop]
                m.joint_weights = self.joint_weights[start:stop]
            out.append(m)
            start = stop
        return out


def merge_meshes(meshes: list[Mesh], name: str, path: str = "") -> Mesh:
    """One mesh made of several (a body split into one skinned mesh per
    part): points, polygons and triangles concatenated, influences padded to
    the largest K with zero weights; each part's own primvars stay on the
    part (``parts``), the merged mesh carries none."""
    if len(meshes) == 1:
        return meshes[0]
    offs = np.cumsum([0] + [m.n_points for m in meshes])
    poly = np.cumsum([0] + [len(m.face_vertex_counts) for m in meshes])
    ji = jw = None
    if all(m.joint_indices is not None for m in meshes):
        k = max(m.joint_indices.shape[1] for m in meshes)
        ji = np.zeros((offs[-1], k), np.int64)
        jw = np.zeros((offs[-1], k))
        for m, o in zip(meshes, offs):
            ji[o:o + m.n_points, :m.joint_indices.shape[1]] = m.joint_indices
            jw[o:o + m.n_points, :m.joint_weights.shape[1]] = m.joint_weights
    return Mesh(name=name, path=path,
                points=np.concatenate([m.points for m in meshes]),
                faces=np.concatenate([m.faces + o for m, o in zip(meshes, offs)]),
                face_vertex_counts=np.concatenate([m.face_vertex_counts for m in meshes]),
                face_vertex_indices=np.concatenate([m.face_vertex_indices + o
                                                    for m, o in zip(meshes, offs)]),
                tri_to_poly=np.concatenate([m.tri_to_poly + p for m, p in zip(meshes, poly)]),
                left_handed=False if any(m.left_handed != meshes[0].left_handed for m in meshes)
                else meshes[0].left_handed,
                double_sided=any(m.double_sided for m in meshes),
                joint_indices=ji, joint_weights=jw,
                display_color=meshes[0].display_color, parts=list(meshes))


@dataclass
class Skeleton:
    """A joint hierarchy in internal space.

    joint_names: short names (last path element), J of them.
    joint_paths: the skeleton's joint tokens (``"Root/pelvis/spine_01"``).
    parents: (J,) int, -1 for a root; ``parents[j] < j``.
    bind_world: (J, 4, 4) bind transforms in internal world space.
    rest_local: (J, 4, 4) rest transforms, local to the parent joint, in the
        skeleton's own (stage) units/axes, as authored.
    skel_to_world: (4, 4) skeleton space -> internal world (the Skeleton
        prim's local-to-world followed by the up-axis/units change).
    """
    joint_names: list[str]
    joint_paths: list[str]
    parents: np.ndarray
    bind_world: np.ndarray
    rest_local: np.ndarray
    skel_to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    path: str = ""

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def world_from_local(self, local: np.ndarray) -> np.ndarray:
        """(..., J, 4, 4) local joint transforms (skeleton units) -> internal
        world transforms (..., J, 4, 4)."""
        local = np.asarray(local, dtype=np.float64)
        world = np.empty_like(local)
        for j, p in enumerate(self.parents):
            if p < 0:
                world[..., j, :, :] = local[..., j, :, :] @ self.skel_to_world
            else:
                world[..., j, :, :] = local[..., j, :, :] @ world[..., p, :, :]
        return world

    def local_from_world(self, world: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`world_from_local`."""
        world = np.asarray(world, dtype=np.float64)
        inv_world = invert(world)
        local = np.empty_like(world)
        inv_k = invert(self.skel_to_world)
        for j, p in enumerate(self.parents):
            if p < 0:
                local[..., j, :, :] = world[..., j, :, :] @ inv_k
            else:
                local[..., j, :, :] = world[..., j, :, :] @ inv_world[..., p, :, :]
        return local

    def rest_world(self) -> np.ndarray:
        """(J, 4, 4) internal world transforms of the rest pose."""
        return self.world_from_local(self.rest_local)

    def bind_positions(self) -> np.ndarray:
        """(J, 3) joint positions in the bind pose (internal world)."""
        return self.bind_world[:, 3, :3].copy()

    def index(self, name: str) -> int:
        return self.joint_names.index(name)


@dataclass
class Character:
    """One stage's rigged body and its wearable items (internal space).

    to_internal: (4, 4) stage world -> internal world (up axis + units).
    """
    source: str
    up_axis: str
    meters_per_unit: float
    to_internal: np.ndarray
    skeleton: Skeleton | None
    body: Mesh
    items: list[Mesh] = field(default_factory=list)
    time_codes_per_second: float = 24.0
    skel_root_path: str = ""

    def to_stage(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) internal points -> this stage's world space."""
        return transform_points(points, invert(self.to_internal))

    def item(self, name: str) -> Mesh:
        for m in self.items:
            if m.name == name:
                return m
        raise KeyError(f"{self.source}: no item named {name!r}; items: "
                       f"{[m.name for m in self.items]}")
