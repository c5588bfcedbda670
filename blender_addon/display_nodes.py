"""The node trees behind :mod:`.display` (what they compute is described there).

Geometry Nodes group, per splat: (1) the direction ``d`` from the *Active Camera* in the
object's own frame (only in the view-dependent group; the fixed-colour variant has no camera
node, so a change of scene camera does not re-evaluate it); (2) the colour — ``divas_color``
or, view-dependent, the SH colour from the ``divas_sh_k`` codes, clamped at 0 like the
engine, selected points tinted — stored as ``divas_shade`` on a clean point cloud; (3) splats:
a quad instanced per point above the opacity threshold, realised, ``divas_shade`` copied to
its active colour attribute. The steps in full: docs/design-notes.md.
"""

from __future__ import annotations

from divas_engine.point_attributes import COLOR, ROTATION, SCALE, SELECTED, sh_attribute_name
from divas_engine.sh_rotation import SH_MONOMIALS

from .node_builder import NodeBuilder

__all__ = [
    "QUAD_UV",
    "DISPLAY_COLOR",
    "SHADE",
    "BLEND_FLAG",
    "srgb_encode",
    "build_display_group",
    "build_splat_material",
    "build_points_material",
]

QUAD_UV = "divas_quad_uv"
DISPLAY_COLOR = "divas_display"
SHADE = "divas_shade"
#: scene property (a BoolProperty registered by :mod:`.blend_space`) the materials read
#: through an Attribute node of type View Layer: set, they emit the display-encoded colour.
BLEND_FLAG = "divas_blend_display"
_SRGB_LIN_KNEE = 0.04045  # sRGB-encoded value where the curve's linear toe ends
_LIN_SRGB_KNEE = 0.0031308  # the same point in linear


def _interface(ng) -> None:
    def add(name, socket_type, default=None, lo=None, hi=None, desc=""):
        s = ng.interface.new_socket(name, in_out="INPUT", socket_type=socket_type)
        if default is not None:
            s.default_value = default
        if lo is not None:
            s.min_value, s.max_value = lo, hi
        s.description = desc
        return s

    add("Geometry", "NodeSocketGeometry")
    add("Points", "NodeSocketBool", False, desc="Fast point display instead of splat quads")
    add("Size", "NodeSocketFloat", 1.0, 0.01, 100.0, "Multiplies every splat's σ")
    add(
        "Opacity Threshold",
        "NodeSocketFloat",
        1.0 / 255.0,
        0.0,
        1.0,
        "Hide splats whose opacity is below this",
    )
    add(
        "View-Dependent Colour",
        "NodeSocketBool",
        True,
        desc="Spherical-harmonic colour as seen from the scene camera",
    )
    add("SH Range", "NodeSocketVector", (0.0, 0.0, 0.0), desc="Per-band range of divas_sh_*")
    add("Max Radius", "NodeSocketFloat", 0.0, 0.0, 1e9, "Point radius clip (0: none)")
    add(
        "Viewport Colours",
        "NodeSocketBool",
        True,
        desc="Evaluate the view-dependent colour of the point display in the viewport too "
        "(the add-on sets it: on while a 3D view shows material colours; renders always do)",
    )
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")


def _named(b: NodeBuilder, name, data_type: str):
    n = b.node("GeometryNodeInputNamedAttribute", {"Name": name}, data_type=data_type)
    return b.out(n, "Attribute"), b.out(n, "Exists")


def _subgroup(name: str, version, inputs, outputs, body):
    """The node group ``name`` (built by ``body(builder, group_input)`` → ``{output:
    socket}``) — small groups keep each tree small, which Blender builds much faster."""
    import bpy

    ng = bpy.data.node_groups.get(name)
    if ng is not None and ng.get("divas_display_version") == version:
        return ng
    if ng is None:
        ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
    ng.nodes.clear()
    ng.interface.clear()
    ng["divas_display_version"] = version
    for n, st in inputs:
        ng.interface.new_socket(n, in_out="INPUT", socket_type=st)
    for n, st in outputs:
        ng.interface.new_socket(n, in_out="OUTPUT", socket_type=st)
    b = NodeBuilder(ng)
    gin = b.node("NodeGroupInput")
    result = body(b, gin)
    gout = b.node("NodeGroupOutput")
    for n, sock in result.items():
        b.link(sock, gout.inputs[n])
    return ng


def _call(b: NodeBuilder, group, inputs: dict):
    n = b.node("GeometryNodeGroup", node_tree=group)
    for k, v in inputs.items():
        b.set(n, k, v)
    return n


