"""glTF in (io.gltf) and out (io.gltf_write, `wearfit export`): known answers
on a synthetic skin, the third-party figures against their Blender USD forms,
the Khronos validator and the round trip on demo scenes."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tests.conftest import DATA, REPO
from wearfit_usd.cli import main
from wearfit_usd.errors import InputError
from wearfit_usd.io.gltf import read_gltf_character, read_gltf_frames
from wearfit_usd.io.usd import read_character
from wearfit_usd.transforms import axis_rotation

pygltflib = pytest.importorskip("pygltflib")  # a required dependency: present wherever the package is installed

BODIES = DATA / "thirdparty" / "bodies"
VALIDATOR = REPO / ".tools" / "node_modules" / "gltf-validator"


# --------------------------------------------------------------------------
# a synthetic 2-joint skin with known answers

def _two_joint_glb(path: Path, bad_joint: bool = False, eight: bool = False) -> Path:
    """Joints: root at the origin, child 1 m up (bind pose: IBMs); the nodes
    hold the child turned 90 degrees about +Z. Skin order child-first (the
    reader must put parents first). Vertices (bind pose):
    0 (0, 1.5, 0) on the child; 1 (0.2, 0, 0) on the root; 2 (0, 1, 0.3)
    half/half; 3 (0.1, 1.2, 0.1) on the child."""
    pts = np.array([[0, 1.5, 0], [0.2, 0, 0], [0, 1, 0.3], [0.1, 1.2, 0.1]], dtype=np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3, 1, 3, 2], dtype=np.uint16)
    # skin joints: [child node 1, root node 0]: JOINTS_0 index 0 = child, 1 = root
    j = np.array([[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0]], dtype=np.uint16)
    w = np.array([[1, 0, 0, 0], [1, 0, 0, 0], [0.5, 0.5, 0, 0], [1, 0, 0, 0]], dtype=np.float32)
    if bad_joint:
        j[3, 0] = 5
    uv = np.array([[0, 0], [1, 0], [0, 1], [0.25, 0.75]], dtype=np.float32)
    ibm = np.stack([np.eye(4), np.eye(4)]).astype(np.float32)
    ibm[0, 3, 1] = -1.0  # child: inverse of "1 m up" (row-vector layout = glTF column-major)
    arrays = [(pts, "VEC3", 5126, True), (idx[:, None], "SCALAR", 5123, False), (j, "VEC4", 5123, False),
              (w, "VEC4", 5126, False), (uv, "VEC2", 5126, False), (ibm.reshape(2, 16), "MAT4", 5126, False)]
    if eight:  # a second influence set: vertex 3 split over both joints in JOINTS_1
        w8 = w.copy()
        w8[3] = [0.25, 0, 0, 0]
        arrays[3] = (w8, "VEC4", 5126, False)
        arrays += [(np.array([[0, 0, 0, 0]] * 3 + [[1, 0, 0, 0]], dtype=np.uint16), "VEC4", 5123, False),
                   (np.array([[0, 0, 0, 0]] * 3 + [[0.75, 0, 0, 0]], dtype=np.float32), "VEC4", 5126, False)]
    blob = bytearray()
    views, accs = [], []
    for arr, typ, comp, mm in arrays:
        off = len(blob)
        blob += arr.tobytes()
        blob += b"\0" * ((-len(blob)) % 4)
        views.append(pygltflib.BufferView(buffer=0, byteOffset=off, byteLength=arr.nbytes))
        acc = pygltflib.Accessor(bufferView=len(views) - 1, componentType=comp, count=len(arr), type=typ)
        if mm:
            acc.min, acc.max = arr.min(0).tolist(), arr.max(0).tolist()
        accs.append(acc)
    attrs = pygltflib.Attributes(POSITION=0, JOINTS_0=2, WEIGHTS_0=3, TEXCOORD_0=4)
    if eight:
        attrs.JOINTS_1, attrs.WEIGHTS_1 = 6, 7
    s = np.sin(np.pi / 4)
    g = pygltflib.GLTF2(
        scenes=[pygltflib.Scene(nodes=[0, 2])], scene=0,
        nodes=[pygltflib.Node(name="hips", children=[1]),
               pygltflib.Node(name="spine.001", translation=[0, 1, 0], rotation=[0, 0, s, s]),
               pygltflib.Node(name="body", mesh=0, skin=0)],
        meshes=[pygltflib.Mesh(primitives=[pygltflib.Primitive(attributes=attrs, indices=1, material=0)])],
        materials=[pygltflib.Material(pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
            baseColorFactor=[0.2, 0.4, 0.6, 1.0]))],
        skins=[pygltflib.Skin(joints=[1, 0], inverseBindMatrices=5)],
        accessors=accs, bufferViews=views, buffers=[pygltflib.Buffer(byteLength=len(blob))])
    g.set_binary_blob(bytes(blob))
    g.save_binary(str(path))
    return path


def test_two_joint_skin_known_answers(tmp_path):
    f = _two_joint_glb(tmp_path / "two.glb")
    bind = read_gltf_character(f, pose="bind")
    sk = bind.skeleton
    assert sk.joint_names == ["hips", "spine_001"] and list(sk.parents) == [-1, 0]
    assert sk.joint_paths == ["hips", "hips/spine_001"]
    np.testing.assert_allclose(sk.bind_positions(), [[0, 0, 0], [0, 1, 0]], atol=1e-7)
    np.testing.assert_allclose(bind.body.points[0], [0, 1.5, 0], atol=1e-7)
    # joint indices remapped to the parents-first order: child is now 1
    assert bind.body.joint_indices[0, 0] == 1 and bind.body.joint_indices[1, 0] == 0
    np.testing.assert_allclose(bind.body.display_color, [0.2, 0.4, 0.6], atol=1e-6)
    st = next(p for p in bind.body.primvars if p.name == "st").values
    np.testing.assert_allclose(st[3], [0.25, 0.25], atol=1e-7)  # V flipped to USD's origin

    nodes = read_gltf_character(f, pose="nodes")
    rot = axis_rotation(2, np.pi / 2)  # row-vector 90 degrees about +Z: (0, 0.5, 0) -> (-0.5, 0, 0)
    expect0 = np.array([0, 0.5, 0]) @ rot + [0, 1, 0]
    expect2 = 0.5 * (np.array([0, 0, 0.3]) @ rot + [0, 1, 0]) + 0.5 * np.array([0, 1, 0.3])
    np.testing.assert_allclose(nodes.body.points[0], expect0, atol=1e-6)
    np.testing.assert_allclose(nodes.body.points[1], [0.2, 0, 0], atol=1e-7)
    np.testing.assert_allclose(nodes.body.points[2], expect2, atol=1e-6)
    np.testing.assert_allclose(expect0, [-0.5, 1, 0], atol=1e-9)
    # the skeleton's bind pose is the chosen pose: skinning at rest gives the points back
    from wearfit_usd.motion.skinning import skin_mesh
    np.testing.assert_allclose(skin_mesh(nodes.body, nodes.skeleton, nodes.skeleton.rest_world()),
                               nodes.body.points, atol=1e-9)


def test_gltf_json_with_embedded_buffer(tmp_path):
    g = pygltflib.GLTF2().load(str(_two_joint_glb(tmp_path / "two.glb")))
    g.convert_buffers(pygltflib.BufferFormat.DATAURI)
    g.save_json(str(tmp_path / "two.gltf"))
    a = read_character(tmp_path / "two.gltf")
    b = read_character(tmp_path / "two.glb")
    assert np.array_equal(a.body.points, b.body.points) and a.skeleton.joint_names == b.skeleton.joint_names


def test_second_influence_set(tmp_path):
    c = read_gltf_character(_two_joint_glb(tmp_path / "eight.glb", eight=True), pose="nodes")
    assert c.body.joint_weights.shape[1] == 8
    p_child = np.array([0.1, 0.2, 0.1]) @ axis_rotation(2, np.pi / 2) + [0, 1, 0]
    np.testing.assert_allclose(c.body.points[3], 0.25 * p_child + 0.75 * np.array([0.1, 1.2, 0.1]), atol=1e-6)


def test_bad_gltf_inputs(tmp_path):
    with pytest.raises(InputError, match="reference joint 5"):
        read_gltf_character(_two_joint_glb(tmp_path / "bad.glb", bad_joint=True), pose="bind")
    junk = tmp_path / "junk.glb"
    junk.write_bytes(b"not a gltf at all")
    with pytest.raises(InputError, match="cannot read as glTF"):
        read_character(junk)
    with pytest.raises(InputError, match="file not found"):
        read_character(tmp_path / "missing.glb")
    with pytest.raises(InputError, match="no animation named"):
        read_gltf_character(_two_joint_glb(tmp_path / "two.glb"), pose="walk")


# --------------------------------------------------------------------------
# third-party figures against their Blender USD forms

@pytest.mark.parametrize("glb, usdc, pose", [
    ("RiggedFigure.glb", "RiggedFigure_blender.usdc", None),
    ("mannequiny-0.3.0.glb", "mannequiny_idle_blender.usdc", None),   # auto must pick the idle frame
    ("mannequiny-0.3.0.glb", "mannequiny_idle_blender.usdc", "idle"),
])
def test_third_party_glb_equals_blender_usd(glb, usdc, pose):
    c = read_gltf_character(BODIES / glb, pose=pose)
    u = read_character(BODIES / usdc)
    assert c.skeleton.n_joints == u.skeleton.n_joints
    assert sorted(c.skeleton.joint_names) == sorted(u.skeleton.joint_names)
    assert c.body.n_points == u.body.n_points
    assert np.abs(c.body.points - u.body.points).max() < 1e-5  # metres; same vertex order
    idx = [u.skeleton.joint_names.index(n) for n in c.skeleton.joint_names]
    assert np.abs(c.skeleton.bind_positions() - u.skeleton.bind_positions()[idx]).max() < 1e-5


def test_splayed_bind_pose_options():
    bind = read_gltf_character(BODIES / "mannequiny-0.3.0.glb", pose="bind")
    idle = read_gltf_character(BODIES / "mannequiny-0.3.0.glb", pose="idle")
    # the IBMs hold a T-pose: hands far apart; the idle frame has them down at the sides
    sk = bind.skeleton
    span = lambda c: abs(c.skeleton.bind_positions()[c.skeleton.index("hand_l"), 0]  # noqa: E731
                         - c.skeleton.bind_positions()[c.skeleton.index("hand_r"), 0])
    assert span(bind) > 1.2 and span(idle) < 0.8 and sk.n_joints == 45


# --------------------------------------------------------------------------
# export: bad input

def test_export_bad_input(tmp_path, capsys):
    out = tmp_path / "x.glb"
    assert main(["export", str(tmp_path / "missing.usda"), "-o", str(out)]) == 2
    from tests.tiny_stage import TINY_USDA
    plain = tmp_path / "plain.usda"  # a rigged stage, but not a wearfit scene layout
    plain.write_text(TINY_USDA.replace('"Root"', '"Scene"').replace("</Root/", "</Scene/"))
    assert main(["export", str(plain), "-o", str(out)]) == 2
    assert "not a wearfit scene" in capsys.readouterr().err
    assert main(["export", str(plain), "-o", str(tmp_path / "x.usda")]) == 2
    same = tmp_path / "same.glb"
    same.write_bytes(b"x")
    assert main(["export", str(same), "-o", str(same)]) == 2 and same.read_bytes() == b"x"
    assert not out.exists() and not list(tmp_path.glob(".x.*"))


# --------------------------------------------------------------------------
# export of demo scenes: validator, round trip, render

def _validate(glb: Path) -> dict:
    script = ("const fs=require('fs');const v=require(process.argv[1]);"
              "v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])))"
              ".then(r=>console.log(JSON.stringify(r.issues)))")
    res = subprocess.run(["node", "-e", script, str(VALIDATOR), str(glb)], capture_output=True, text=True,
                         timeout=300, check=True)
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def demo_scenes(tmp_path_factory):
    from wearfit_usd.demo.samples import motion_path, write_sample_set
    d = tmp_path_factory.mktemp("gltf_demo")
    s = write_sample_set(d / "samples", targets=["short_heavy"], garment_sets=[])
    dressed, shot, lbs = d / "dressed.usda", d / "walk.usdc", d / "walk_lbs.usdc"
    ref, tgt, walk = str(s["reference"]), str(s["target_short_heavy"]), str(motion_path("walk"))
    assert main(["dress", ref, tgt, "-o", str(dressed), "-q"]) == 0
    assert main(["animate", ref, tgt, walk, "--end", "9", "-o", str(shot), "-q"]) == 0
    # items both as point caches and as skinned meshes: exported once each, skinned
    assert main(["animate", ref, tgt, walk, "--end", "9", "--mode", "lbs", "--write-skinned-items",
                 "-o", str(lbs), "-q"]) == 0
    return dressed, shot, lbs


def test_skinned_items_exported_skinned_once(demo_scenes, tmp_path):
    glb = tmp_path / "lbs.glb"
    assert main(["export", str(demo_scenes[2]), "-o", str(glb), "-q"]) == 0
    g = pygltflib.GLTF2().load(str(glb))
    usd = read_character(demo_scenes[2], skinned_copies=True)
    skinned = {m.name for m in usd.items if m.is_skinned}
    assert skinned and all(n.endswith("_skinned") for n in skinned)
    names = [m.name for m in g.meshes]
    # each item once, skinned, under its own name
    assert len(names) == len(set(names)) == 1 + len(skinned)
    assert set(names) == {"Body"} | {n[:-len("_skinned")] for n in skinned}
    assert all(n.skin == 0 for n in g.nodes if n.mesh is not None)
    assert not any(p.targets for m in g.meshes for p in m.primitives)


@pytest.mark.slow
@pytest.mark.parametrize("which", [0, 1], ids=["dressed", "walk"])
def test_export_validates_and_round_trips(demo_scenes, tmp_path, which):
    from wearfit_usd.render.scene import read_scene
    scene = demo_scenes[which]
    glb = tmp_path / "character.glb"
    assert main(["export", str(scene), "-o", str(glb), "-q"]) == 0
    if shutil.which("node") and VALIDATOR.exists():
        issues = _validate(glb)
        assert issues["numErrors"] == 0, issues["messages"][:5]
    usd, back = read_character(scene), read_character(glb)
    assert back.skeleton.joint_names == usd.skeleton.joint_names
    assert np.abs(back.skeleton.bind_world - usd.skeleton.bind_world).max() < 1e-5
    assert np.abs(back.body.points - usd.body.points).max() < 1e-6
    assert sorted(m.name for m in back.items) == sorted(m.name for m in usd.items)
    # every frame of every mesh as the toolkit's USD scene reader poses it (UsdSkel, point caches)
    sc = read_scene(scene)
    char, frames, fps, n = read_gltf_frames(glb)
    assert n == len(sc.times)
    by_name = {m.name: k for k, m in enumerate([char.body] + char.items)}
    # an item written both ways (`dress`) is exported skinned: its skinned
    # copy's own rest points (fitted to example poses, animate.skin_fit),
    # not the point copy the scene reader shows
    copies = {m.name[:-len("_skinned")]: m.points for m in read_character(scene, skinned_copies=True).items
              if m.name.endswith("_skinned")}
    for m in sc.meshes:
        k = by_name[m.name]
        for f in range(n):
            want = m.frames[f]
            if m.name in copies:
                assert n == 1
                want = copies[m.name]
            d, _ = cKDTree(frames[k][f]).query(want)
            assert d.max() < 1e-5, (m.name, f, d.max())


def test_export_materials_and_texture(tmp_path):
    """baseColor from the UsdPreviewSurface's diffuseColor; a diffuseColor read
    from a UsdUVTexture file is embedded as the baseColorTexture; face-varying
    UVs split vertices on their seams."""
    from PIL import Image
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    from tests.tiny_stage import write_tiny
    scene = write_tiny(tmp_path / "tiny.usda")
    Image.new("RGB", (4, 4), (200, 30, 30)).save(tmp_path / "red.png")
    stage = Usd.Stage.Open(str(scene))
    scarf = stage.GetPrimAtPath("/Root/Scarf")
    n_corners = len(UsdGeom.Mesh(scarf).GetFaceVertexIndicesAttr().Get())
    st = UsdGeom.PrimvarsAPI(scarf).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                  UsdGeom.Tokens.faceVarying)
    st.Set([(i / n_corners, 0.5) for i in range(n_corners)])
    for name, prim, tex in (("Skin", stage.GetPrimAtPath("/Root/Character/Body"), None), ("Cloth", scarf, "red.png")):
        mat = UsdShade.Material.Define(stage, f"/Root/Looks/{name}")
        surf = UsdShade.Shader.Define(stage, f"/Root/Looks/{name}/Surface")
        surf.CreateIdAttr("UsdPreviewSurface")
        col = surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
        if tex:
            t = UsdShade.Shader.Define(stage, f"/Root/Looks/{name}/Tex")
            t.CreateIdAttr("UsdUVTexture")
            t.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(tex)
            col.ConnectToSource(t.ConnectableAPI(), "rgb")
        else:
            col.Set((0.1, 0.5, 0.9))
        surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.3)
        mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)
    stage.GetRootLayer().Save()
    glb = tmp_path / "tiny.glb"
    assert main(["export", str(scene), "-o", str(glb), "-q"]) == 0
    g = pygltflib.GLTF2().load(str(glb))
    mats = {m.name: m.pbrMetallicRoughness for m in g.materials}
    np.testing.assert_allclose(mats["Skin"].baseColorFactor, [0.1, 0.5, 0.9, 1.0], atol=1e-6)
    assert mats["Skin"].roughnessFactor == pytest.approx(0.3) and mats["Skin"].baseColorTexture is None
    assert mats["Cloth"].baseColorTexture is not None and len(g.images) == 1
    assert g.images[0].mimeType == "image/png"
    scarf_mesh = next(m for m in g.meshes if m.name == "Scarf")
    assert g.accessors[scarf_mesh.primitives[0].attributes.POSITION].count == n_corners  # every corner its UV
    if shutil.which("node") and VALIDATOR.exists():
        assert _validate(glb)["numErrors"] == 0
    back = read_character(glb)
    np.testing.assert_allclose(back.body.display_color, [0.1, 0.5, 0.9], atol=1e-6)


def test_export_one_primitive_per_subset_material(tmp_path):
    """A mesh whose GeomSubsets (familyName materialBind) bind materials of
    their own is written as one primitive per material over the same
    vertices: every triangle once, each with its subset's baseColor; the
    faces in no subset keep the mesh's material. Valid glTF; read back with
    the same geometry."""
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    from tests.tiny_stage import write_tiny
    scene = write_tiny(tmp_path / "tiny.usda")
    stage = Usd.Stage.Open(str(scene))
    body = stage.GetPrimAtPath("/Root/Character/Body")
    n_faces = len(UsdGeom.Mesh(body).GetFaceVertexCountsAttr().Get())
    assert n_faces >= 3

    def material(name, rgb):
        mat = UsdShade.Material.Define(stage, f"/Root/Looks/{name}")
        surf = UsdShade.Shader.Define(stage, f"/Root/Looks/{name}/Surface")
        surf.CreateIdAttr("UsdPreviewSurface")
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(rgb)
        mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
        return mat

    UsdShade.MaterialBindingAPI.Apply(body).Bind(material("Skin", (0.9, 0.7, 0.6)))
    bind = UsdShade.MaterialBindingAPI(body)
    for name, rgb, faces in (("Red", (1.0, 0.0, 0.0), [0]), ("Blue", (0.0, 0.0, 1.0), [1, 2])):
        sub = bind.CreateMaterialBindSubset(name, faces, UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(sub.GetPrim()).Bind(material(name, rgb))
    stage.GetRootLayer().Save()
    glb = tmp_path / "subsets.glb"
    assert main(["export", str(scene), "-o", str(glb), "-q"]) == 0
    g = pygltflib.GLTF2().load(str(glb))
    gm = next(m for m in g.meshes if m.name == "Body")
    colours = {g.materials[p.material].name: p for p in gm.primitives}
    assert set(colours) == {"Red", "Blue", "Skin"}
    assert len({p.attributes.POSITION for p in gm.primitives}) == 1  # one vertex set
    base = {g.materials[p.material].name: g.materials[p.material].pbrMetallicRoughness.baseColorFactor
            for p in gm.primitives}
    np.testing.assert_allclose(base["Red"], [1, 0, 0, 1])
    np.testing.assert_allclose(base["Blue"], [0, 0, 1, 1])
    src = read_character(scene)
    n_tris = {k: g.accessors[p.indices].count // 3 for k, p in colours.items()}
    assert sum(n_tris.values()) == len(src.body.faces)
    per_poly = np.bincount(src.body.tri_to_poly, minlength=n_faces)
    assert n_tris["Red"] == per_poly[0] and n_tris["Blue"] == per_poly[1] + per_poly[2]
    if shutil.which("node") and VALIDATOR.exists():
        assert _validate(glb)["numErrors"] == 0
    back = read_character(glb)
    assert len(back.body.faces) == len(src.body.faces)
    np.testing.assert_allclose(np.sort(back.body.points, axis=0), np.sort(src.body.points, axis=0), atol=1e-5)
