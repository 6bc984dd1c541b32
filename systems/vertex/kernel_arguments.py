"""How the compiled vertex kernels take their arguments, for every system's colour sweep (mass_spring, fem's solids
and shells): the code of a block projection, and a colour's vertices as unsigned indices."""

from __future__ import annotations

import numpy as np

# a colour's vertices as unsigned indices, by the identity of the colour's array (the solver keeps its colours for
# the run): made once, not per sweep
_UNSIGNED: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def unsigned(vertices: np.ndarray) -> np.ndarray:
    """``vertices`` as uint64: numba's indexing then skips the wraparound test of a negative index."""
    kept = _UNSIGNED.get(id(vertices))
    if kept is None or kept[0] is not vertices:
        if len(_UNSIGNED) > 4096:
            _UNSIGNED.clear()
        kept = _UNSIGNED[id(vertices)] = (vertices, vertices.astype(np.uint64))
    return kept[1]


# projections of the terms' blocks: none, negative eigenvalues clamped at 0, mirrored (the codes that
# vertex_kernels.py's filtered_eigenvalue reads)
PROJECTION_CODES = {False: 0, "clamp": 1, True: 1, "abs": 2}
