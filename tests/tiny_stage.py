"""A tiny rigged USD stage (a 2-joint skeleton, an 8-vertex box body and a
one-quad item) as text, for tests that need a stage but not the data set:
bad-input cases are made by replacing one piece of it."""
from __future__ import annotations

from pathlib import Path

#: a box body (0.4 x 2 x 0.2 m) skinned to hips/spine, Y up, metres, with an item "Scarf"
TINY_USDA = """#usda 1.0
(
    defaultPrim = "Root"
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "Root"
{
    def SkelRoot "Character"
    {
        def Skeleton "Skeleton"
        {
            uniform token[] joints = ["hips", "hips/spine"]
            uniform matrix4d[] bindTransforms = [( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 1, 0, 1) ), ( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 1.5, 0, 1) )]
            uniform matrix4d[] restTransforms = [( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 1, 0, 1) ), ( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0.5, 0, 1) )]
        }

        def Mesh "Body" (
            prepend apiSchemas = ["SkelBindingAPI"]
        )
        {
            int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
            int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 7, 6, 6, 7, 5, 4, 4, 5, 1, 0, 2, 6, 4, 0, 7, 3, 1, 5]
            point3f[] points = [(-0.2, 0, 0.1), (0.2, 0, 0.1), (-0.2, 2, 0.1), (0.2, 2, 0.1), (-0.2, 0, -0.1), (0.2, 0, -0.1), (-0.2, 2, -0.1), (0.2, 2, -0.1)]
            int[] primvars:skel:jointIndices = [0, 0, 1, 1, 0, 0, 1, 1] (
                elementSize = 1
                interpolation = "vertex"
            )
            float[] primvars:skel:jointWeights = [1, 1, 1, 1, 1, 1, 1, 1] (
                elementSize = 1
                interpolation = "vertex"
            )
            rel skel:skeleton = </Root/Character/Skeleton>
        }
    }

    def Mesh "Scarf"
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-0.25, 1.5, 0.15), (0.25, 1.5, 0.15), (0.25, 1.7, 0.15), (-0.25, 1.7, 0.15)]
    }
}
"""

#: the item's face lists and points, as written in :data:`TINY_USDA`
ITEM_FACES = "int[] faceVertexCounts = [4]\n        int[] faceVertexIndices = [0, 1, 2, 3]"
ITEM_POINTS = "[(-0.25, 1.5, 0.15), (0.25, 1.5, 0.15), (0.25, 1.7, 0.15), (-0.25, 1.7, 0.15)]"


def write_tiny(path, old: str | None = None, new: str | None = None) -> Path:
    """Write :data:`TINY_USDA` to ``path``, with ``old`` replaced by ``new``
    (``old`` must occur in it)."""
    text = TINY_USDA
    if old is not None:
        assert old in text, old
        text = text.replace(old, new)
    path = Path(path)
    path.write_text(text)
    return path


#: the tiny skeleton's joints paired with the packaged clips' (a 2-joint
#: skeleton has no legs or arms for the role matcher: the user's map pairs it)
TINY_MAP = '{"hips": "Hips", "spine": "Spine"}'


def write_tiny_map(folder) -> Path:
    """Write :data:`TINY_MAP` to ``folder/tiny_map.json``; returns its path."""
    path = Path(folder) / "tiny_map.json"
    path.write_text(TINY_MAP)
    return path
