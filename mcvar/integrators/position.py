"""The ``position`` AOV: the world position of the first hit (0 on a miss).

The smallest complete method: one shading function and one registration
line (docs/integrators.md, 'Adding a method'); the contract suite
(``tests/test_integrator_contract.py``) runs on it because it is registered.
"""
from .aov import aov_method
from .registry import register


def _position(hit):
    return hit.p


register(aov_method("position", _position, "first-hit world position, 0 on a miss (AOV)"))