def _per_axis(b: NodeBuilder, op: str, v, arg=None):
    """Scalar Math ``op`` on each component of the vector socket ``v`` (with ``arg`` as
    the second operand): Vector Math has no POWER or SIGN before Blender 4.5."""
    sep = b.node("ShaderNodeSeparateXYZ", {0: v})
    axes = [b.math(op, b.out(sep, k), arg) for k in ("X", "Y", "Z")]
    return b.node("ShaderNodeCombineXYZ", dict(enumerate(axes))).outputs[0]


def _step(b: NodeBuilder, v, knee: float):
    """Per component 1 where ``v > knee``, else 0 (both sRGB branches meet at the knee)."""
    return _per_axis(b, "GREATER_THAN", v, knee)


def srgb_encode(b: NodeBuilder, lin):
    """Extended sRGB encoding of a vector socket (sign-symmetric), as in
    ``linear_to_srgb``; plain math nodes, so it builds in a Geometry Nodes tree and in a
    material alike."""
    a = b.vmath("ABSOLUTE", lin)
    lo = b.vmath("SCALE", a, 12.92)
    root = _per_axis(b, "POWER", a, 1 / 2.4)
    hi = b.vmath("SUBTRACT", b.vmath("SCALE", root, 1.055), (0.055,) * 3)
    enc = b.vmath(
        "ADD", lo, b.vmath("MULTIPLY", _step(b, a, _LIN_SRGB_KNEE), b.vmath("SUBTRACT", hi, lo))
    )
    return b.vmath("MULTIPLY", enc, _per_axis(b, "SIGN", lin))


def _srgb_encode_group(version):
    """:func:`srgb_encode` as a node group."""

    def body(b, gin):
        return {"Vector": srgb_encode(b, b.out(gin, "Vector"))}

    vec = [("Vector", "NodeSocketVector")]
    return _subgroup("DivAS sRGB Encode", version, vec, vec, body)


def _srgb_decode_group(version):
    """sRGB decoding of a non-negative vector, as in ``srgb_to_linear``."""

    def body(b, gin):
        c = b.out(gin, "Vector")
        lo = b.vmath("SCALE", c, 1 / 12.92)
        base = b.vmath("SCALE", b.vmath("ADD", c, (0.055,) * 3), 1 / 1.055)
        hi = _per_axis(b, "POWER", base, 2.4)
        step = _step(b, c, _SRGB_LIN_KNEE)
        return {
            "Vector": b.vmath("ADD", lo, b.vmath("MULTIPLY", step, b.vmath("SUBTRACT", hi, lo)))
        }

    vec = [("Vector", "NodeSocketVector")]
    return _subgroup("DivAS sRGB Decode", version, vec, vec, body)


def _sh_term_group(version):
    """``Y · c``: the coefficient named *Name* decoded from its packed 8-bit codes
    (``(code − 128) / 127 · Range`` per channel), times the basis value *Y*; 0
    when the attribute does not exist."""

    def body(b, gin):
        code, exists = _named(b, b.out(gin, "Name"), "INT")
        hi = b.math("FLOOR", b.math("DIVIDE", code, 256.0))
        rgb = b.node(
            "ShaderNodeCombineXYZ",
            {
                0: b.math("FLOORED_MODULO", code, 256.0),
                1: b.math("FLOORED_MODULO", hi, 256.0),
                2: b.math("FLOOR", b.math("DIVIDE", hi, 256.0)),
            },
        ).outputs[0]
        rng = b.out(gin, "Range")
        value = b.vmath(
            "SCALE", b.vmath("SUBTRACT", rgb, (128.0,) * 3), b.math("DIVIDE", rng, 127.0)
        )
        y = b.math("MULTIPLY", b.out(gin, "Y"), exists)
        return {"Vector": b.vmath("SCALE", value, y), "Exists": exists}

    return _subgroup(
        "DivAS SH Term",
        version,
        [("Name", "NodeSocketString"), ("Range", "NodeSocketFloat"), ("Y", "NodeSocketFloat")],
        [("Vector", "NodeSocketVector"), ("Exists", "NodeSocketBool")],
        body,
    )


