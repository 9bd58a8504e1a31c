"""CLI: `wearfit dress REF TARGET -o OUT` writes a readable stage; bad input writes nothing."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from benchmarks.peers.mhclo import shape_points, to_internal
from wearfit_usd.cli import main
from wearfit_usd.dress.apply import dress
from wearfit_usd.dress.metrics import dress_report
from wearfit_usd.io.usd import read_character


def test_cli_writes_target_body_and_all_items(tmp_path, usd_dir, ref_male):
    from wearfit_usd.io.usd import read_character
    out = tmp_path / "out.usda"
    rc = main(["dress", str(usd_dir / "ref_male.usda"), str(usd_dir / "body_male_heavy.usdc"),
               "-o", str(out), "--k", "4", "-q"])
    assert rc == 0 and out.exists()
    back = read_character(out)
    target = read_character(usd_dir / "body_male_heavy.usdc")
    assert back.up_axis == target.up_axis
    np.testing.assert_allclose(back.body.points, target.body.points, atol=1e-5)
    assert back.skeleton.joint_names == target.skeleton.joint_names
    assert sorted(m.name for m in back.items) == sorted(m.name for m in ref_male.items)
    for m in ref_male.items:
        b = back.item(m.name)
        assert np.array_equal(b.face_vertex_counts, m.face_vertex_counts)
        assert np.array_equal(b.face_vertex_indices, m.face_vertex_indices)
        assert [p.name for p in b.primvars] == [p.name for p in m.primvars]
        # moved onto the heavier body, but still close to where it was
        assert np.abs(b.points - m.points).max() < 0.1


def test_cli_missing_file_exit_2_no_output(tmp_path, usd_dir, capsys):
    out = tmp_path / "out.usda"
    rc = main(["dress", str(tmp_path / "missing.usda"), str(usd_dir / "body_male_heavy.usdc"),
               "-o", str(out)])
    assert rc == 2
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
    assert "missing.usda" in capsys.readouterr().err


def test_cli_reference_without_items_exit_2(tmp_path, usd_dir):
    out = tmp_path / "out.usda"
    rc = main(["dress", str(usd_dir / "body_male_tall.usdc"), str(usd_dir / "body_male_heavy.usdc"),
               "-o", str(out), "-q"])
    assert rc == 2
    assert not out.exists()


def test_cli_dress_report(tmp_path, usd_dir, capsys):
    import json
    out, rep = tmp_path / "d.usdc", tmp_path / "r.json"
    assert main(["dress", str(usd_dir / "ref_female.usda"), str(usd_dir / "body_female_thin.usdc"), "-o", str(out),
                 "--report", str(rep)]) == 0
    items = json.loads(rep.read_text())["items"]
    assert {r["item"] for r in items} == {"eyebrow001", "female_casualsuit01", "shoes02", "ponytail01"}
    for r in items:
        assert r["new_pen_pct"] <= 0.5 and r["clear_med_mm"] <= 2.0
        assert r["flipped_pct"] == 0.0 and r["overstretch_pct"] == 0.0, r
    err = capsys.readouterr().err
    assert "ponytail01" in err and "edges beyond the body's stretch 0.00 %" in err and "untangle" in err


@pytest.mark.slow
def test_low_poly_game_body_no_new_penetrations(data_dir, ref_male):
    # GDQuest's mannequin (another topology, edges up to 215 mm): the items
    # were 4-11 % inside it where the fitted body left its surface outside
    target = read_character(data_dir / "thirdparty" / "bodies" / "mannequiny_idle_blender.usdc")
    res = dress(ref_male, target)
    rows = dress_report(ref_male, target, res)
    assert max(r["new_pen_pct"] for r in rows) <= 1.0, rows


@pytest.mark.slow
@pytest.mark.parametrize("shape, limit", [("thin", 0.016), ("short", 0.028)])
def test_long_skirt_near_makehuman_helper(data_dir, usd_dir, shape, limit):
    """MakeHuman's own skirt helper deformed by the shape's targets is the
    designer's fit. On the thin body the hem used to rise and split open at
    the back (p95 97 mm), then the binding kept it wide (17.7 mm); on the
    13 % shorter body the hem, lengthened as the legs' edges, hung 4.5 cm
    lower than the helper's (p95 45.7 mm): the skirt now keeps its height
    over the floor in proportion to its top's (thin 14.6, short 23.6 mm;
    smoothed in the body's frames, 15.9 and 23.1 mm)."""
    ref = read_character(usd_dir / "ref_female_longskirt.usda")
    skirt = next(i for i, m in enumerate(ref.items) if "skirt" in m.name)
    _, idx = cKDTree(to_internal(shape_points(data_dir / "makehuman", "female_average"))).query(
        ref.items[skirt].points)
    helper = to_internal(shape_points(data_dir / "makehuman", f"female_{shape}"))[idx]
    res = dress(ref, read_character(usd_dir / f"body_female_{shape}.usdc"))
    pts = res.items[skirt].points
    err = np.linalg.norm(pts - helper, axis=1)
    assert np.percentile(err, 95) < limit
    assert abs(pts[:, 1].min() - helper[:, 1].min()) < 0.015  # the hem's height
