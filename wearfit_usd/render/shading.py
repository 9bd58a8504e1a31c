"""A light preview shader for pyrender, plugged in through its program cache.

pyrender 0.1.45 draws every lit mesh with ``mesh.vert``/``mesh.frag``, a
physically based metallic-roughness shader (Fresnel, Smith geometry term, GGX
distribution per light and fragment). Under llvmpipe that fragment shader is
most of the frame: ~40 of ~75 ms for a dressed 51k-triangle character at
640x480 (a flat-colour pass takes ~21 ms, depth only ~25 ms).

:class:`PreviewProgramCache` replaces pyrender's ``ShaderProgramCache`` on one
renderer. For the ``mesh.vert``/``mesh.frag`` pair it returns a
:class:`PreviewProgram` compiled from the GLSL below; every other program
(flat, depth, segmentation, normals, text) still comes from pyrender's files.
The preview shader reads the same uniforms pyrender already sets
(``M V P cam_pos ambient_light n_directional_lights directional_lights[i]
material.base_color_factor``) and the same vertex layout (pyrender's
``*_LOC`` defines), so nothing else in pyrender changes.

Lighting model (linear colour, written gamma 2.2 like pyrender's):

* ambient: a hemisphere term, ``ambient_light`` times a sky/ground blend on
  the world +Y normal component (upward faces a little brighter);
* each directional light: wrapped Lambert diffuse ``max((n.l + w) / (1 + w), 0)``
  (softer terminator than plain Lambert), scaled by ``intensity / pi`` like
  pyrender's PBR diffuse so the light rig keeps its brightness, plus a weak
  Blinn-Phong highlight;
* double-sided meshes: the normal is flipped on back faces, so the inside
  of a hat brim or a sleeve is lit instead of black;
* per-vertex colours (pyrender's ``COLOR_0``) multiply the base colour
  (heatmaps).

``make_cache(..., lighting="fragment")`` (what :class:`~.offscreen.Renderer`
uses) evaluates it per fragment; ``lighting="vertex"`` evaluates it per vertex
(Gouraud, a front and a back colour) and only interpolates: about 10% faster
on ref_male (22 vs 25 ms/frame), nearly the same picture at these triangle
densities, but highlights follow the mesh. Measured on ref_male, 640x480,
OSMesa: 26 ms/frame static with this shader, 45 ms with pyrender's PBR shader
(both with the fixed cache), 75 ms with pyrender's stock cache
(``benchmarks/bench_render.py --full``).
"""
from __future__ import annotations

import os
import re

# ---------------------------------------------------------------------------
# GLSL. The light loop and the material are shared by both variants; the
# variant is chosen with the PER_VERTEX define.

_MATERIAL = r"""
struct Material {
    vec3 emissive_factor;
    vec4 base_color_factor;
    float metallic_factor;
    float roughness_factor;
};
uniform Material material;
"""

_COMMON = r"""
struct DirectionalLight {
    vec3 color;
    float intensity;
    vec3 direction;
};
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform int n_directional_lights;
uniform vec3 ambient_light;
uniform vec3 cam_pos;

const float INV_PI = 0.3183098861837907;
const float WRAP = 0.25;          // wrapped diffuse: softer terminator
const float SPEC = 0.06;          // highlight strength (relative to intensity / pi)
const float SHININESS = 24.0;     // Blinn-Phong exponent
const vec3 SKY = vec3(1.12);      // hemisphere ambient: up-facing
const vec3 GROUND = vec3(0.80);   //                     down-facing

// n: unit normal facing the viewer, v: unit vector to the camera, albedo linear.
vec3 shade(vec3 n, vec3 v, vec3 albedo)
{
    vec3 diffuse = ambient_light * mix(GROUND, SKY, 0.5 + 0.5 * n.y);
    vec3 spec = vec3(0.0);
    for (int i = 0; i < n_directional_lights; i++) {
        vec3 l = -directional_lights[i].direction;
        vec3 radiance = directional_lights[i].intensity * INV_PI * directional_lights[i].color;
        float nl = dot(n, l);
        diffuse += radiance * max((nl + WRAP) * (1.0 / (1.0 + WRAP)), 0.0);
        if (nl > 0.0) {
            float nh = max(dot(n, normalize(l + v)), 0.0);
            spec += radiance * (SPEC * pow(nh, SHININESS));
        }
    }
    return albedo * diffuse + spec;
}
"""

_VERT = r"""#version 330 core
layout(location = 0) in vec3 position;
#ifdef NORMAL_LOC
layout(location = NORMAL_LOC) in vec3 normal;
#endif
#ifdef COLOR_0_LOC
layout(location = COLOR_0_LOC) in vec4 color_0;
#endif
layout(location = INST_M_LOC) in mat4 inst_m;

uniform mat4 M;
uniform mat4 V;
uniform mat4 P;
@MATERIAL@
#ifdef PER_VERTEX
@COMMON@
out vec3 v_front;   // colour lit from the normal's side
out vec3 v_back;    // colour lit from the other side (seen on back faces)
#else
out vec3 frag_position;
out vec3 frag_normal;
out vec4 v_color;
#endif

void main()
{
    // rigid/uniformly scaled models only (pyrender node poses here are
    // identity): mat3(model) transforms normals up to a scale, renormalised.
    mat4 model = M * inst_m;
    vec4 world = model * vec4(position, 1.0);
    gl_Position = P * (V * world);
#ifdef NORMAL_LOC
    vec3 n = normalize(mat3(model) * normal);
#else
    vec3 n = vec3(0.0, 1.0, 0.0);
#endif
    vec4 base = material.base_color_factor;
#ifdef COLOR_0_LOC
    base *= color_0;
#endif
#ifdef PER_VERTEX
    vec3 v = normalize(cam_pos - world.xyz);
    v_front = shade(n, v, base.rgb);
    v_back = shade(-n, v, base.rgb);
#else
    frag_position = world.xyz;
    frag_normal = n;
    v_color = base;
#endif
}
"""