def _sh_colour_group(version):
    """``Σ_k Y_k(d) c_k`` over the ``divas_sh_k`` attributes (k = 1 … 15) along the unit
    direction *Direction*, and whether ``divas_sh_1`` exists."""
    term = _sh_term_group(version)

    def body(b, gin):
        sep = b.node("ShaderNodeSeparateXYZ", {0: b.out(gin, "Direction")})
        xyz = [b.out(sep, k) for k in ("X", "Y", "Z")]
        ranges = b.node("ShaderNodeSeparateXYZ", {0: b.out(gin, "SH Range")})
        band_range = [b.out(ranges, k) for k in ("X", "Y", "Z")]
        powers: dict[tuple[int, int, int], object] = {}

        def monomial(p):
            if p not in powers:
                factors = [xyz[axis] for axis in range(3) for _ in range(p[axis])]
                v = factors[0]
                for f in factors[1:]:
                    v = b.math("MULTIPLY", v, f)
                powers[p] = v
            return powers[p]

        total, first = None, None
        for k, terms in enumerate(SH_MONOMIALS, start=1):
            y = None
            for coef, *p in terms:
                t = b.math("MULTIPLY", monomial(tuple(p)), coef)
                y = t if y is None else b.math("ADD", y, t)
            n = _call(
                b,
                term,
                {"Name": sh_attribute_name(k), "Range": band_range[int(k**0.5) - 1], "Y": y},
            )
            first = b.out(n, "Exists") if first is None else first
            total = (
                b.out(n, "Vector") if total is None else b.vmath("ADD", total, b.out(n, "Vector"))
            )
        return {"Vector": total, "Exists": first}

    return _subgroup(
        "DivAS SH Colour",
        version,
        [("Direction", "NodeSocketVector"), ("SH Range", "NodeSocketVector")],
        [("Vector", "NodeSocketVector"), ("Exists", "NodeSocketBool")],
        body,
    )


def _view_dependent_rgb(b: NodeBuilder, gin, lin_dc, version):
    """The SH colour along the direction from the scene camera (module docstring, steps
    1–2), or ``max(lin_dc, 0)`` when *View-Dependent Colour* is off or there are no SH."""
    cam = b.node("GeometryNodeInputActiveCamera")
    info = b.node("GeometryNodeObjectInfo", {"Object": b.out(cam, 0)}, transform_space="RELATIVE")
    pos = b.out(b.node("GeometryNodeInputPosition"), 0)
    d = b.vmath("NORMALIZE", b.vmath("SUBTRACT", pos, b.out(info, "Location")))
    sh = _call(b, _sh_colour_group(version), {"Direction": d, "SH Range": b.out(gin, "SH Range")})
    dc = b.out(_call(b, _srgb_encode_group(version), {"Vector": lin_dc}), 0)
    shown = b.vmath("MAXIMUM", b.vmath("ADD", dc, b.out(sh, "Vector")), (0.0,) * 3)
    lin_sh = b.out(_call(b, _srgb_decode_group(version), {"Vector": shown}), 0)
    use_sh = b.node(
        "FunctionNodeBooleanMath",
        {0: b.out(gin, "View-Dependent Colour"), 1: b.out(sh, "Exists")},
        operation="AND",
    )
    dc_only = b.vmath("MAXIMUM", lin_dc, (0.0,) * 3)
    rgb = b.node(
        "GeometryNodeSwitch",
        {"Switch": b.out(use_sh, 0), "False": dc_only, "True": lin_sh},
        input_type="VECTOR",
    ).outputs[0]
    # step 1's gate: a single value, so the Switch evaluates only the branch it passes
    is_viewport = b.out(b.node("GeometryNodeIsViewport"), 0)
    hidden = b.node(
        "FunctionNodeBooleanMath",
        {0: is_viewport, 1: b.out(gin, "Points")},
        operation="AND",
    )
    shown = b.node(
        "FunctionNodeBooleanMath",
        {0: b.out(hidden, 0), 1: b.out(gin, "Viewport Colours")},
        operation="IMPLY",
    )
    return b.node(
        "GeometryNodeSwitch",
        {"Switch": b.out(shown, 0), "False": dc_only, "True": rgb},
        input_type="VECTOR",
    ).outputs[0]


