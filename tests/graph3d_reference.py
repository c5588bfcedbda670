"""An independent reference of the 3D graph segmenter's per-prompt voxel graph and of its
supports' primitive test, written from their documented definitions (the
``voxel_graph.py`` section of docs/design-notes.md, ``_extent_entries``' docstring,
:class:`~divas_engine.segment.graph3d.config.Graph3DConfig`) and not from the code:
loops over primitives and their extents' lattice samples, dictionaries keyed by integer
cell, ``np.add.at`` sums, a sorted lookup of neighbour cells, per-edge formulas as
written. Slow (small test scenes only); it shares nothing with graph3d but the
:class:`Graph3DConfig` values and the :class:`VoxelGraph` container it fills. The
definitions it implements (primitives, region, extents, nodes, edges, supports) are
listed in docs/design-notes.md.
"""

from __future__ import annotations

import itertools
import math
import statistics
from dataclasses import dataclass

import cv2
import numpy as np

from divas_engine.kinds import SceneKind
from divas_engine.scene import SH_C0, SurfelScene
from divas_engine.segment.graph3d.config import Graph3DConfig
from divas_engine.segment.graph3d.voxel_graph import VoxelGraph

__all__ = [
    "ReferencePrimitives",
    "reference_primitives",
    "reference_voxel_graph",
    "reference_support_primitives",
    "graph_by_cell",
]

#: a primitive's reach in σ: its cutoff disc (α ≥ 1/255 down to α ≈ 1/3000) lies within 4 σ
REACH_SIGMAS = 4.0
_NEIGHBOURS = [d for d in itertools.product((-1, 0, 1), repeat=3) if d != (0, 0, 0)]


@dataclass(eq=False)
class ReferencePrimitives:
    """Per-primitive features (float64), in the segmenter's primitive order."""

    index: np.ndarray  # scene row of each primitive
    points: np.ndarray
    mass: np.ndarray
    lab: np.ndarray
    normals: np.ndarray
    kappa: np.ndarray
    axes: np.ndarray | None  # [M,3,3] rows: σ-scaled principal axes (surfels)
    sigma: np.ndarray | None
    gs3d: bool
    cell: float  # a density grid's cell edge, 0 for surfels

    @property
    def reach(self) -> np.ndarray:
        return REACH_SIGMAS * self.sigma


