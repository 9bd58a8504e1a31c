"""Procedural garments made on a sample body: long and loose ones for the
motion tests (issue 17), built like real assets.

* ``dress``: a strapless bodice (the body's own quads offset to its
  clearance, cut straight under the arms, lower in front) sewn at the waist
  to an A-line skirt to the ankles, one mesh;
* ``pencil_skirt``: a straight, slightly tapered skirt from the waist to
  below the knees (one closed tube, open at the waist and the hem);
* ``suit``: a jacket with long sleeves and a skirt to the knees in one mesh
  (the jacket's hem loop is the skirt's first row);
* ``coat``: the same construction, wider, to mid-calf;
* ``long_hair``: a scalp cap from the crown hanging straight down the back
  to the shoulder blades, open at the face.

Every garment is outside the body by at least its clearance
(:data:`GARMENT_CLEARANCE`; the implicit solid's 1-Lipschitz bound, as in
:mod:`.items`), open at its hems, cuffs and neck, closed around the body,
carries a faceVarying ``st`` UV primvar (cylindrical about the vertical axis,
a seam at the back, values in [0, 1]) and has a few thousand vertices.
Everything is deterministic (no random numbers).
"""
from __future__ import annotations

import numpy as np

from ...geometry.mesh import boundary_loops
from ...model import Character, Mesh, Primvar
from .body import JOINT_NAMES, body_params, layout, make_body
from .implicit import Solid, relax_on_surface
from .items import item_mesh, offset_shell

#: clearance of each garment above the skin, metres (lower bound of the offset)
GARMENT_CLEARANCE = {"dress": 0.012, "pencil_skirt": 0.008, "suit": 0.012, "coat": 0.018,
                     "long_hair": 0.006}
#: garments hanging free of the legs or the back (loose parts in issue 17's sense)
LOOSE_GARMENTS = ("dress", "coat", "long_hair")
#: grid step (m) of the body mesh whose quads the bodices and jackets are cut from
#: (coarser than the sample bodies: a jacket keeps a few thousand vertices)
SHELL_RESOLUTION = 0.02
RELAX_ITERS = 10  # extra smoothing of a shell's interior vertices on its level set

_UP = np.array([0.0, 1.0, 0.0])
_TORSO = {"pelvis", "spine_01", "spine_02", "spine_03", "neck_01", "clavicle_l", "clavicle_r"}
_ARM_BONES = [n for n in JOINT_NAMES if n.startswith(("upperarm", "lowerarm", "hand", "clavicle"))]


def _leg_and_torso_points(body: Mesh) -> np.ndarray:
    """Body vertices not on the arms (the skirt envelopes ignore the arms)."""
    bone = np.asarray(JOINT_NAMES)[body.joint_indices[:, 0]]
    return body.points[~np.isin(bone, _ARM_BONES)]


def make_garments(body: Character, names: list[str] | None = None) -> list[Mesh]:
    """Garments fitted to a sample body (made by :func:`.body.make_body`).

    Parameters
    ----------
    body : the sample character (its ``source`` names its parameters).
    names : subset of :data:`GARMENT_CLEARANCE` keys (default: all, in that order).

    Returns
    -------
    list of :class:`~wearfit_usd.model.Mesh`, one per name, in internal space.
    """
    params = body_params(body)
    lay = layout(params)
    want = list(GARMENT_CLEARANCE) if names is None else list(names)
    unknown = [n for n in want if n not in GARMENT_CLEARANCE]
    if unknown:
        raise KeyError(f"unknown sample garment {unknown[0]!r}; known: {list(GARMENT_CLEARANCE)}")
    shell_body = None
    out = []
    for name in want:
        c = GARMENT_CLEARANCE[name]
        if name in ("dress", "suit", "coat"):
            if shell_body is None:
                shell_body = make_body(params, resolution=SHELL_RESOLUTION).body
            out.append(_BUILDERS[name](body.body, lay, c, shell_body))
        else:
            out.append(_BUILDERS[name](body.body, lay, c))
    return out


# --------------------------------------------------------------------------
# pieces

def _mesh(name: str, points: np.ndarray, polys: list[np.ndarray], axis_z: float) -> Mesh:
    return item_mesh(name, points, polys, cylindrical_uv(points, polys, axis_z))


