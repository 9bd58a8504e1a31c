"""io.usd_carry / usd_carry_check: what the inputs carry (materials and their
networks, bindings on meshes and GeomSubsets, inherited bindings and
primvars, indexed primvars, custom attributes, kind, purpose) reaches the
outputs, copied or referenced; on a small synthetic stage (known answers)
and on the dev references through the `dress` and `animate` commands."""
from __future__ import annotations

import numpy as np
import pytest

from tests.tiny_stage import TINY_USDA
from wearfit_usd.dress.hidden_body import drop_polygons
from wearfit_usd.io.usd import read_character, write_character
from wearfit_usd.io.usd_carry import HIDDEN_SUBSET, CarryPlan
from wearfit_usd.io.usd_carry_check import check_carried

pxr = pytest.importorskip("pxr")

#: the tiny stage's scarf made two quads, with materials, a materialBind
#: subset, an indexed face-varying UV set, a custom uniform primvar, custom
#: attribute and metadata; a second item inherits its binding and a
#: constant primvar from its parent Xform; the body has UVs and a material
SCARF = '''    def Mesh "Scarf" (
        prepend apiSchemas = ["MaterialBindingAPI"]
        kind = "component"
        customData = {string origin = "test"}
    )
    {
        int[] faceVertexCounts = [4, 4]
        int[] faceVertexIndices = [0, 1, 2, 3, 1, 4, 5, 2]
        point3f[] points = [(-0.25, 1.5, 0.15), (0, 1.5, 0.15), (0, 1.7, 0.15), (-0.25, 1.7, 0.15),
                            (0.25, 1.5, 0.15), (0.25, 1.7, 0.15)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "faceVarying"
        )
        int[] primvars:st:indices = [0, 1, 2, 3, 0, 1, 2, 3]
        float[] primvars:wear = [0.25, 0.75] (
            interpolation = "uniform"
        )
        color3f[] primvars:displayColor = [(0.2, 0.4, 0.6)] (
            interpolation = "constant"
        )
        uniform token subdivisionScheme = "catmullClark"
        uniform token purpose = "render"
        custom string userProperties:note = "hand-made"
        rel material:binding = </Root/Looks/Cloth>

        def GeomSubset "trim" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {
            uniform token elementType = "face"
            uniform token familyName = "materialBind"
            int[] indices = [1]
            rel material:binding = </Root/Looks/Trim>
        }
    }

    def Xform "Outfit" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {
        rel material:binding = </Root/Looks/Trim>
        float[] primvars:displayOpacity = [0.5] (
            interpolation = "constant"
        )

        def Mesh "Cap"
        {
            int[] faceVertexCounts = [4]
            int[] faceVertexIndices = [0, 1, 2, 3]
            point3f[] points = [(-0.2, 2.05, 0.15), (0.2, 2.05, 0.15), (0.2, 2.05, -0.15), (-0.2, 2.05, -0.15)]
        }
    }

    def Scope "Looks"
    {
        def Material "Cloth"
        {
            token outputs:surface.connect = </Root/Looks/Cloth/Surface.outputs:surface>

            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor.connect = </Root/Looks/Cloth/Tex.outputs:rgb>
                float inputs:roughness = 0.7
                token outputs:surface
            }

            def Shader "Tex"
            {
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @cloth.png@
                float2 inputs:st.connect = </Root/Looks/Cloth/Reader.outputs:result>
                float3 outputs:rgb
            }

            def Shader "Reader"
            {
                uniform token info:id = "UsdPrimvarReader_float2"
                token inputs:varname = "st"
                float2 outputs:result
            }
        }

        def Material "Trim"
        {
            token outputs:surface.connect = </Root/Looks/Trim/Surface.outputs:surface>

            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0.9, 0.1, 0.1)
                token outputs:surface
            }
        }

        def Material "Skin"
        {
            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0.8, 0.6, 0.5)
            }
        }
    }
'''
SCARF_OLD = TINY_USDA[TINY_USDA.index('    def Mesh "Scarf"'):TINY_USDA.rindex("}")]
BODY_OLD = '            rel skel:skeleton = </Root/Character/Skeleton>\n'
BODY_NEW = ('            rel skel:skeleton = </Root/Character/Skeleton>\n'
            '            rel material:binding = </Root/Looks/Skin>\n'
            '            texCoord2f[] primvars:st = [(0, 0), (1, 0), (0, 1), (1, 1), (0, 0.5), (1, 0.5), '
            '(0, 0.7), (1, 0.7)] (\n                interpolation = "vertex"\n            )\n')