def _shade_field(b: NodeBuilder, gin, tint, version, view_dependent: bool):
    """The display colour field on ``P`` (module docstring, step 2) and opacity; without
    ``view_dependent`` no node reads the scene camera."""
    color, _ = _named(b, COLOR, "FLOAT_COLOR")
    sep = b.node("FunctionNodeSeparateColor", {0: color})
    lin_dc = b.node(
        "ShaderNodeCombineXYZ",
        {0: b.out(sep, "Red"), 1: b.out(sep, "Green"), 2: b.out(sep, "Blue")},
    ).outputs[0]
    if view_dependent:
        rgb = _view_dependent_rgb(b, gin, lin_dc, version)
    else:  # the view-dependent group's "False" branch, node for node
        rgb = b.vmath("MAXIMUM", lin_dc, (0.0,) * 3)
    selected, _ = _named(b, SELECTED, "BOOLEAN")
    mix = b.node(
        "ShaderNodeMix",
        {"Factor": b.math("MULTIPLY", selected, 0.5), "A": rgb, "B": tint[:3]},
        data_type="VECTOR",
    )
    sep_rgb = b.node("ShaderNodeSeparateXYZ", {0: b.out(mix, "Result")})
    out = b.node(
        "FunctionNodeCombineColor",
        {
            "Red": b.out(sep_rgb, "X"),
            "Green": b.out(sep_rgb, "Y"),
            "Blue": b.out(sep_rgb, "Z"),
            "Alpha": b.out(sep, "Alpha"),
        },
    )
    return b.out(out, "Color"), b.out(sep, "Alpha")


def build_display_group(
    ng, *, splat_material, points_material, quad, tint, version, view_dependent: bool = True
) -> None:
    """Fill the (empty) Geometry Nodes group ``ng`` (module docstring); without
    ``view_dependent`` the fixed-colour variant (no camera dependency, same inputs)."""
    ng.is_modifier = True
    _interface(ng)
    b = NodeBuilder(ng)
    gin = b.node("NodeGroupInput")
    geo = b.out(gin, "Geometry")
    index = b.out(b.node("GeometryNodeInputIndex"), 0)

    def sample(value, data_type):
        n = b.node(
            "GeometryNodeSampleIndex",
            {"Geometry": geo, "Value": value, "Index": index},
            data_type=data_type,
            domain="POINT",
        )
        return b.out(n, "Value")

    shade, opacity = _shade_field(b, gin, tint, version, view_dependent)
    count = b.out(
        b.node("GeometryNodeAttributeDomainSize", {0: geo}, component="POINTCLOUD"), "Point Count"
    )
    pos = b.out(b.node("GeometryNodeInputPosition"), 0)
    clean = b.node("GeometryNodePoints", {"Count": count, "Position": sample(pos, "FLOAT_VECTOR")})
    store = b.node(
        "GeometryNodeStoreNamedAttribute",
        {"Geometry": b.out(clean, 0), "Name": SHADE, "Value": sample(shade, "FLOAT_COLOR")},
        data_type="FLOAT_COLOR",
        domain="POINT",
    )
    visible = b.node(
        "FunctionNodeCompare",
        {"A": opacity, "B": b.out(gin, "Opacity Threshold")},
        data_type="FLOAT",
        operation="GREATER_EQUAL",
    )
    keep = sample(b.out(visible, 0), "BOOLEAN")
    # splats
    rot, _ = _named(b, ROTATION, "QUATERNION")
    scale, _ = _named(b, SCALE, "FLOAT_VECTOR")
    s = b.node("ShaderNodeSeparateXYZ", {0: scale})
    s1, s2 = b.out(s, "X"), b.out(s, "Y")
    quad_scale = b.vmath(
        "SCALE",
        b.node("ShaderNodeCombineXYZ", {0: s1, 1: s2, 2: b.math("MAXIMUM", s1, s2)}).outputs[0],
        b.math("MULTIPLY", b.out(gin, "Size"), _quad_extent()),
    )
    quad_info = b.node("GeometryNodeObjectInfo", {"Object": quad}, transform_space="ORIGINAL")
    inst = b.node(
        "GeometryNodeInstanceOnPoints",
        {
            "Points": b.out(store, 0),
            "Selection": keep,
            "Instance": b.out(quad_info, "Geometry"),
            "Rotation": sample(rot, "QUATERNION"),
            "Scale": sample(quad_scale, "FLOAT_VECTOR"),
        },
    )
    real = b.node("GeometryNodeRealizeInstances", {"Geometry": b.out(inst, 0)})
    shade_attr, _ = _named(b, SHADE, "FLOAT_COLOR")
    to_display = b.node(
        "GeometryNodeStoreNamedAttribute",
        {"Geometry": b.out(real, 0), "Name": DISPLAY_COLOR, "Value": shade_attr},
        data_type="FLOAT_COLOR",
        domain="POINT",
    )
    drop = b.node("GeometryNodeRemoveAttribute", {"Geometry": b.out(to_display, 0), "Name": SHADE})
    splats = b.node(
        "GeometryNodeSetMaterial", {"Geometry": b.out(drop, 0), "Material": splat_material}
    )
    # points
    grid_radius, has_grid_radius = _named(b, "divas_radius", "FLOAT")
    gauss_radius = b.math("MULTIPLY", b.math("SQRT", b.math("MULTIPLY", s1, s2)), 2.0)
    max_r = b.out(gin, "Max Radius")
    clipped = b.node(
        "GeometryNodeSwitch",
        {
            "Switch": b.math("GREATER_THAN", max_r, 0.0),
            "False": gauss_radius,
            "True": b.math("MINIMUM", gauss_radius, max_r),
        },
        input_type="FLOAT",
    ).outputs[0]
    radius = b.node(
        "GeometryNodeSwitch",
        {"Switch": has_grid_radius, "False": clipped, "True": grid_radius},
        input_type="FLOAT",
    ).outputs[0]
    radius = b.math("MULTIPLY", radius, b.out(gin, "Size"))
    sized = b.node(
        "GeometryNodeSetPointRadius", {"Points": b.out(store, 0), "Radius": sample(radius, "FLOAT")}
    )
    hidden = b.node("FunctionNodeBooleanMath", {0: keep}, operation="NOT")
    pts = b.node(
        "GeometryNodeDeleteGeometry",
        {"Geometry": b.out(sized, 0), "Selection": b.out(hidden, 0)},
        domain="POINT",
    )
    points = b.node(
        "GeometryNodeSetMaterial", {"Geometry": b.out(pts, 0), "Material": points_material}
    )
    pick = b.node(
        "GeometryNodeSwitch",
        {"Switch": b.out(gin, "Points"), "False": b.out(splats, 0), "True": b.out(points, 0)},
        input_type="GEOMETRY",
    )
    gout = b.node("NodeGroupOutput")
    b.link(b.out(pick, 0), gout.inputs[0])