def cylindrical_uv(points: np.ndarray, polys: list[np.ndarray], axis_z: float = 0.0) -> Primvar:
    """Indexed faceVarying ``st``: u = angle about the vertical axis through
    (0, axis_z) (seam at the back, -z), v = height over the mesh's height.

    Parameters
    ----------
    points : (V, 3) vertices.
    polys : [(P, arity) int] polygon blocks, in the mesh's polygon order.
    axis_z : z of the vertical axis.

    Returns
    -------
    Primvar ``st`` (texCoord2f[], faceVarying) with values (U, 2) in [0, 1]
    and indices (sum of polygon sizes,).
    """
    u = (np.arctan2(points[:, 0], points[:, 2] - axis_z) / (2 * np.pi) + 0.5)
    v = (points[:, 1] - points[:, 1].min()) / max(np.ptp(points[:, 1]), 1e-9)
    on_axis = np.hypot(points[:, 0], points[:, 2] - axis_z) < 1e-6
    fv_u, fv_v = [], []
    for p in polys:
        uu = u[p].copy()
        seam = (uu.max(axis=1) - uu.min(axis=1)) > 0.5
        uu[seam] = np.where(uu[seam] < 0.5, uu[seam] + 1.0, uu[seam])
        axis_corner = on_axis[p]
        if axis_corner.any():  # a pole: the mean u of the polygon's other corners
            other = np.where(axis_corner, 0.0, uu).sum(1) / np.maximum((~axis_corner).sum(1), 1)
            uu = np.where(axis_corner, other[:, None], uu)
        fv_u.append(uu.ravel())
        fv_v.append(v[p].ravel())
    fu = np.concatenate(fv_u)
    fu = fu / max(float(fu.max()), 1.0)  # seam corners beyond 1: squeeze back into [0, 1]
    uv = np.round(np.stack([fu, np.concatenate(fv_v)], 1), 6)
    values, idx = np.unique(uv, axis=0, return_inverse=True)
    return Primvar("st", "texCoord2f[]", "faceVarying", values.astype(np.float32),
                   idx.ravel().astype(np.int64))


