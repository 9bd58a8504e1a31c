"""Surface distances and the quality figures of a fit (plain numpy).

- :class:`SurfaceIndex`: closest points on a fixed triangle mesh, zero-area
  triangles left out (the fit's correspondence search and every measure);
- :func:`surface_distances`, :func:`surface_samples`, :func:`chamfer`:
  point-to-surface distances, area-uniform samples, both-way chamfer in mm;
- :func:`count_flipped`: triangles turned over between two embeddings;
- :func:`triangle_normals`: unnormalised triangle normals (2 x area long).

Used by :mod:`.body_fit`, the benchmarks and the tests.
"""
from __future__ import annotations

import numpy as np

from ..geometry.closest import SurfaceQuery, face_normals, vertex_normals
from ..geometry.mesh import nondegenerate
from ..types import Faces, Points, Scalars, Vectors


def triangle_normals(points: Points, faces: Faces) -> Vectors:
    """(T, 3) unnormalised normals (length = 2 * area)."""
    return face_normals(points, faces, unit=False)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n < 1e-30, 1.0, n)


class SurfaceIndex:
    """Closest-point queries on a fixed triangle mesh, for fitting: a thin
    layer over :class:`~wearfit_usd.geometry.closest.SurfaceQuery` that
    leaves degenerate triangles out (zero-area, see
    :func:`~wearfit_usd.geometry.mesh.nondegenerate`) and reports original
    face ids and the interpolated unit vertex normal at the closest point.
    """

    def __init__(self, points: Points, faces: Faces, k: int = 6):
        self.points = np.asarray(points, float)
        fn = triangle_normals(self.points, faces)
        area2 = np.linalg.norm(fn, axis=1)
        good = nondegenerate(self.points, faces)
        self.face_ids = np.flatnonzero(good)
        self.faces = np.asarray(faces)[good]
        self.face_normals = fn[good] / area2[good, None]
        self.k = int(min(k, len(self.faces)))
        self._query = SurfaceQuery(self.faces, self.points)
        self._vertex_normals = None

    @property
    def vertex_normals(self) -> np.ndarray:
        if self._vertex_normals is None:
            self._vertex_normals = vertex_normals(self.points, self.faces)
        return self._vertex_normals

    def query(self, q: np.ndarray, chunk: int = 20000, fast: bool = False):
        """Closest surface points to q (M, 3).

        Returns dict: ``points`` (M, 3), ``distance`` (M,), ``face`` (M,)
        index into the ORIGINAL face array, ``bary`` (M, 3), ``normal`` (M, 3)
        (interpolated vertex normal, unit). ``fast``: only the triangles with
        the nearest centroids are tested (no vertex ring), about 2x cheaper
        and nearly always the same answer on fine meshes.
        """
        res = self._query.closest(np.asarray(q, float), k=self.k, chunk=chunk, ring=not fast,
                                  signed=False)
        f, b = res["triangle"], res["bary"]
        nrm = _unit(np.einsum("mk,mkj->mj", b, self.vertex_normals[self.faces[f]]))
        return {"points": res["point"], "distance": res["distance"], "face_local": f,
                "face": self.face_ids[f], "bary": b, "normal": nrm}


def surface_distances(points: Points, mesh_points: Points, mesh_faces: Faces,
                      index: SurfaceIndex | None = None) -> Scalars:
    """(M,) distance from each of points (M, 3) to the surface (mesh_points, mesh_faces)."""
    index = index or SurfaceIndex(mesh_points, mesh_faces)
    return index.query(points)["distance"]


def surface_samples(points: Points, faces: Faces, count: int = 30000,
                    seed: int = 0) -> Points:
    """(count, 3) points spread uniformly by area over the triangles
    (points (N, 3), faces (T, 3)); deterministic for a given ``seed``."""
    points = np.asarray(points, float)
    faces = np.asarray(faces)
    area = np.linalg.norm(triangle_normals(points, faces), axis=1)
    rng = np.random.default_rng(seed)
    t = rng.choice(len(faces), size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    w = np.stack([1.0 - s, s * (1.0 - r2), s * r2], axis=1)  # uniform barycentric
    return np.einsum("mk,mkj->mj", w, points[faces[t]])


def chamfer(a_points: Points, a_faces: Faces, b_points: Points, b_faces: Faces,
            index_b: SurfaceIndex | None = None, samples: int = 30000) -> dict:
    """Point-to-surface distances both ways, in millimetres (inputs in metres).

    ``fit_to_target_*``: vertices of a to the surface of b; ``target_to_fit_*``:
    vertices of b to the surface of a. ``*_surface_*``: the same from
    ``samples`` points spread uniformly by area over each surface (the
    surface-to-surface figure: a vertex-dense detail such as the mouth weighs
    by its area, not by its vertex count). 0 samples: vertices only.
    """
    index_b = index_b or SurfaceIndex(b_points, b_faces)
    index_a = SurfaceIndex(a_points, a_faces)
    d_ab = index_b.query(a_points)["distance"] * 1e3
    d_ba = index_a.query(b_points)["distance"] * 1e3
    out = {"fit_to_target_mean_mm": float(d_ab.mean()),
           "fit_to_target_p99_mm": float(np.percentile(d_ab, 99)),
           "target_to_fit_mean_mm": float(d_ba.mean()),
           "target_to_fit_p99_mm": float(np.percentile(d_ba, 99))}
    if samples:
        s_ab = index_b.query(surface_samples(a_points, a_faces, samples))["distance"] * 1e3
        s_ba = index_a.query(surface_samples(b_points, b_faces, samples))["distance"] * 1e3
        out.update(fit_to_target_surface_mean_mm=float(s_ab.mean()),
                   fit_to_target_surface_p99_mm=float(np.percentile(s_ab, 99)),
                   target_to_fit_surface_mean_mm=float(s_ba.mean()),
                   target_to_fit_surface_p99_mm=float(np.percentile(s_ba, 99)))
    return out


def count_flipped(before: Points, after: Points, faces: Faces) -> int:
    """Triangles whose normal turned by more than 90 degrees between two
    embeddings of the same mesh (zero-area triangles in ``before`` ignored)."""
    n0 = triangle_normals(before, faces)
    n1 = triangle_normals(after, faces)
    good = nondegenerate(before, faces)
    return int(np.sum(np.einsum("ij,ij->i", n0[good], n1[good]) <= 0))