def _quad_extent() -> float:
    from .display import QUAD_EXTENT

    return QUAD_EXTENT


def _blended_colour(b: NodeBuilder, color):
    """What the material emits: the linear display colour, or with the scene's
    :data:`BLEND_FLAG` set its sRGB encoding (blending then sums display values
    like the trainers; :mod:`.blend_space` decodes the sum in the compositor)."""
    flag = b.node("ShaderNodeAttribute", attribute_type="VIEW_LAYER", attribute_name=BLEND_FLAG)
    mix = b.node(
        "ShaderNodeMix",
        {"Factor": b.out(flag, "Fac"), "A": color, "B": srgb_encode(b, color)},
        data_type="VECTOR",
    )
    return b.out(mix, "Result")


def _emission_over_transparent(b: NodeBuilder, color, alpha) -> None:
    em = b.node("ShaderNodeEmission", {"Color": _blended_colour(b, color), "Strength": 1.0})
    tr = b.node("ShaderNodeBsdfTransparent")
    mix = b.node("ShaderNodeMixShader", {0: alpha, 1: b.out(tr, 0), 2: b.out(em, 0)})
    out = b.node("ShaderNodeOutputMaterial", {"Surface": b.out(mix, 0)})
    out.target = "ALL"


def build_splat_material(nt) -> None:
    """The 2DGS Gaussian on the quad (NOTES "Depth tuple": α = min(0.99, o·G), skip
    α < 1/255) as the alpha of an unlit emission of the splat's display colour
    (display-encoded when the scene blends in display space)."""
    b = NodeBuilder(nt)
    uv = b.node("ShaderNodeAttribute", attribute_type="GEOMETRY", attribute_name=QUAD_UV)
    col = b.node("ShaderNodeAttribute", attribute_type="GEOMETRY", attribute_name=DISPLAY_COLOR)
    r2 = b.vmath("DOT_PRODUCT", b.out(uv, "Vector"), b.out(uv, "Vector"))
    g = b.math("EXPONENT", b.math("MULTIPLY", r2, -0.5))
    alpha = b.math("MINIMUM", b.math("MULTIPLY", b.out(col, "Alpha"), g), 0.99)
    alpha = b.math("MULTIPLY", alpha, b.math("GREATER_THAN", alpha, 1.0 / 255.0 - 1e-7))
    _emission_over_transparent(b, b.out(col, "Color"), alpha)


def build_points_material(nt) -> None:
    """Unlit display colour, opacity as alpha (for the point display)."""
    b = NodeBuilder(nt)
    col = b.node("ShaderNodeAttribute", attribute_type="GEOMETRY", attribute_name=SHADE)
    _emission_over_transparent(b, b.out(col, "Color"), b.out(col, "Alpha"))