def _rich_stage(tmp_path):
    text = TINY_USDA.replace(SCARF_OLD, SCARF).replace(BODY_OLD, BODY_NEW)
    text = text.replace('prepend apiSchemas = ["SkelBindingAPI"]',
                        'prepend apiSchemas = ["SkelBindingAPI", "MaterialBindingAPI"]')
    p = tmp_path / "rich.usda"
    p.write_text(text)
    return p


def _moved(char):
    return [m.copy_with_points(m.points + 0.01) for m in char.items]


@pytest.mark.parametrize("reference", [False, True], ids=["copy", "reference"])
def test_everything_carried_onto_moved_items(tmp_path, reference):
    src = _rich_stage(tmp_path)
    char = read_character(src)
    items = _moved(char)
    out = tmp_path / "out.usda"
    write_character(out, char, items=items,
                    carry_plan=CarryPlan.for_dress(char, char, items, reference_inputs=reference))
    assert check_carried(src, out) == []
    assert check_carried(src, out, {"/Root/Character/Body": "/Root/Character/Body"}, points_changed=False) == []
    st = pxr.Usd.Stage.Open(str(out))
    scarf = st.GetPrimAtPath("/Root/Items/Scarf")
    # the points are the moved ones, whatever the input says
    pts = np.asarray(pxr.UsdGeom.Mesh(scarf).GetPointsAttr().Get())
    np.testing.assert_allclose(pts, items[[m.name for m in items].index("Scarf")].points, atol=1e-6)
    mat, _ = pxr.UsdShade.MaterialBindingAPI(scarf.GetChild("trim")).ComputeBoundMaterial()
    assert str(mat.GetPath()).startswith("/Root/Materials/")
    cap_mat, _ = pxr.UsdShade.MaterialBindingAPI(st.GetPrimAtPath("/Root/Items/Cap")).ComputeBoundMaterial()
    assert cap_mat.GetPath().name == "Trim"          # inherited from its parent Xform in the input
    assert pxr.UsdGeom.Mesh(scarf).GetSubdivisionSchemeAttr().Get() == "catmullClark"
    assert pxr.UsdGeom.Xformable(scarf).ComputeLocalToWorldTransform(0) == pxr.Gf.Matrix4d(1)
    layer_text = st.GetRootLayer().ExportToString()
    assert ("references" in layer_text) == reference
    assert ("UsdUVTexture" in layer_text) == (not reference)


def test_check_finds_what_a_plain_write_loses(tmp_path):
    src = _rich_stage(tmp_path)
    char = read_character(src)
    out = tmp_path / "plain.usda"
    write_character(out, char, items=_moved(char))
    lost = check_carried(src, out)
    assert any("material binding" in x and "Scarf" in x for x in lost)
    assert any("GeomSubset trim missing" in x for x in lost)
    assert any("userProperties:note" in x for x in lost)
    assert any("metadata kind" in x for x in lost)


def test_dropped_body_faces_reindex_carried_data(tmp_path):
    src = _rich_stage(tmp_path)
    char = read_character(src)
    body, keep = drop_polygons(char.body, np.array([1, 4]))
    assert keep.tolist() == [True, False, True, True, False, True]
    plan = CarryPlan.for_dress(char, char, char.items).with_hidden({}, keep)
    out = tmp_path / "dropped.usda"
    write_character(out, char, items=char.items, body=body, carry_plan=plan)
    st = pxr.Usd.Stage.Open(str(out))
    m = pxr.UsdGeom.Mesh(st.GetPrimAtPath("/Root/Character/Body"))
    n = len(m.GetPointsAttr().Get())
    idx = np.asarray(m.GetFaceVertexIndicesAttr().Get())
    assert len(m.GetFaceVertexCountsAttr().Get()) == 4 and idx.max() == n - 1
    st_pv = pxr.UsdGeom.PrimvarsAPI(m.GetPrim()).GetPrimvar("st").Get()
    assert len(st_pv) == n == len(body.points)
    ji = pxr.UsdSkel.BindingAPI(m.GetPrim()).GetJointIndicesPrimvar().Get()
    assert len(ji) == n
    # the kept vertices' UVs are the input's at those vertices
    used = np.zeros(8, bool)
    corner = np.repeat(keep, char.body.face_vertex_counts)
    used[char.body.face_vertex_indices[corner]] = True
    src_stage = pxr.Usd.Stage.Open(str(src))
    src_st = np.asarray(pxr.UsdGeom.PrimvarsAPI(src_stage.GetPrimAtPath("/Root/Character/Body"))
                        .GetPrimvar("st").Get())
    np.testing.assert_array_equal(np.asarray(st_pv), src_st[used])