_FRAG = r"""#version 330 core
#ifdef PER_VERTEX
in vec3 v_front;
in vec3 v_back;
#else
@COMMON@
in vec3 frag_position;
in vec3 frag_normal;
in vec4 v_color;
#endif
out vec4 frag_color;

void main()
{
#ifdef PER_VERTEX
    vec3 c = gl_FrontFacing ? v_front : v_back;
#else
    vec3 n = normalize(frag_normal);
    if (!gl_FrontFacing) n = -n;
    vec3 c = shade(n, normalize(cam_pos - frag_position), v_color.rgb);
#endif
    frag_color = vec4(pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)), 1.0);
}
"""

def _source(template: str, defines: dict) -> str:
    """Insert the shared code, resolve ``#ifdef NAME`` / ``#ifndef NAME``
    against ``defines`` (as pyrender's loader does, so its ``*_LOC`` values
    slot in) and substitute define values."""
    text = template.replace("@MATERIAL@", _MATERIAL).replace("@COMMON@", _COMMON)
    text = re.sub(r"#ifdef\s+([A-Za-z_]\w*)\s*$",
                  lambda m: "#if 1" if m.group(1) in defines else "#if 0", text, flags=re.M)
    text = re.sub(r"#ifndef\s+([A-Za-z_]\w*)\s*$",
                  lambda m: "#if 0" if m.group(1) in defines else "#if 1", text, flags=re.M)
    for name in sorted(defines, key=len, reverse=True):
        text = re.sub(r"\b" + name + r"\b", str(defines[name]), text)
    return text


def vertex_source(defines: dict) -> str:
    return _source(_VERT, defines)


def fragment_source(defines: dict) -> str:
    return _source(_FRAG, defines)


SHADINGS = ("preview", "pbr")
LIGHTING_MODES = ("vertex", "fragment")


def make_cache(pyrender_module, shading: str = "preview", lighting: str = "vertex"):
    """A ``ShaderProgramCache`` for one pyrender renderer that serves the
    preview shader instead of ``mesh.vert``/``mesh.frag`` (``shading="pbr"``:
    pyrender's own shaders, only the cache fixed)."""
    if shading not in SHADINGS:
        raise ValueError(f"shading must be one of {SHADINGS}, got {shading!r}")
    if lighting not in LIGHTING_MODES:
        raise ValueError(f"lighting must be one of {LIGHTING_MODES}, got {lighting!r}")
    sp = pyrender_module.shader_program
    from OpenGL.GL import GL_FRAGMENT_SHADER, GL_VERTEX_SHADER, glBindVertexArray, glGenVertexArrays
    from OpenGL.GL import shaders as glsl

    class PreviewProgram(sp.ShaderProgram):
        """pyrender ShaderProgram compiled from in-memory GLSL."""

        def __init__(self, defines):
            super().__init__(vertex_shader="<preview>.vert", fragment_shader="<preview>.frag",
                             defines=defines)

        def _add_to_context(self):
            if self._program_id is not None:
                raise ValueError("Shader program already in context")
            vs = glsl.compileShader(vertex_source(self.defines), GL_VERTEX_SHADER)
            fs = glsl.compileShader(fragment_source(self.defines), GL_FRAGMENT_SHADER)
            if self._vao_id is None:  # pyrender binds an empty VAO while linking
                self._vao_id = glGenVertexArrays(1)
            glBindVertexArray(self._vao_id)
            self._program_id = glsl.compileProgram(vs, fs)
            glBindVertexArray(0)

    class PreviewProgramCache(sp.ShaderProgramCache):
        """One cache per pyrender renderer, i.e. per GL context: keyed on the
        shader names and defines only. (pyrender's own key also holds
        ``OpenGL.contextdata.getContext()``, which under OSMesa is a new
        pointer object on every call, so its cache never hits there and every
        draw compiled and linked its program again.)"""

        def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
            defines = dict(defines or {})
            preview = (vertex_shader == "mesh.vert" and fragment_shader == "mesh.frag"
                       and not geometry_shader and shading == "preview"
                       and "USE_METALLIC_MATERIAL" in defines
                       and not any(k.startswith("HAS_") and k.endswith("_TEX") for k in defines)
                       and not any(k.endswith("_SHADOWS") for k in defines))
            # textures, shadows, glossy materials: not used by previews; pyrender's shader
            if preview and lighting == "vertex":
                defines["PER_VERTEX"] = 1
            key = (preview, vertex_shader, fragment_shader, geometry_shader,
                   tuple(sorted(defines.items())))
            prog = self._program_cache.get(key)
            if prog is None:
                if preview:
                    prog = PreviewProgram(defines)
                else:
                    files = [None if f is None else os.path.join(self.shader_dir, f)
                             for f in (vertex_shader, fragment_shader, geometry_shader)]
                    prog = sp.ShaderProgram(*files, defines=defines)
                self._program_cache[key] = prog
            return prog

    return PreviewProgramCache()