def drop_slivers(points: np.ndarray, quads: np.ndarray, rel_area: float = 0.02):
    """Remove boundary quads with a near-zero-area fan triangle (three
    corners in a line where a hem was snapped onto its plane) whose removal
    leaves no vertex behind but their own ear vertex; repeat until none.

    Parameters
    ----------
    points : (V, 3); quads : (Q, 4) int.
    rel_area : a triangle is a sliver below this fraction of the median quad area.

    Returns
    -------
    points (V', 3) and quads (Q', 4) with the unused vertices dropped.
    """
    q = np.asarray(quads)
    while True:
        a, b, c, d = (points[q[:, i]] for i in range(4))
        t1 = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        t2 = 0.5 * np.linalg.norm(np.cross(c - a, d - a), axis=1)
        thin = np.minimum(t1, t2) < rel_area * np.median(t1 + t2)
        if not thin.any():
            break
        use = np.bincount(q.ravel(), minlength=len(points))
        ear = (use[q] == 1).any(axis=1)  # a corner only this quad uses: on the boundary
        drop = thin & ear
        if not drop.any():
            break
        q = q[~drop]
    used = np.unique(q)
    remap = -np.ones(len(points), np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[q]


def _min_angles(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(T,) smallest corner angle (radians) of triangles with corners (T, 3) each."""
    def corner(p, q, r):
        u, v = q - p, r - p
        cos = np.sum(u * v, 1) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-300)
        return np.arccos(np.clip(cos, -1.0, 1.0))
    return np.minimum(np.minimum(corner(a, b, c), corner(b, c, a)), corner(c, a, b))


def fattest_split(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Rotate each quad so that its fan diagonal (v0-v2) is the one whose two
    triangles have the larger smallest angle (no needle triangles where three
    corners lie nearly in a line).

    Parameters
    ----------
    points : (V, 3); quads : (Q, 4) int.

    Returns
    -------
    (Q, 4) the same quads, some started one corner later (winding kept).
    """
    p = [points[quads[:, i]] for i in range(4)]
    keep = np.minimum(_min_angles(p[0], p[1], p[2]), _min_angles(p[0], p[2], p[3]))
    turn = np.minimum(_min_angles(p[1], p[2], p[3]), _min_angles(p[1], p[3], p[0]))
    out = quads.copy()
    flip = turn > keep
    out[flip] = np.roll(quads[flip], -1, axis=1)
    return out


def _support(points: np.ndarray, ys: np.ndarray, dirs: np.ndarray, centre: np.ndarray,
             band: float) -> np.ndarray:
    """(R, C) support function of the body's horizontal slices: for each
    height ``ys[r]`` the farthest extent, along each unit ``dirs[c]`` (C, 3),
    of ``points`` within ``band`` of that height, from ``centre`` (3,)."""
    out = np.empty((len(ys), len(dirs)))
    for r, y in enumerate(ys):
        sl = points[np.abs(points[:, 1] - y) < band] - centre
        out[r] = (sl[:, [0, 2]] @ dirs[:, [0, 2]].T).max(axis=0)
    return out


def _hanging_rows(top: np.ndarray, centre: np.ndarray, ys: np.ndarray, body: Mesh, solid: Solid,
                  c: float, flare: np.ndarray, taper: float, band: float) -> np.ndarray:
    """Rows of a skirt hanging from the ring ``top`` (C, 3) down to the
    heights ``ys`` (R,): each row keeps the convex envelope of the legs and
    hips (never each leg) plus ``c``, never narrower than the rows above by
    more than ``taper`` (fraction of the radius at the hem), plus ``flare``
    (R,) metres; finally pushed out of the solid. Returns (R, C, 3)."""
    d = top[:, [0, 2]] - centre[[0, 2]]
    th = np.arctan2(d[:, 0], d[:, 1])
    dirs = np.stack([np.sin(th), np.zeros(len(th)), np.cos(th)], 1)
    env = _support(_leg_and_torso_points(body), ys, dirs, centre, band) + c
    rho0 = np.sum(d * dirs[:, [0, 2]], axis=1)
    widest = np.maximum.accumulate(np.vstack([rho0, env]), axis=0)[1:]
    t = (ys[0] - ys) / max(ys[0] - ys[-1], 1e-9)
    radius = np.maximum(env, widest * (1.0 - taper * t)[:, None]) + flare[:, None]
    for _ in range(4):  # round the corners of the envelope, never inwards
        radius = np.maximum(radius, 0.5 * radius + 0.25 * (np.roll(radius, 1, 1) + np.roll(radius, -1, 1)))
    pts = centre[None, None] * [1, 0, 1] + ys[:, None, None] * _UP + radius[:, :, None] * dirs[None]
    flat = solid.push_out(pts.reshape(-1, 3), np.repeat(dirs[None], len(ys), 0).reshape(-1, 3), c)
    return flat.reshape(len(ys), len(th), 3)


def _ring_quads(rows_ids: np.ndarray) -> np.ndarray:
    """Quads between consecutive rows of vertex ids (R, C), columns closed:
    row r's edge ``i -> i+1`` is walked backwards by the quad below it, so a
    first row that is a boundary loop walked along its quads' winding is
    continued with the same orientation."""
    R, C = rows_ids.shape
    i, j = np.meshgrid(np.arange(R - 1), np.arange(C), indexing="ij")
    i, j = i.ravel(), j.ravel()
    j1 = (j + 1) % C
    return np.stack([rows_ids[i, j1], rows_ids[i, j], rows_ids[i + 1, j], rows_ids[i + 1, j1]], 1)


def _shell_with_skirt(name: str, body: Mesh, shell_body: Mesh, lay, c: float, parts, hem_y: float,
                      bottom_y: float, flare: float, taper: float = 0.0, row_step: float = 0.03) -> Mesh:
    """An offset shell (bodice or jacket, see :func:`.items.offset_shell`) of
    ``shell_body``'s quads cut by the plane ``y = hem_y``, continued below its
    hem loop by a skirt hanging to ``bottom_y`` around ``body`` that flares
    by ``flare`` metres at its hem."""
    s = lay.landmarks["scale"]
    pts, q = drop_slivers(*offset_shell(shell_body, lay.solid, c, parts, snap=0.03 * s))
    loops = boundary_loops(q)
    # even out the spacing where the offset surface folds in (the armpits)
    rim = np.zeros(len(pts), bool)
    rim[np.concatenate(loops)] = True
    pts = relax_on_surface(lay.solid, pts, q, c, iters=RELAX_ITERS, amount=0.5, fixed=rim)
    hem = min(loops, key=lambda lp: pts[lp, 1].mean())
    top = pts[hem]
    centre = np.array([0.0, 0.0, top[:, 2].mean()])
    n_rows = max(int(np.ceil((hem_y - bottom_y) / (row_step * s))), 2)
    ys = np.linspace(hem_y, bottom_y, n_rows + 1)[1:]
    tt = (hem_y - ys) / (hem_y - bottom_y)
    rows = _hanging_rows(top, centre, ys, body, lay.solid, c, flare * tt ** 1.3, taper, 0.025 * s)
    ids = np.vstack([hem, len(pts) + np.arange(rows.shape[0] * rows.shape[1]).reshape(rows.shape[:2])])
    allp = np.vstack([pts, rows.reshape(-1, 3)])
    quads = fattest_split(allp, np.vstack([q, _ring_quads(ids)]))  # offsetting changed the quads' shapes
    return _mesh(name, allp, [quads], centre[2])


# --------------------------------------------------------------------------
# the garments

def _dress(body: Mesh, lay, c: float, shell_body: Mesh) -> Mesh:
    """Strapless A-line dress to the ankles: the bodice's top edge runs under
    the arms, lower in front; the skirt flares by 24 cm (scaled) at the hem."""
    L = lay.landmarks
    s = L["scale"]
    waist = L["waist_y"]
    neck = ((0.0, 1.0, 0.55), float(L["neck_base_y"] - 0.07 * s))
    bodice = [(_TORSO - {"neck_01"}, [(-_UP, -waist), neck])]
    return _shell_with_skirt("dress", body, shell_body, lay, c, bodice, waist, L["ankle_y"] + 0.06 * s,
                             flare=0.24 * s)


def _jacket_parts(lay, hem_y: float, cuff_back: float, neck_drop: float):
    L, J = lay.landmarks, lay.joints
    s = L["scale"]
    parts = [(_TORSO | {"thigh_l", "thigh_r"}, [(-_UP, -hem_y),
                                                 ((0.0, 1.0, 0.45), float(L["neck_base_y"] - neck_drop))])]
    for side in "lr":
        d = L[f"arm_dir_{side}"]
        length = (0.29 + 0.255) * s - cuff_back
        parts.append(({f"upperarm_{side}", f"lowerarm_{side}"},
                      [(d, float(d @ J[f"upperarm_{side}"] + length))]))
    return parts


def _suit(body: Mesh, lay, c: float, shell_body: Mesh) -> Mesh:
    """One-piece jacket with long sleeves and a skirt to the knees."""
    L = lay.landmarks
    s = L["scale"]
    hem = L["hip_y"] + 0.04 * s
    return _shell_with_skirt("suit", body, shell_body, lay, c, _jacket_parts(lay, hem, 0.025 * s, 0.01 * s),
                             hem, L["knee_y"] + 0.02 * s, flare=0.03 * s)


def _coat(body: Mesh, lay, c: float, shell_body: Mesh) -> Mesh:
    """Long coat to mid-calf: long sleeves, closed front, a slight flare."""
    L = lay.landmarks
    s = L["scale"]
    hem = L["hip_y"] + 0.04 * s
    return _shell_with_skirt("coat", body, shell_body, lay, c, _jacket_parts(lay, hem, 0.015 * s, 0.0),
                             hem, 0.5 * (L["knee_y"] + L["ankle_y"]), flare=0.1 * s)


def _pencil_skirt(body: Mesh, lay, c: float, cols: int = 64) -> Mesh:
    """Waist to below the knees, following the hips and tapering to the hem."""
    L = lay.landmarks
    s = L["scale"]
    top, bottom = L["waist_y"], L["knee_y"] - 0.06 * s
    th = 2 * np.pi * np.arange(cols) / cols
    dirs = np.stack([np.sin(th), np.zeros(cols), np.cos(th)], 1)
    pts_b = _leg_and_torso_points(body)
    centre = np.array([0.0, 0.0, pts_b[np.abs(pts_b[:, 1] - top) < 0.03 * s, 2].mean()])
    ring = centre + top * _UP + (_support(pts_b, [top], dirs, centre, 0.02 * s)[0] + c)[:, None] * dirs
    ring = lay.solid.push_out(ring, dirs, c)
    n_rows = int(np.ceil((top - bottom) / (0.025 * s)))
    ys = np.linspace(top, bottom, n_rows + 1)[1:]
    rows = _hanging_rows(ring, centre, ys, body, lay.solid, c, np.zeros(n_rows), 0.08, 0.025 * s)
    allp = np.vstack([ring, rows.reshape(-1, 3)])
    ids = np.arange(len(allp)).reshape(n_rows + 1, cols)
    quads = _ring_quads(ids)
    return _mesh("pencil_skirt", allp, [_outward(allp, quads, centre)], centre[2])


def _outward(points: np.ndarray, quads: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``quads`` flipped if most of them face the vertical axis through ``centre``."""
    a, b, c = points[quads[:, 0]], points[quads[:, 1]], points[quads[:, 2]]
    n = np.cross(b - a, c - a)
    out = points[quads].mean(1) - centre
    out[:, 1] = 0.0
    return quads if np.sum(np.sign(np.sum(n * out, 1))) >= 0 else quads[:, ::-1].copy()


def _long_hair(body: Mesh, lay, c: float, cols: int = 64, rows: int = 44) -> Mesh:
    """A cap from the crown over the head, open at the face, hanging straight
    down the back to the shoulder blades. One grid of columns from the
    crown, evenly spaced along a column's length, trimmed where each column
    ends (a hairline at the forehead, below the ears at the sides, mid-back
    behind: an uneven, layered hem)."""
    L = lay.landmarks
    s = L["scale"]
    hc, hr = L["head_center"], L["head_radii"]
    solid = lay.solid
    th = 2 * np.pi * np.arange(cols) / cols  # 0 = front (+z)
    dirs = np.stack([np.sin(th), np.zeros(cols), np.cos(th)], 1)
    w = 0.5 * (1.0 - np.cos(th))  # 0 at the front, 1 at the back
    y_end = hc[1] + s * np.interp(w, [0.0, 0.2, 0.35, 0.5, 0.75, 1.0],
                                  [0.065, 0.045, -0.05, -0.13, -0.33, -0.47])
    # sigma 0..1: crown to the head's equator (polar angle / 90 deg); beyond:
    # the hanging drop below the equator in units of the quarter meridian
    unit = 0.5 * np.pi * hr[1]
    sig_end = np.where(y_end >= hc[1], np.arccos(np.clip((y_end - hc[1]) / hr[1], -1, 1)) / (0.5 * np.pi),
                       1.0 + (hc[1] - y_end) / unit)
    sig = sig_end.max() * np.arange(1, rows + 1) / rows  # (rows,) the same in every column
    on_head = np.repeat((sig <= 1.0)[:, None], cols, 1)
    phi = 0.5 * np.pi * np.minimum(sig, 1.0)
    ray = (np.sin(phi)[:, None, None] * dirs[None] * (hr / hr[1])[None, None]
           + np.cos(phi)[:, None, None] * _UP)
    head_pts = solid.push_out(np.repeat(hc[None], rows * cols, 0), ray.reshape(-1, 3), c).reshape(rows, cols, 3)
    # hanging part: straight down from the head's widest ring, pushed off neck, shoulders and back
    eq = solid.push_out(np.repeat(hc[None], cols, 0), dirs * (hr / hr[1]), c)
    r_eq = np.sum((eq - hc)[:, [0, 2]] * dirs[:, [0, 2]], axis=1)
    y_h = hc[1] - np.maximum(sig - 1.0, 0.0) * unit
    start = hc * [1, 0, 1] + y_h[:, None, None] * _UP + r_eq[None, :, None] * dirs[None]
    flat_dirs = np.repeat(dirs[None], rows, 0).reshape(-1, 3)
    hang = solid.push_out(start.reshape(-1, 3), flat_dirs, c).reshape(rows, cols, 3)
    pts = np.where(on_head[..., None], head_pts, hang)
    hanging = ~on_head.ravel()
    for _ in range(3):  # smooth the hanging columns (a kink over the shoulders), then clear again
        sm = pts.copy()
        sm[1:-1] = 0.25 * pts[:-2] + 0.5 * pts[1:-1] + 0.25 * pts[2:]
        flat = np.where(on_head[..., None], pts, sm).reshape(-1, 3)
        flat[hanging] = solid.push_out(flat[hanging], flat_dirs[hanging], c)
        pts = flat.reshape(rows, cols, 3)
    pole = solid.push_out(hc[None], _UP[None], c)
    allp = np.vstack([pole, pts.reshape(-1, 3)])
    ids = 1 + np.arange(rows * cols).reshape(rows, cols)
    quads = _ring_quads(ids)
    # keep the quads whose corners all lie within their columns' lengths
    inside = np.concatenate([[True], (sig[:, None] <= sig_end[None, :] + 1e-9).ravel()])
    quads = quads[inside[quads].all(axis=1)]
    j = np.arange(cols)
    tris = np.stack([np.zeros(cols, np.int64), ids[0, j], ids[0, (j + 1) % cols]], 1)
    used = np.unique(np.concatenate([quads.ravel(), tris.ravel()]))
    remap = -np.ones(len(allp), np.int64)
    remap[used] = np.arange(len(used))
    centre = np.array([hc[0], 0.0, hc[2]])
    allp, quads, tris = allp[used], remap[quads], remap[tris]
    quads_o = _outward(allp, quads, centre)
    if quads_o is not quads:
        tris = tris[:, ::-1].copy()
    return _mesh("long_hair", allp, [quads_o, tris], hc[2])


_BUILDERS = {"dress": _dress, "pencil_skirt": _pencil_skirt, "suit": _suit, "coat": _coat,
             "long_hair": _long_hair}
