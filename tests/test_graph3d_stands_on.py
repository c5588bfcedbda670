"""The stand-on rule of the sweep (``cut._on_its_support``) on hand-made voxel graphs:
a column of another material standing on a block is cut off the block; a patch of
another material set into the top of a plate — its boundary running round its sides,
level with it — is not something standing on the plate."""

from __future__ import annotations

import numpy as np

from divas_engine.segment.graph3d import Graph3DConfig
from divas_engine.segment.graph3d.cut import _local_minima, _on_its_support, _prefix_cuts
from divas_engine.segment.graph3d.voxel_graph import VoxelGraph

_H = 0.01
_ACROSS = 0.05  # the affinity between two materials (1 within one)


def _graph(cells: np.ndarray, material: np.ndarray) -> VoxelGraph:
    """A 6-neighbour voxel graph of integer ``cells [V,3]`` (z up), Lab colour by
    ``material`` (0: grey, 1: red), affinity 1 within a material, ``_ACROSS`` across."""
    v = len(cells)
    index = {tuple(c): i for i, c in enumerate(cells)}
    edges = []
    for i, c in enumerate(cells):
        for d in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
            j = index.get((c[0] + d[0], c[1] + d[1], c[2] + d[2]))
            if j is not None:
                edges.append((i, j))
    e = np.array(edges, np.int64)
    w = np.where(material[e[:, 0]] == material[e[:, 1]], 1.0, _ACROSS)
    lab = np.where(material[:, None] == 1, [[50.0, 60.0, 40.0]], [[60.0, 0.0, 0.0]])
    normal = np.tile([0.0, 0.0, 1.0], (v, 1))
    return VoxelGraph(
        prim=np.arange(v),
        voxel_of=np.arange(v),
        centroid=cells * _H,
        lab=lab,
        normal=normal,
        kappa=np.zeros(v),
        mass=np.ones(v),
        cell=cells.astype(np.int64),
        rim=np.zeros(v, bool),
        edges=e,
        weights=w,
        lo=np.zeros(3),
        h=_H,
        cells=64,
    )


def _chosen(cells: np.ndarray, material: np.ndarray, seed: int) -> np.ndarray:
    """The region the stand-on rule keeps when the sweep ran over the red part first,
    then the grey one, each by distance from the seed voxel, and chose the whole."""
    graph = _graph(cells, material)
    dist = np.linalg.norm(cells - cells[seed], axis=1)
    order = np.lexsort((dist, material != 1))
    deg = np.bincount(graph.edges.ravel(), np.r_[graph.weights, graph.weights], len(cells))
    cut = _prefix_cuts(order, graph, deg)
    vol = np.cumsum(deg[order])
    total = 2.0 * vol[-1]  # as much again outside (the rest of the region)
    phi = cut / np.minimum(vol, total - vol)
    big = np.ones(len(cells), bool)
    cfg = Graph3DConfig()
    positive = np.zeros(len(cells), bool)
    positive[seed] = True
    best = len(cells) - 1
    dip = int(np.count_nonzero(material == 1)) - 1
    assert dip in _local_minima(phi, vol, cfg.tie_window)  # the red part is a dip of φ
    k = _on_its_support(
        graph,
        order,
        phi,
        vol,
        big,
        best,
        1,
        np.zeros(len(cells), bool),
        positive,
        np.array([0.0, 0.0, 1.0]),
        cfg,
    )
    out = np.zeros(len(cells), bool)
    out[order[: k + 1]] = True
    return out


def _plate(nx: int, nz: int, ny: int = 3) -> list[tuple[int, int, int]]:
    return [(x, y, z) for x in range(nx) for y in range(ny) for z in range(nz)]


def test_a_column_standing_on_a_block_of_another_material_is_cut_off_it():
    block = _plate(20, 10)
    column = [(x, y, z) for x in range(8, 12) for y in range(3) for z in range(10, 22)]
    cells = np.array(block + column)
    material = np.r_[np.zeros(len(block), int), np.ones(len(column), int)]
    seed = len(block) + len(column) - 1  # the column's top
    chosen = _chosen(cells, material, seed)
    assert np.array_equal(chosen, material == 1)


def test_a_patch_set_level_into_the_top_of_a_plate_keeps_the_plate():
    cells = np.array(_plate(20, 12))
    patch = (cells[:, 0] >= 8) & (cells[:, 0] < 12) & (cells[:, 2] >= 9)  # the top 3 layers
    material = patch.astype(int)
    seed = int(np.flatnonzero(patch)[-1])
    chosen = _chosen(cells, material, seed)
    assert chosen.all()  # the whole plate: the patch stands on nothing