def test_hidden_subsets_written_and_not_drawn(tmp_path):
    from wearfit_usd.render.scene import read_scene
    src = _rich_stage(tmp_path)
    char = read_character(src)
    plan = CarryPlan.for_dress(char, char, char.items).with_hidden({HIDDEN_SUBSET: np.array([0, 2])})
    out = tmp_path / "hidden.usda"
    write_character(out, char, items=char.items, carry_plan=plan)
    st = pxr.Usd.Stage.Open(str(out))
    sub = pxr.UsdGeom.Subset(st.GetPrimAtPath(f"/Root/Character/Body/{HIDDEN_SUBSET}"))
    assert list(sub.GetIndicesAttr().Get()) == [0, 2]
    assert sub.GetElementTypeAttr().Get() == "face"
    scene = read_scene(out)
    assert len(scene.body.faces) == 2 * (6 - 2)


@pytest.mark.parametrize("reference", [False, True], ids=["copy", "reference"])
def test_shot_with_value_clips_keeps_everything(tmp_path, reference):
    from wearfit_usd.io.usd_shot import ShotWriter
    src = _rich_stage(tmp_path)
    char = read_character(src)
    out = tmp_path / "shot.usda"
    plan = CarryPlan.for_dress(char, char, char.items, reference_inputs=reference)
    with ShotWriter(out, char, char.items, fps=24, n_frames=3, clip_frames=2, carry_plan=plan) as w:
        for f in range(3):
            w.write_frame(f, [m.points + 0.01 * f for m in char.items])
    assert check_carried(src, out) == []
    st = pxr.Usd.Stage.Open(str(out))
    scarf = char.items[[m.name for m in char.items].index("Scarf")]
    pts = np.asarray(pxr.UsdGeom.Mesh(st.GetPrimAtPath("/Root/Items/Scarf")).GetPointsAttr().Get(2))
    np.testing.assert_allclose(pts, scarf.points + 0.02, atol=1e-6)


DEV_PAIRS = [("ref_female_longskirt", "body_female_heavy"), ("ref_female", "body_female_thin"),
             ("ref_male", "body_male_heavy")]


@pytest.mark.slow
@pytest.mark.parametrize("ref,target", DEV_PAIRS)
def test_dev_references_lose_nothing_in_dress_and_animate(tmp_path, data_dir, ref, target):
    """Every material, binding, primvar and attribute of the dev references'
    items (and of the target body) is in the `dress` and `animate` outputs,
    copied and referenced."""
    from wearfit_usd.cli import main
    usd = data_dir / "usd"
    src, tgt = usd / f"{ref}.usda", usd / f"{target}.usdc"
    outs = []
    for extra in ([], ["--reference-inputs"]):
        d = tmp_path / f"dress{len(extra)}.usdc"
        assert main(["dress", "-q", str(src), str(tgt), "-o", str(d), *extra]) == 0
        a = tmp_path / f"anim{len(extra)}.usdc"
        assert main(["animate", "-q", str(src), str(tgt), str(data_dir / "bvh" / "cmu_07_01_walk.bvh"),
                     "--start", "1", "--end", "9", "-o", str(a), *extra]) == 0
        outs += [d, a]
    st = pxr.Usd.Stage.Open(str(src))
    n_items = sum(1 for p in st.Traverse() if p.IsA(pxr.UsdGeom.Mesh)) - 1
    for out in outs:
        assert check_carried(src, out) == [], out
        body = {"/root/Skeleton/Body/Body": "/Root/Character/Body"}
        assert check_carried(tgt, out, body, points_changed=False) == [], out
        o = pxr.Usd.Stage.Open(str(out))
        assert len(pxr.UsdGeom.Subset.GetAllGeomSubsets(
            pxr.UsdGeom.Imageable(o.GetPrimAtPath("/Root/Character/Body")))) >= 1
        assert len(o.GetPrimAtPath("/Root/Items").GetChildren()) == n_items
