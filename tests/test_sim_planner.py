"""The walk planner's searches against their plain forms: the cost-bounded shortest path
against a search of the whole grid, the waypoints picked a block at a time against one cell
at a time."""

import numpy as np
from scipy.sparse.csgraph import dijkstra

from bimgraph.sim.occupancy import Grid
from bimgraph.sim.trajectory import _Planner, waypoints


def _floor() -> tuple[np.ndarray, np.ndarray]:
    """Two rooms joined by a door, and an enclosed closet the walk cannot reach."""
    free = np.ones((60, 140), dtype=bool)
    free[:, 70] = False
    free[28:32, 70] = True  # the door
    free[5:15, 5:15] = False
    free[7:13, 7:13] = True  # the closet, walled round
    distance = np.ones(free.shape)
    distance[:, 65:76] = 0.3  # costlier near the wall
    return free, distance


def test_bounded_search_finds_the_shortest_path():
    free, distance = _floor()
    planner = _Planner(free, distance, clearance=0.4, cell=0.1)
    node = planner.node
    start = node[30, 2]
    for goal in [node[31, 4], node[2, 138], node[59, 69], node[45, 100]]:
        cells = planner.path(start, goal)
        full, _ = dijkstra(planner.graph, directed=False, indices=start, return_predecessors=True)
        steps = np.diff(cells, axis=0)
        assert (tuple(cells[0]), tuple(cells[-1])) == (tuple(planner.cells[start]), tuple(planner.cells[goal]))
        assert (np.abs(steps).max(axis=1) == 1).all()  # neighbouring cells
        cost = sum(planner.graph[node[tuple(a)], node[tuple(b)]] or planner.graph[node[tuple(b)], node[tuple(a)]]
                   for a, b in zip(cells, cells[1:]))
        assert np.isclose(cost, full[goal], rtol=1e-12)
    closet = node[10, 10]
    assert (planner.path(start, closet) == planner.cells[[start]]).all()  # unreachable: stays put


def test_waypoints_are_picked_as_one_cell_at_a_time_would():
    free, distance = _floor()
    grid = Grid(np.zeros(2), 0.1, free.shape)
    picked = waypoints(free, distance, grid, 1.5, np.random.default_rng(3))
    # the plain form: every cell in the drawn order, taken unless a taken one blocks it
    rng = np.random.default_rng(3)
    cells = np.argwhere(free)
    weight = distance[tuple(cells.T)] ** 2
    order = rng.choice(len(cells), size=len(cells), replace=False, p=weight / weight.sum())
    chosen = []
    for i, j in cells[order]:
        if all(np.hypot(i - a, j - b) * 0.1 >= 1.5 for a, b in chosen):
            chosen.append((i, j))
    assert picked.tolist() == [list(c) for c in chosen]
