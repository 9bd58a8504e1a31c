"""Dressing benchmark: reference items on every target body, next to MakeHuman's .mhclo fitting.

Peers in the same run: MakeHuman's .mhclo proxy fitting (same-topology shapes)
and the classic one-triangle barycentric wrap (K=1, no regions, no push-out).
Writes front-view comparison pictures (items coloured by clearance):
``dress_<reference>_<target>.png``.

Per (reference, target, item): new penetrations (item vertices >1 mm inside the
target body that were outside the reference body), clearance change (median /
95th percentile of |signed distance change|), flipped item triangles and item
edges stretched beyond the body's own local stretch (``metrics.shape_change``:
main figures against the binding's blended body deformation and the 2K bound
triangles with the clearance's offset factor, degenerate reference triangles
(< 1 degree) left out and counted in ``degenerate_excluded``; edges of
rigid parts left out of ``overstretch_pct`` and judged by their own
criterion instead: ``rigid_edges`` of them, ``overstretch_rigid_pct`` beyond
[0.8, 1.25] x their part's fitted uniform scale, ``rigid_residual_mm`` how
far a rigid part was bent off its best-fit similarity; ``_strict``
columns: one body triangle, nothing left out), timings (binding evaluation,
penetration + layer passes, untangle pass; ``bind_redress_s`` = the plan
plus ``dress`` on the fitted body, and the same at 15,000 item vertices with
an outer layer added); for the same-topology
targets also the MakeHuman proxy fit (.mhclo on the recipe shape incl. helper
vertices) and the mean distance between both results.

    python3 benchmarks/bench_dress.py [--full]
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
DATA = REPO.parent / "shared" / "data"

MALE = ["body_male_heavy.usdc", "body_male_muscular_heavy.usdc", "body_male_tall.usdc",
        "body_male_muscular_posed.usdc", "body_male_cmu_rig.usdc"]
FEMALE = ["body_female_thin.usdc", "body_female_heavy.usdc", "body_female_short.usdc",
          "body_female_uncommon_yup.usdc", "body_female_heavy_remeshed.usdc"]
QUICK = {"body_male_heavy.usdc", "body_male_muscular_posed.usdc", "body_female_heavy.usdc",
         "body_female_heavy_remeshed.usdc"}
# body_shapes.json recipe of each target (None: no MakeHuman peer: posed body)
SHAPE = {"ref_male.usda": "male_average", "ref_female.usda": "female_average",
         "body_male_heavy.usdc": "male_heavy", "body_male_muscular_heavy.usdc": "male_muscular_heavy",
         "body_male_tall.usdc": "male_tall", "body_male_muscular_posed.usdc": None,
         "body_male_cmu_rig.usdc": "male_average", "body_female_thin.usdc": "female_thin",
         "body_female_heavy.usdc": "female_heavy", "body_female_short.usdc": "female_short",
         "body_female_uncommon_yup.usdc": "female_weak_uncommon_proportions",
         "body_female_heavy_remeshed.usdc": "female_heavy"}
# targets on which the 15,000-vertex outfit is timed too (the slowest two)
LARGE_TARGETS = {"body_male_muscular_heavy.usdc", "body_male_muscular_posed.usdc"}


def _proxies():
    from benchmarks.peers.mhclo import read_mhclo
    return [read_mhclo(p) for p in sorted((DATA / "items").glob("*/*.mhclo"))]


def _proxy_for(item, proxies):
    for px in proxies:
        if len(px.refs) == item.n_points and (item.name.startswith(px.name) or px.name.startswith(item.name)):
            return px
    return None


def run(full: bool, out_dir: Path) -> list[dict]:
    from benchmarks.peers.mhclo import fit as mh_fit
    from benchmarks.peers.mhclo import shape_points, to_internal
    from wearfit_usd.dress.apply import dress, fitted_body_points
    from wearfit_usd.dress.binding import bind
    from wearfit_usd.dress.metrics import clearance_change, item_rigid_groups, shape_change
    from wearfit_usd.dress.plan import plan
    from wearfit_usd.geometry.closest import SurfaceQuery
    from wearfit_usd.io.usd import read_character

    usd = DATA / "usd"
    proxies = _proxies()
    shapes = {}
    rows = []
    fitted = {}
    for ref_name, targets in (("ref_male.usda", MALE), ("ref_female.usda", FEMALE)):
        ref = read_character(usd / ref_name)
        qr = SurfaceQuery(ref.body.faces, ref.body.points)
        ref_d = [qr.signed_distance(m.points) for m in ref.items]
        t0 = time.perf_counter()
        pl = plan(ref)
        t_plan = time.perf_counter() - t0
        # peer: the classic one-triangle barycentric wrap (K=1, no regions, no push-out)
        wrap = bind(ref.body.points, ref.body.faces, pl.ref_points, k=1)
        pictured = False
        for tname in targets:
            if not full and tname not in QUICK:
                continue
            tgt = read_character(usd / tname)
            base = {"reference": ref_name, "target": tname}
            try:
                t0 = time.perf_counter()
                body = fitted_body_points(ref, tgt)
                t_fit = time.perf_counter() - t0
            except Exception as exc:  # other topology without body_fit
                rows.append({**base, "item": "*", "error": str(exc).split(": ", 1)[-1][:90]})
                continue
            # the reference's plan, made once, on this fitted body (rigid parts
            # that do not fit it are released: res.plan)
            t0 = time.perf_counter()
            res = dress(ref, tgt, body_points=body, prepared=pl)
            t_dress = time.perf_counter() - t0
            pl_t, pts, moved, tm = res.plan, res.points, res.moved, res.timings
            if tname in LARGE_TARGETS:
                fitted[tname] = (tgt, body)
            released = [n for n in pl.rigid_items if n not in pl_t.rigid_items]
            pts_k1 = wrap.evaluate(body)
            qt = SurfaceQuery(tgt.body.faces, tgt.body.points)
            mh_items = []
            shape = SHAPE.get(tname)
            mh_base = body_err = None
            if shape is not None:
                if shape not in shapes:
                    shapes[shape] = shape_points(DATA / "makehuman", shape)
                mh_base = shapes[shape]
                if tgt.body.n_points == ref.body.n_points:
                    body_err = float(np.abs(to_internal(mh_base[:ref.body.n_points])
                                            - tgt.body.points).max()) * 1000
            for i, (item, sl) in enumerate(zip(pl.items, pl.item_slices())):
                p = pts[sl]
                dr, dt = ref_d[i], qt.signed_distance(p)
                sc = shape_change(item.points, p, item.faces, pl.binding.triangles[sl], pl.binding.weights[sl],
                                  ref.body.points, body, ref.body.faces, dr,
                                  rigid_groups=item_rigid_groups(pl_t, sl))
                row = {**base, "item": item.name, "verts": item.n_points,
                       "rigid": item.name in pl_t.rigid_items, "released": item.name in released,
                       **{k: round(v, 3) for k, v in clearance_change(dr, dt).items()},
                       "flipped_pct": round(sc["flipped_pct"], 3),
                       "flipped_strict_pct": round(sc["flipped_strict_pct"], 3),
                       "degenerate_excluded": sc["degenerate"], "flipped_degenerate": sc["flipped_degenerate"],
                       "overstretch_pct": round(sc["overstretch_pct"], 3),
                       "overstretch_strict_pct": round(sc["overstretch_strict_pct"], 3),
                       "rigid_edges": sc["rigid_edges"],
                       "overstretch_rigid_pct": round(sc["overstretch_rigid_pct"], 3),
                       "rigid_residual_mm": round(sc["rigid_residual_mm"], 3),
                       "pushed": int(moved[sl].sum())}
                k1 = clearance_change(dr, qt.signed_distance(pts_k1[sl]))
                k1s = shape_change(item.points, pts_k1[sl], item.faces, wrap.triangles[sl], wrap.weights[sl],
                                   ref.body.points, body, ref.body.faces, dr)
                row.update({"k1_new_pen_pct": round(k1["new_pen_pct"], 3),
                            "k1_clear_med_mm": round(k1["clear_med_mm"], 3),
                            "k1_clear_p95_mm": round(k1["clear_p95_mm"], 3),
                            "k1_flipped_pct": round(k1s["flipped_pct"], 3),
                            "k1_flipped_strict_pct": round(k1s["flipped_strict_pct"], 3),
                            "k1_overstretch_pct": round(k1s["overstretch_pct"], 3),
                            "k1_overstretch_strict_pct": round(k1s["overstretch_strict_pct"], 3)})
                px = _proxy_for(item, proxies)
                if mh_base is not None and px is not None:
                    mp = to_internal(mh_fit(px, mh_base))
                    mh_items.append(item.copy_with_points(mp))
                    mh = clearance_change(dr, qt.signed_distance(mp))
                    row.update({"mh_new_pen_pct": round(mh["new_pen_pct"], 3),
                                "mh_clear_med_mm": round(mh["clear_med_mm"], 3),
                                "mh_clear_p95_mm": round(mh["clear_p95_mm"], 3),
                                "dist_to_mh_mean_mm": round(float(np.linalg.norm(p - mp, axis=1).mean()) * 1000, 3)})
                if body_err is not None:
                    row["mh_body_recipe_err_mm"] = round(body_err, 6)
                rows.append(row)
            if not pictured and mh_items:
                pictured = True
                _picture(ref, tgt, [m.copy_with_points(pts[sl]) for m, sl in zip(pl.items, pl.item_slices())],
                         mh_items, [m.copy_with_points(pts_k1[sl]) for m, sl in zip(pl.items, pl.item_slices())],
                         Path(out_dir) / f"dress_{Path(ref_name).stem}_{Path(tname).stem}.png")
            rows.append({**base, "item": "*timing*", "verts": int(len(pts)),
                         "plan_s": round(t_plan, 4), "bind_s": round(pl.timings["bind_s"], 4),
                         "evaluate_ms": round(tm["evaluate_s"] * 1000, 3),
                         "penetration_s": round(tm["penetration_s"], 4),
                         "untangle_s": round(tm.get("untangle_s", 0.0), 4), "body_fit_s": round(t_fit, 4),
                         "dress_s": round(t_dress, 4), "bind_redress_s": round(t_plan + t_dress, 4)})
        # per-frame evaluation speed of the whole binding (the lead's animation loop)
        n = 200
        t0 = time.perf_counter()
        for _ in range(n):
            pl.binding.evaluate(ref.body.points)
        per = (time.perf_counter() - t0) / n
        rows.append({"reference": ref_name, "target": "(per frame)", "item": "*evaluate*",
                     "verts": int(pl.binding.n_items), "evaluate_ms": round(per * 1000, 3),
                     "frames_per_s": round(1.0 / per, 1), "nnz": int(pl.binding.matrix.nnz)})
        if ref_name == "ref_male.usda" and fitted:
            rows += _large_outfit(ref, fitted)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "dress.json").write_text(json.dumps(rows, indent=1))
    return rows


def _large_outfit(ref, fitted: dict, n_total: int = 15000, repeat: int = 3) -> list[dict]:
    """Binding plus redress time at the size the issue names (15,000 item
    vertices; ref_male has 12,661): ref_male's items plus an outer layer 4 mm
    over its suit (its first vertices, up to ``n_total`` in all), planned and
    dressed on each fitted target of ``fitted`` {name: (target, fitted body
    points)}; median of ``repeat`` runs, and the outer layer's fit figures."""
    from dataclasses import replace

    from benchmarks.bench_animate import _layer_item, _outer_layer
    from wearfit_usd.dress.apply import dress
    from wearfit_usd.dress.metrics import clearance_change, shape_change
    from wearfit_usd.dress.plan import plan
    from wearfit_usd.geometry.closest import SurfaceQuery
    suit = max(ref.items, key=lambda m: m.n_points)
    layer = _layer_item(suit, _outer_layer(suit, 0.004), n_total - sum(m.n_points for m in ref.items))
    big = replace(ref, items=list(ref.items) + [layer])
    d_ref = SurfaceQuery(ref.body.faces, ref.body.points).signed_distance(layer.points)
    rows = []
    for tname, (tgt, body) in fitted.items():
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            pl = plan(big)
            t1 = time.perf_counter()
            res = dress(big, tgt, body_points=body, prepared=pl)
            times.append((t1 - t0, time.perf_counter() - t1))
        t_plan, t_dress = np.median(np.array(times), axis=0)
        sl = res.plan.item_slices()[-1]
        p = res.points[sl]
        sc = shape_change(layer.points, p, layer.faces, res.plan.binding.triangles[sl],
                          res.plan.binding.weights[sl], ref.body.points, body, ref.body.faces, d_ref)
        cc = clearance_change(d_ref, SurfaceQuery(tgt.body.faces, tgt.body.points).signed_distance(p))
        rows.append({"reference": "ref_male.usda + outer layer", "target": tname, "item": "*timing*",
                     "verts": int(res.points.shape[0]), "plan_s": round(float(t_plan), 4),
                     "dress_s": round(float(t_dress), 4), "bind_redress_s": round(float(t_plan + t_dress), 4),
                     "penetration_s": round(res.timings["penetration_s"], 4),
                     "untangle_s": round(res.timings.get("untangle_s", 0.0), 4),
                     "layer_new_pen_pct": round(cc["new_pen_pct"], 3),
                     "layer_clear_med_mm": round(cc["clear_med_mm"], 3),
                     "layer_flipped_pct": round(sc["flipped_pct"], 3),
                     "layer_overstretch_pct": round(sc["overstretch_pct"], 3)})
    return rows


