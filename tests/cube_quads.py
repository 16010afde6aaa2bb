"""The closed unit cube of the light-transport tests, as quads with inward normals."""
import numpy as np


def unit_cube_quads():
    """Six quads (4, 3) of the unit cube, each wound so its normal ``cross(q1 - q0, q2 - q0)`` points inwards."""
    quads = []
    for axis in range(3):
        for lo in (0.0, 1.0):
            a, b = (axis + 1) % 3, (axis + 2) % 3
            q = []
            for u, v in ((0, 0), (1, 0), (1, 1), (0, 1)):
                p = np.zeros(3)
                p[axis], p[a], p[b] = lo, u, v
                q.append(p)
            q = np.array(q)
            inward = np.zeros(3)
            inward[axis] = 1.0 if lo == 0.0 else -1.0
            if np.cross(q[1] - q[0], q[2] - q[0]) @ inward < 0:
                q = q[::-1]
            quads.append(q)
    return quads
