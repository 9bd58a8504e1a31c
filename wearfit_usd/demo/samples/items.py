"""Procedural wearable items made on a sample body (see :mod:`.body`).

Two constructions, both guaranteed outside the body through the implicit
solid's 1-Lipschitz bound (``f(p) >= c`` means at least ``c`` metres out):

* offset patches (undershirt, shirt, trousers, shoes, hair cap): the body's
  own quads in a region, moved onto the level set ``f = clearance``; hems
  are snapped onto their cutting planes so they come out straight;
* swept and lathed grids (skirt, hat, glasses, watch, necklace): rings of
  points pushed outward along rays until ``f >= clearance``.

Every item is a :class:`~wearfit_usd.model.Mesh` (quads where natural) with
a ``st`` UV primvar (``texCoord2f[]``; vertex for patches, indexed
faceVarying for grids) and a display colour.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ...geometry.closest import vertex_normals
from ...io.usd import triangulate
from ...model import Character, Mesh, Primvar
from .body import JOINT_NAMES, body_params, layout
from .implicit import Solid, relax_on_surface

#: clearance of each item above the skin, metres (lower bound of the offset)
CLEARANCE = {
    "undershirt": 0.004, "shirt": 0.012, "trousers": 0.008, "skirt": 0.02, "shoes": 0.005,
    "hat": 0.008, "glasses": 0.006, "watch": 0.003, "necklace": 0.004, "hair_cap": 0.005,
}
COLORS = {
    "undershirt": (0.92, 0.92, 0.88), "shirt": (0.25, 0.42, 0.7), "trousers": (0.2, 0.22, 0.3),
    "skirt": (0.7, 0.2, 0.3), "shoes": (0.35, 0.2, 0.1), "hat": (0.3, 0.25, 0.2),
    "glasses": (0.05, 0.05, 0.05), "watch": (0.75, 0.7, 0.3), "necklace": (0.85, 0.75, 0.2),
    "hair_cap": (0.3, 0.18, 0.08),
    # the garments of :mod:`.garments`
    "dress": (0.18, 0.5, 0.45), "pencil_skirt": (0.15, 0.15, 0.18), "suit": (0.42, 0.36, 0.3),
    "coat": (0.55, 0.45, 0.3), "long_hair": (0.45, 0.28, 0.12),
}


# --------------------------------------------------------------------------
# mesh building

def item_mesh(name: str, points: np.ndarray, polys: list[np.ndarray], st: Primvar) -> Mesh:
    """An item :class:`Mesh` from polygon blocks ``polys`` [(P, arity) vertex
    indices], its ``st`` primvar and the colour of ``name`` in :data:`COLORS`."""
    counts = np.concatenate([np.full(len(p), p.shape[1], dtype=np.int64) for p in polys if len(p)])
    fvi = np.concatenate([p.ravel() for p in polys if len(p)]).astype(np.int64)
    faces, t2p = triangulate(counts, fvi)
    return Mesh(name=name, points=np.asarray(points, np.float64), faces=faces,
                face_vertex_counts=counts, face_vertex_indices=fvi, tri_to_poly=t2p,
                path=f"/Root/Items/{name}", primvars=[st],
                display_color=np.array(COLORS.get(name, (0.5, 0.5, 0.5)), dtype=float))


def _st_vertex(uv: np.ndarray) -> Primvar:
    return Primvar("st", "texCoord2f[]", "vertex", np.asarray(uv, np.float32))


class _Grid:
    """A (rows, cols) grid of vertices: quads between rows, columns closed
    into a loop when ``closed``; optional pole vertices cap the first/last
    row with triangles. UVs are faceVarying, indexed, with a seam column."""

    def __init__(self, rows: int, cols: int, closed: bool = True, wrap_rows: bool = False):
        self.rows, self.cols, self.closed, self.wrap = rows, cols, closed, wrap_rows

    def build(self, name: str, pts: np.ndarray, pole_start=None, pole_end=None,
              offset: int = 0) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]:
        """pts (rows, cols, 3) -> points, polygons, uv values, uv indices per
        face-vertex (in polygon order)."""
        R, C = self.rows, self.cols
        vid = np.arange(R * C).reshape(R, C) + offset
        ncol = C if self.closed else C - 1
        nrow_uv = R + 1 if self.wrap else R
        uv_vals = np.stack(np.meshgrid(np.arange(C + 1) / C if self.closed else np.arange(C) / (C - 1),
                                       np.arange(nrow_uv) / max(nrow_uv - 1, 1), indexing="xy"), -1)
        uvc = uv_vals.shape[1]
        uv_id = np.arange(nrow_uv * uvc).reshape(nrow_uv, uvc)
        i, j = np.meshgrid(np.arange(R if self.wrap else R - 1), np.arange(ncol), indexing="ij")
        i, j = i.ravel(), j.ravel()
        j1 = (j + 1) % C
        i1 = (i + 1) % R
        quads = np.stack([vid[i, j], vid[i, j1], vid[i1, j1], vid[i1, j]], 1)
        uq = np.stack([uv_id[i, j], uv_id[i, j + 1], uv_id[i + 1, j + 1], uv_id[i + 1, j]], 1)
        points = pts.reshape(-1, 3)
        polys = [quads]
        uvi = [uq.ravel()]
        uv = uv_vals.reshape(-1, 2)
        for pole, row, flip in ((pole_start, 0, True), (pole_end, R - 1, False)):
            if pole is None:
                continue
            pid = offset + len(points)
            points = np.vstack([points, pole])
            jj = np.arange(ncol)
            tri = np.stack([vid[row, jj % C], vid[row, (jj + 1) % C], np.full(ncol, pid)], 1)
            uv_pole = len(uv)
            uv = np.vstack([uv, [[0.5, 0.0 if flip else 1.0]]])
            ut = np.stack([uv_id[row, jj], uv_id[row, jj + 1], np.full(ncol, uv_pole)], 1)
            if flip:
                tri, ut = tri[:, ::-1], ut[:, ::-1]
            polys.append(tri)
            uvi.append(ut.ravel())
        return points, polys, uv, np.concatenate(uvi)


def _orient(points: np.ndarray, polys: list[np.ndarray], uvi: np.ndarray, ref: np.ndarray):
    """Flip a part's polygons (and their uv indices) if most of them face
    towards their nearest ``ref`` point (ref (K, 3): a centre or a path)."""
    votes = 0.0
    for p in polys:
        a, b, c = points[p[:, 0]], points[p[:, 1]], points[p[:, 2]]
        n = np.cross(b - a, c - a)
        ctr = points[p].mean(axis=1)
        near = ref[np.argmin(((ctr[:, None] - ref[None]) ** 2).sum(-1), axis=1)]
        votes += np.sum(np.sign(np.sum(n * (ctr - near), 1)))
    if votes >= 0:
        return polys, uvi
    out_p, out_u, k = [], [], 0
    for p in polys:
        m = p.size
        out_p.append(p[:, ::-1].copy())
        out_u.append(uvi[k:k + m].reshape(p.shape)[:, ::-1].ravel())
        k += m
    return out_p, np.concatenate(out_u)


def _grid_mesh(name: str, parts: list[tuple]) -> Mesh:
    """Concatenate grids: parts = [(grid, pts (R, C, 3), pole_start, pole_end, ref)],
    each oriented so that its faces point away from ``ref`` (K, 3)."""
    all_pts, all_polys, all_uv, all_uvi = [], [], [], []
    n = 0
    nuv = 0
    for grid, pts, ps, pe, ref in parts:
        p, polys, uv, uvi = grid.build(name, pts, ps, pe, offset=n)
        local = [q - n for q in polys]
        local, uvi = _orient(p, local, uvi, np.atleast_2d(ref))
        polys = [q + n for q in local]
        all_pts.append(p)
        all_polys.extend(polys)
        all_uv.append(uv)
        all_uvi.append(uvi + nuv)
        n += len(p)
        nuv += len(uv)
    # keep the polygon order matching the uv index order: quads then triangles per part
    st = Primvar("st", "texCoord2f[]", "faceVarying", np.vstack(all_uv).astype(np.float32),
                 np.concatenate(all_uvi).astype(np.int64))
    # group polygons by arity is not needed: counts follow the list order
    return item_mesh(name, np.vstack(all_pts), all_polys, st)


def _frames_along(path: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tangents and parallel-transported normals/binormals along a polyline."""
    if closed:
        t = np.roll(path, -1, 0) - np.roll(path, 1, 0)
    else:
        t = np.gradient(path, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    n = np.zeros_like(t)
    ref = np.array([0.0, 1.0, 0.0]) if abs(t[0, 1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    n[0] = np.cross(t[0], ref)
    n[0] /= np.linalg.norm(n[0])
    for i in range(1, len(t)):
        v = n[i - 1] - np.dot(n[i - 1], t[i]) * t[i]
        n[i] = v / np.linalg.norm(v)
    b = np.cross(t, n)
    return t, n, b


def _tube(path: np.ndarray, radius: float, sides: int = 8, closed: bool = False):
    """(grid, pts, pole_start, pole_end) of a tube swept along ``path``."""
    _, n, b = _frames_along(path, closed)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = np.cos(ang)[None, :, None] * n[:, None] + np.sin(ang)[None, :, None] * b[:, None]
    pts = path[:, None, :] + radius * ring
    grid = _Grid(len(pts), sides, closed=True, wrap_rows=closed)
    # rows run along the path, columns around; cap open ends with poles
    return grid, pts, (None if closed else path[0]), (None if closed else path[-1]), path


# --------------------------------------------------------------------------
# offset patches

def _offset_patch(name: str, body: Mesh, solid: Solid, clearance: float, parts, snap: float,
                  keep_components: int = 1) -> Mesh:
    """:func:`offset_shell` as an item with cylindrical vertex UVs."""
    pts, q = offset_shell(body, solid, clearance, parts, snap, keep_components)
    # cylindrical UVs about the body's vertical axis
    u = np.arctan2(pts[:, 0], pts[:, 2]) / (2 * np.pi) + 0.5
    v = (pts[:, 1] - pts[:, 1].min()) / max(np.ptp(pts[:, 1]), 1e-9)
    return item_mesh(name, pts, [q], _st_vertex(np.stack([u, v], 1)))


def offset_shell(body: Mesh, solid: Solid, clearance: float, parts, snap: float,
                 keep_components: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Body quads whose vertices fall in ``parts`` moved to ``f = clearance``.

    parts: [(bone names, [(normal (3,), d), ...])]: a vertex belongs to a
        part if its dominant bone is listed and ``normal . p <= d`` for every
        plane (evaluated on the body point).
    snap: boundary vertices within this distance of a plane are moved onto it.

    Returns
    -------
    points : (V, 3) the shell's vertices, at least ``clearance`` outside.
    quads : (Q, 4) int64, wound like the body's (outward).
    """
    bone = np.asarray(JOINT_NAMES)[body.joint_indices[:, 0]]
    p0 = body.points
    keep = np.zeros(len(p0), bool)
    for bones, planes in parts:
        m = np.isin(bone, list(bones))
        for n, d in planes:
            m &= p0 @ np.asarray(n, float) <= d
        keep |= m
    quads = body.face_vertex_indices.reshape(-1, 4)
    qk = quads[keep[quads].all(axis=1)]
    # connected components over the kept quads; keep the largest ones
    nq = len(qk)
    a = np.repeat(np.arange(nq), 4)
    g = sp.coo_matrix((np.ones(4 * nq), (a, qk.ravel())), shape=(nq, len(p0))).tocsr()
    ncomp, lab = connected_components(g @ g.T, directed=False)
    sizes = np.bincount(lab)
    big = np.argsort(-sizes)[:keep_components]
    qk = qk[np.isin(lab, big)]
    used = np.unique(qk)
    remap = -np.ones(len(p0), np.int64)
    remap[used] = np.arange(len(used))
    q = remap[qk]
    src = p0[used]
    nrm = vertex_normals(body.points, body.faces)[used]
    pts = solid.project(src + clearance * nrm, clearance, iters=3)
    # boundary vertices: on an edge used by one quad only
    e = np.sort(np.stack([q, np.roll(q, -1, 1)], -1).reshape(-1, 2), axis=1)
    ue, cnt = np.unique(e, axis=0, return_counts=True)
    bnd = np.unique(ue[cnt == 1])
    # snap hems: boundary vertices near one of their part's planes
    all_planes = [(np.asarray(n, float) / np.linalg.norm(n), d / np.linalg.norm(n))
                  for _, planes in parts for n, d in planes]
    if all_planes and len(bnd):
        normals = np.stack([n for n, _ in all_planes])
        ds = np.array([d for _, d in all_planes])
        for _ in range(2):
            pb = pts[bnd]
            gap = pb @ normals.T - ds  # (B, P) <= 0 inside
            k = np.argmax(np.where(np.abs(gap) < snap, gap, -np.inf), axis=1)
            gk = gap[np.arange(len(bnd)), k]
            ok = np.abs(gk) < snap
            _, grad = solid.value_and_gradient(pb)
            sn = grad / np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-9)
            pn = normals[k]
            tang = pn - np.sum(pn * sn, 1, keepdims=True) * sn
            denom = np.maximum(np.sum(tang * pn, 1), 0.2)
            move = (-gk / denom)[:, None] * tang
            pb = pb + np.where(ok[:, None], move, 0.0)
            pts[bnd] = solid.project(pb, clearance, iters=3)
    fixed = np.zeros(len(pts), bool)
    fixed[bnd] = True
    pts = relax_on_surface(solid, pts, q, clearance, iters=2, amount=0.4, fixed=fixed)
    pts[bnd] = solid.project(pts[bnd], clearance, iters=3)
    return pts, q


# --------------------------------------------------------------------------
# the items

def make_items(body: Character, names: list[str] | None = None) -> list[Mesh]:
    """Sample items fitted to a sample body (made by :func:`.make_body`).

    names: subset of :data:`CLEARANCE` keys (default: all, in that order).
    """
    P = body_params(body)
    lay = layout(P)
    solid = lay.solid
    L = lay.landmarks
    J = lay.joints
    s = L["scale"]
    b = body.body
    want = list(CLEARANCE) if names is None else list(names)
    out = []
    up = np.array([0.0, 1.0, 0.0])
    torso = {"pelvis", "spine_01", "spine_02", "spine_03", "neck_01", "clavicle_l", "clavicle_r",
             "thigh_l", "thigh_r"}

    def arm_planes(side, length):
        d = L[f"arm_dir_{side}"]
        sh = J[f"upperarm_{side}"]
        return [(d, float(d @ sh + length))]

    def neckline(drop_front):
        # keep y + a z <= c: lower at the front (z > 0), higher at the back
        return ((0.0, 1.0, 0.45), float(L["neck_base_y"] - drop_front + 0.45 * 0.0))

    for name in want:
        c = CLEARANCE[name]
        if name in ("undershirt", "shirt"):
            inner = name == "undershirt"
            hem = L["hip_y"] + (0.02 if inner else -0.03) * s
            sleeve = 0.12 * s if inner else 0.29 * s + 0.255 * s - 0.03 * s
            arm_bones = ["upperarm"] if inner else ["upperarm", "lowerarm"]
            parts = [(torso, [(-up, -hem), neckline(0.035 * s if inner else 0.02 * s)])]
            for side in "lr":
                parts.append(({f"{bn}_{side}" for bn in arm_bones}, arm_planes(side, sleeve)))
            out.append(_offset_patch(name, b, solid, c, parts, snap=0.03 * s))
        elif name == "trousers":
            bones = {"pelvis", "spine_01", "spine_02", "thigh_l", "thigh_r", "calf_l", "calf_r",
                     "foot_l", "foot_r"}
            parts = [(bones, [(up, L["waist_y"]), (-up, -(L["ankle_y"] + 0.035 * s))])]
            out.append(_offset_patch(name, b, solid, c, parts, snap=0.03 * s))
        elif name == "shoes":
            bones = {"foot_l", "foot_r", "ball_l", "ball_r", "calf_l", "calf_r"}
            parts = [(bones, [(up, L["ankle_y"] + 0.025 * s)])]
            out.append(_offset_patch(name, b, solid, c, parts, snap=0.02 * s, keep_components=2))
        elif name == "hair_cap":
            ey = L["eye_l"][1]
            # keep y - 0.6 z >= ey - 0.015: hairline high at the forehead, low at the nape
            parts = [({"head", "neck_01"}, [((0.0, -1.0, 0.6), -(ey + 0.045 * s - 0.6 * 0.1 * s))])]
            out.append(_offset_patch(name, b, solid, c, parts, snap=0.02 * s))
        elif name == "skirt":
            out.append(_skirt(b, solid, lay, c))
        elif name == "hat":
            out.append(_hat(solid, lay, c))
        elif name == "glasses":
            out.append(_glasses(solid, lay, c))
        elif name == "watch":
            out.append(_watch(solid, lay, c))
        elif name == "necklace":
            out.append(_necklace(solid, lay, c))
        else:
            raise KeyError(f"unknown sample item {name!r}; known: {list(CLEARANCE)}")
    return out


def _skirt(body: Mesh, solid: Solid, lay, c: float, cols: int = 72, rows: int = 16) -> Mesh:
    """A flared tube from the waist to above the knees around both legs:
    each ring follows the support function (convex envelope) of the body's
    cross-section, never each leg."""
    L = lay.landmarks
    s = L["scale"]
    top, bottom = L["waist_y"], L["knee_y"] + 0.08 * s
    ys = np.linspace(top, bottom, rows)
    th = 2 * np.pi * np.arange(cols) / cols
    dirs = np.stack([np.sin(th), np.zeros(cols), np.cos(th)], 1)
    bone = np.asarray(JOINT_NAMES)[body.joint_indices[:, 0]]
    arm_bones = [n for n in JOINT_NAMES if n.startswith(("upperarm", "lowerarm", "hand", "clavicle"))]
    legs = ~np.isin(bone, arm_bones)
    pts_b = body.points[legs]
    centre = np.array([0.0, 0.0, pts_b[np.abs(pts_b[:, 1] - top) < 0.03, 2].mean()])
    radius = np.zeros((rows, cols))
    for i, y in enumerate(ys):
        sl = pts_b[np.abs(pts_b[:, 1] - y) < 0.025 * s] - centre
        radius[i] = (sl[:, [0, 2]] @ dirs[:, [0, 2]].T).max(axis=0) + c
    radius = np.maximum.accumulate(radius, axis=0)  # never narrower going down
    flare = 0.07 * s * ((top - ys) / (top - bottom)) ** 1.5
    radius += flare[:, None]
    for _ in range(4):  # round the corners of the envelope, never inwards
        radius = np.maximum(radius, 0.5 * radius + 0.25 * (np.roll(radius, 1, 1) + np.roll(radius, -1, 1)))
    pts = centre + ys[:, None, None] * np.array([0, 1.0, 0]) + radius[:, :, None] * dirs[None]
    flat = solid.push_out(pts.reshape(-1, 3), np.repeat(dirs[None], rows, 0).reshape(-1, 3), c)
    pts = flat.reshape(rows, cols, 3)
    axis = np.stack([np.zeros(rows), ys, np.full(rows, centre[2])], 1)
    return _grid_mesh("skirt", [(_Grid(rows, cols), pts, None, None, axis)])


def _hat(solid: Solid, lay, c: float, cols: int = 48) -> Mesh:
    """Crown (a boxy dome) and a flat brim, one grid from the brim's edge to
    the top pole."""
    L = lay.landmarks
    s = L["scale"]
    hc, hr = L["head_center"], L["head_radii"]
    yb = hc[1] + 0.03 * s
    th = 2 * np.pi * np.arange(cols) / cols
    dirs = np.stack([np.sin(th), np.zeros(cols), np.cos(th)], 1)
    axis_pt = np.array([hc[0], yb, hc[2]])
    base = solid.push_out(np.repeat(axis_pt[None], cols, 0), dirs, c + 0.004)
    r0 = np.linalg.norm((base - axis_pt)[:, [0, 2]], axis=1)
    brim_w = 0.055 * s * (1.0 + 0.25 * np.cos(th) ** 2)
    rows = []
    for t in np.linspace(1.0, 0.0, 5)[:-1]:  # brim, outer edge first
        r = r0 + brim_w * t
        y = yb - 0.012 * s * t * t
        rows.append(axis_pt + r[:, None] * dirs + (y - yb) * np.array([0, 1.0, 0]))
    top = hc[1] + hr[1] + 0.035 * s
    height = top - yb
    for phi in np.linspace(0, np.pi / 2, 10)[:-1]:  # crown, superellipse profile
        rho = np.cos(phi) ** 0.5
        hgt = np.sin(phi) ** 0.5
        taper = 1.0 - 0.08 * hgt
        rows.append(axis_pt + (r0 * rho * taper)[:, None] * dirs + hgt * height * np.array([0, 1.0, 0]))
    pts = np.stack(rows)
    crown = slice(4, None)
    flat = pts[crown].reshape(-1, 3)
    out_dir = flat - hc
    pts[crown] = solid.push_out(flat, out_dir, c).reshape(pts[crown].shape)
    pole = np.array([hc[0], hc[1] + hr[1] + 0.035 * s, hc[2]])
    ref = np.array([hc[0], yb - 0.3 * s, hc[2]])  # below the brim: faces point up and out
    return _grid_mesh("hat", [(_Grid(len(pts), cols), pts, None, pole, ref)])


def _glasses(solid: Solid, lay, c: float) -> Mesh:
    """Two elliptical rims in front of the eyes, a bridge and two temples."""
    L = lay.landmarks
    s = L["scale"]
    tube = 0.0022 * s
    level = c + tube
    parts = []
    hc = L["head_center"]
    rim_a, rim_b = 0.024 * s, 0.017 * s
    eye_l = L["eye_l"]
    # front plane: just in front of the face at the eyes and over the nose
    probe = np.array([[eye_l[0], eye_l[1], hc[2]], [-eye_l[0], eye_l[1], hc[2]], [0, eye_l[1], hc[2]],
                      [eye_l[0] + rim_a, eye_l[1], hc[2]], [eye_l[0], eye_l[1] - rim_b, hc[2]]])
    zf = solid.push_out(probe, np.tile([0, 0, 1.0], (len(probe), 1)), level + 0.004)[:, 2].max()
    ang = 2 * np.pi * np.arange(28) / 28
    for sx in (1.0, -1.0):
        cx = sx * (eye_l[0] + 0.004 * s)
        loop = np.stack([cx + rim_a * np.cos(ang), eye_l[1] + rim_b * np.sin(ang),
                         np.full(len(ang), zf) - 0.004 * s * (np.cos(ang) * sx) ** 2], 1)
        loop = solid.push_out(loop, np.tile([0, 0, 1.0], (len(loop), 1)), level)
        parts.append(_tube(loop, tube, closed=True))
    # bridge over the nose
    x0 = eye_l[0] + 0.004 * s - rim_a
    t = np.linspace(-1, 1, 9)
    bridge = np.stack([x0 * t, eye_l[1] + 0.006 * s + 0.005 * s * (1 - t * t), np.full(9, zf)], 1)
    bridge = solid.push_out(bridge, np.tile([0, 0, 1.0], (9, 1)), level)
    parts.append(_tube(bridge, tube))
    # temples: from the rims' outer edge back over the ears
    for sx in (1.0, -1.0):
        x_out = sx * (eye_l[0] + 0.004 * s + rim_a)
        zs = np.linspace(zf, hc[2] - 0.045 * s, 12)
        y = eye_l[1] + 0.004 * s - 0.02 * s * np.clip((hc[2] - zs) / (0.045 * s), 0, 1) ** 2
        path = np.stack([np.full(12, x_out * 0.5), y, zs], 1)
        path = solid.push_out(path, np.tile([sx, 0, 0], (12, 1)), level + 0.002)
        path[0] = [x_out, eye_l[1], zf]
        path[:, 0] = sx * np.maximum(sx * path[:, 0], sx * x_out * 0.98)
        parts.append(_tube(path, tube))
    return _grid_mesh("glasses", parts)


def _watch(solid: Solid, lay, c: float, cols: int = 40) -> Mesh:
    """A band with a rectangular section around the left wrist, thicker on
    the back of the wrist (the case)."""
    L = lay.landmarks
    s = L["scale"]
    J = lay.joints
    d = J["hand_l"] - J["lowerarm_l"]
    d /= np.linalg.norm(d)
    centre = J["hand_l"] - 0.04 * s * d
    e1 = np.cross(d, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e1, d)
    th = 2 * np.pi * np.arange(cols) / cols
    dirs = np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2
    half_w = 0.011 * s
    inner_b = solid.push_out(np.repeat((centre - half_w * d)[None], cols, 0), dirs, c)
    inner_f = solid.push_out(np.repeat((centre + half_w * d)[None], cols, 0), dirs, c)
    r_in = np.maximum(np.sum((inner_b - centre) * dirs, 1), np.sum((inner_f - centre) * dirs, 1))
    case = np.exp(-((np.angle(np.exp(1j * (th - np.pi / 2)))) / 0.45) ** 2)  # on e2 (back of wrist)
    r_out = r_in + 0.003 * s + 0.006 * s * case
    sect = [(-half_w, r_in), (-half_w, r_out), (half_w, r_out), (half_w, r_in)]
    rows = [centre + a * d + r[:, None] * dirs for a, r in sect]
    pts = np.stack(rows)
    ring = centre + 0.5 * (r_in + r_out)[:, None] * dirs
    return _grid_mesh("watch", [(_Grid(len(pts), cols, wrap_rows=True), pts, None, None, ring)])


def _necklace(solid: Solid, lay, c: float, n: int = 64) -> Mesh:
    """A tube around the base of the neck, dipping onto the chest in front."""
    L = lay.landmarks
    s = L["scale"]
    J = lay.joints
    tube = 0.0035 * s
    th = 2 * np.pi * np.arange(n) / n
    dirs = np.stack([np.sin(th), np.zeros(n), np.cos(th)], 1)
    y = L["neck_base_y"] - 0.005 * s - 0.06 * s * np.maximum(np.cos(th), 0) ** 2
    start = np.stack([np.full(n, J["neck_01"][0]), y, np.full(n, J["neck_01"][2])], 1)
    path = solid.push_out(start, dirs, c + tube)
    for _ in range(3):  # smooth the loop, then make sure it is still clear
        path = 0.5 * path + 0.25 * (np.roll(path, 1, 0) + np.roll(path, -1, 0))
        path = solid.push_out(path, dirs, c + tube)
    return _grid_mesh("necklace", [_tube(path, tube, sides=8, closed=True)])