def _picture(ref, tgt, ours, mh, k1, dest: Path) -> None:
    """Front views side by side: reference, target body, our result, the
    MakeHuman .mhclo fit and the K=1 wrap, items coloured by clearance."""
    import tempfile

    from PIL import Image, ImageDraw

    from wearfit_usd.io.usd import write_character
    from wearfit_usd.render import render_frames
    tiles = []
    with tempfile.TemporaryDirectory() as tmp:
        stages = [("reference", ref.source, True)]
        for label, items, heat in (("target", [], False), ("wearfit", ours, True),
                                   ("MakeHuman .mhclo", mh, True), ("K=1 wrap", k1, True)):
            p = Path(tmp) / f"{len(stages)}.usda"
            write_character(p, tgt, items=items)
            stages.append((label, p, heat))
        for label, path, heat in stages:
            im = render_frames(path, size=(300, 450), camera="front", heatmap=heat, show_progress=False)[0]
            img = Image.fromarray(im)
            ImageDraw.Draw(img).text((8, 8), label, fill=(20, 20, 20))
            tiles.append(np.asarray(img))
    dest.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(tiles, axis=1)).save(dest)


def _table(rows):
    cols = ["reference", "target", "item", "verts", "rigid", "new_pen_pct", "mh_new_pen_pct",
            "clear_med_mm", "clear_p95_mm", "mh_clear_med_mm", "mh_clear_p95_mm", "flipped_pct",
            "flipped_strict_pct", "degenerate_excluded", "overstretch_pct", "overstretch_strict_pct",
            "rigid_edges", "overstretch_rigid_pct", "rigid_residual_mm",
            "k1_new_pen_pct", "k1_clear_med_mm", "k1_flipped_pct", "k1_flipped_strict_pct", "k1_overstretch_pct",
            "k1_overstretch_strict_pct",
            "dist_to_mh_mean_mm", "pushed", "bind_s", "evaluate_ms",
            "penetration_s", "untangle_s", "frames_per_s", "error"]
    used = [c for c in cols if any(c in r for r in rows)]
    lines = [" | ".join(used)]
    for r in rows:
        lines.append(" | ".join(str(r.get(c, "")) for c in used))
    return "\n".join(lines)


if __name__ == "__main__":
    import warnings
    warnings.simplefilter("ignore")
    rows = run("--full" in sys.argv, REPO / "benchmarks" / "results")
    print(_table(rows))