def _unit_quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """``[N,3,3]``: the rotation of each quaternion (w, x, y, z), normalised first."""
    out = np.empty((len(q), 3, 3))
    for i, row in enumerate(np.asarray(q, np.float64)):
        w, x, y, z = row / math.sqrt(float(row @ row))
        out[i] = [
            [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
        ]
    return out


def reference_primitives(scene, min_opacity: float, grid_prims=None) -> ReferencePrimitives:
    """Features of a surfel ``scene`` (docs/design-notes.md); for a density grid pass the
    segmenter's ``grid_prims`` (:class:`ScenePrimitives`), whose cells are taken as they are."""
    if not isinstance(scene, SurfelScene):
        gp = grid_prims
        return ReferencePrimitives(
            np.asarray(gp.index),
            gp.points.astype(np.float64),
            gp.mass.astype(np.float64),
            gp.lab.astype(np.float64),
            gp.normals.astype(np.float64),
            gp.kappa.astype(np.float64),
            None,
            None,
            False,
            float(gp.cell),
        )
    keep = np.flatnonzero(scene.opacities >= min_opacity)
    rgb = np.clip(0.5 + SH_C0 * scene.sh[keep, 0, :], 0.0, 1.0).astype(np.float32)
    lab = cv2.cvtColor(rgb.reshape(-1, 1, 3), cv2.COLOR_RGB2Lab).reshape(-1, 3)
    rot = _unit_quaternion_matrices(scene.quats[keep])
    s = np.zeros((len(keep), 3))
    s[:, :2] = scene.scales[keep]
    if scene.scale_n is None:
        kappa = np.ones(len(keep))
    else:
        s[:, 2] = scene.scale_n[keep]
        kappa = np.clip(1.0 - s[:, 2] / np.maximum(s[:, :2].min(axis=1), 1e-12), 0.0, 1.0)
    axes = np.stack([rot[:, :, k] * s[:, k : k + 1] for k in range(3)], axis=1)
    return ReferencePrimitives(
        keep,
        scene.means[keep].astype(np.float64),
        scene.opacities[keep].astype(np.float64),
        lab.astype(np.float64),
        rot[:, :, 2],
        kappa,
        axes,
        s.max(axis=1),
        scene.kind == SceneKind.GS3D,
        0.0,
    )


def _region(ref: ReferencePrimitives, center, radius: float, config: Graph3DConfig):
    g = int(config.grid_cells)
    if ref.cell > 0.0:
        g = max(4, min(g, int(2.0 * float(radius) / ref.cell)))
    h = 2.0 * float(radius) / g
    lo = np.asarray(center, np.float64) - float(radius) - h
    return g + 2, h, lo


def _extent_samples(ref, i, centre_cell, lo, h, cells, config) -> dict:
    """``{cell: (falloff, position)}`` of primitive ``i``'s extent (docs/design-notes.md)."""
    k = float(config.extent_sigmas)
    s = np.linalg.norm(ref.axes[i], axis=1)
    dirs = ref.axes[i] / np.where(s > 0, s, 1.0)[:, None]
    steps = [min(math.ceil(k * si / h), config.extent_max_steps) if si > 0 else 0 for si in s]
    per = np.array([min(k * si / m, h) / si if m > 0 else 0.0 for si, m in zip(s, steps)])
    # the lattice in lexicographic order of j (the tie rule), without j = 0
    j = np.array(list(itertools.product(*[range(-m, m + 1) for m in steps])), np.float64)
    j = j[np.any(j != 0, axis=1)]
    u = j * per  # σ units
    r2 = np.sum(u * u, axis=1)
    u, r2 = u[r2 <= k * k + 1e-9], r2[r2 <= k * k + 1e-9]
    pos = ref.points[i] + (u * s) @ dirs
    best: dict[tuple, tuple[float, np.ndarray]] = {}
    for p, q in zip(pos, r2):
        c = tuple(math.floor((p[a] - lo[a]) / h) for a in range(3))
        if not all(0 <= x < cells for x in c) or c == centre_cell:
            continue
        falloff = math.exp(-0.5 * q)
        if c not in best or falloff > best[c][0]:
            best[c] = (falloff, p)
    return best


def reference_voxel_graph(
    ref: ReferencePrimitives,
    center,
    radius: float,
    config: Graph3DConfig,
    normal_gaps: dict | None = None,
) -> VoxelGraph:
    """The voxel graph of the cube ``center ± radius`` (docs/design-notes.md).
    ``normal_gaps``: filled with each node cell's relative gap between the two largest
    eigenvalues of its tensor (near 0: its principal normal is not defined — a voxel
    where two faces carry the same mass — and any unit vector of the plane is one)."""
    cells, h, lo = _region(ref, center, radius, config)
    hi = lo + cells * h
    inside = np.flatnonzero(np.all((ref.points >= lo) & (ref.points <= hi), axis=1))
    centre_cells = np.clip(np.floor((ref.points[inside] - lo) / h), 0, cells - 1).astype(int)
    centre = {int(i): tuple(int(x) for x in c) for i, c in zip(inside, centre_cells)}
    with_centre = set(centre.values())
    # entries (primitive, mass, position, cell): every centre, then the extents' samples
    rows, masses, points, where = list(inside), list(ref.mass[inside]), [ref.points[inside]], []
    where += [centre[int(i)] for i in inside]
    k = float(config.extent_sigmas)
    extents = ref.axes is not None and k > 0.0 and (ref.gs3d or not config.extent_gs3d_only)
    for i in inside if extents else ():
        if not ref.sigma[i] > config.extent_min_sigma * h:
            continue
        c = centre[int(i)]
        if any(tuple(x + d for x, d in zip(c, off)) in with_centre for off in _NEIGHBOURS):
            continue
        for cell, (falloff, pos) in _extent_samples(ref, i, c, lo, h, cells, config).items():
            rows.append(i)
            masses.append(ref.mass[i] * falloff)
            points.append(pos[None])
            where.append(cell)
    rows, a, p = np.array(rows, np.int64), np.array(masses), np.concatenate(points)

    # nodes: the occupied cells in ascending z, y, x; the sums per node by np.add.at
    order = sorted(set(where), key=lambda c: (c[2], c[1], c[0]))
    node = {c: n for n, c in enumerate(order)}
    of = np.array([node[c] for c in where], np.int64)
    v = len(order)
    mass = np.zeros(v)
    np.add.at(mass, of, a)
    safe = np.maximum(mass, 1e-12)[:, None]
    centroid, lab, tensor = np.zeros((v, 3)), np.zeros((v, 3)), np.zeros((v, 3, 3))
    np.add.at(centroid, of, a[:, None] * p)
    np.add.at(lab, of, a[:, None] * ref.lab[rows])
    n = ref.normals[rows]
    np.add.at(tensor, of, (a * ref.kappa[rows])[:, None, None] * n[:, :, None] * n[:, None, :])
    centroid /= safe
    lab /= safe
    evals, evecs = np.linalg.eigh(tensor)
    normal = evecs[:, :, 2]
    trace = np.trace(tensor, axis1=1, axis2=2)
    nu = np.clip(trace / safe[:, 0], 0.0, 1.0)
    tensor /= np.maximum(trace, 1e-12)[:, None, None]
    if normal_gaps is not None:
        gap = (evals[:, 2] - evals[:, 1]) / np.maximum(evals[:, 2], 1e-300)
        normal_gaps.update(zip(order, gap.tolist()))

    # 26-neighbour pairs, each once (to the later node): a sorted lookup of cell codes
    cell = np.array(order, np.int64).reshape(-1, 3)
    span = cells + 2  # room for a neighbour one cell outside the cube

    def cell_code(c: np.ndarray) -> np.ndarray:
        return ((c[:, 2] + 1) * span + c[:, 1] + 1) * span + c[:, 0] + 1

    code = cell_code(cell)  # ascending: the node order
    pairs = []
    for off in _NEIGHBOURS:
        other = np.searchsorted(code, cell_code(cell + np.array(off)))
        other = np.minimum(other, max(v - 1, 0))
        hit = (code[other] == cell_code(cell + np.array(off))) & (other > np.arange(v))
        pairs.append(np.stack([np.flatnonzero(hit), other[hit]], 1))
    e = np.concatenate(pairs) if v else np.zeros((0, 2), np.int64)
    typical = statistics.median(mass[node[c]] for c in with_centre) if with_centre else 0.0
    weights = _weights(e, centroid, lab, normal, tensor, nu, mass, typical, h, config)
    return VoxelGraph(
        prim=inside.astype(np.int64),
        voxel_of=np.array([node[centre[int(i)]] for i in inside], np.int64),
        centroid=centroid,
        lab=lab,
        normal=normal,
        kappa=nu,
        mass=mass,
        cell=cell,
        rim=np.any((cell == 0) | (cell == cells - 1), axis=1),
        edges=e,
        weights=weights,
        lo=lo,
        h=h,
        cells=cells,
    )


def _weights(e, centroid, lab, normal, tensor, nu, mass, typical, h, config) -> np.ndarray:
    """``w = a_d a_c a_n a_m`` per edge ``e [E,2]`` (Graph3DConfig's definitions)."""
    if len(e) == 0:
        return np.zeros(0)
    i, j = e[:, 0], e[:, 1]
    d2 = np.sum((centroid[i] - centroid[j]) ** 2, axis=1)
    a_d = np.exp(-d2 / (2.0 * (config.sigma_d * h) ** 2))
    dc2 = np.sum((lab[i] - lab[j]) ** 2, axis=1)
    a_c = np.exp(-config.colour_contrast / max(float(dc2.mean()), 1e-6) * dc2)
    # the share of j's normal mass along i's principal normal, and of i's along j's
    along_i = np.clip(
        np.matmul(normal[i][:, None, :], np.matmul(tensor[j], normal[i][:, :, None])), 0, 1
    )
    along_j = np.clip(
        np.matmul(normal[j][:, None, :], np.matmul(tensor[i], normal[j][:, :, None])), 0, 1
    )
    agree = np.sqrt(along_i * along_j).reshape(-1)
    a_n = np.exp(-nu[i] * nu[j] * (1.0 - agree) / config.normal_sigma)
    mm = np.minimum(mass[i], mass[j])
    return a_d * a_c * a_n * mm / (mm + max(config.mass_floor * typical, 1e-12))


def reference_support_primitives(
    graph: VoxelGraph,
    ref: ReferencePrimitives,
    up: np.ndarray | None,
    planes: np.ndarray,
    config: Graph3DConfig,
) -> np.ndarray:
    """Bool per ``graph.prim``: a support's primitive in a kept voxel (docs/design-notes.md)."""
    out = np.zeros(len(graph.prim), bool)
    if up is None or not planes.any():
        return out
    up = np.asarray(up, np.float64)
    levels = {float(np.round(c @ up / graph.h)) for c in graph.centroid[planes]}
    cos_min = math.cos(math.radians(config.ground_normal_deg))
    for r, i in enumerate(graph.prim):
        if abs(float(ref.normals[i] @ up)) < cos_min:
            continue
        height = float(ref.points[i] @ up) / graph.h
        out[r] = any(abs(height - level) <= 1.0 for level in levels)
    return out


def graph_by_cell(g: VoxelGraph) -> dict:
    """A graph in node-order-free form: per cell its node's attributes, per primitive its
    centre's cell, per undirected cell pair its weight."""
    cells = [tuple(int(x) for x in c) for c in g.cell]
    return {
        "nodes": {
            c: (g.mass[n], g.centroid[n], g.lab[n], g.normal[n], g.kappa[n], bool(g.rim[n]))
            for n, c in enumerate(cells)
        },
        "prims": {int(p): cells[int(v)] for p, v in zip(g.prim, g.voxel_of)},
        "edges": {
            frozenset((cells[int(a)], cells[int(b)])): float(w)
            for (a, b), w in zip(g.edges, g.weights)
        },
    }
