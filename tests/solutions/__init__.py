"""The course exercises' answers: reference solutions and planted wrong ones.

They live in the test suite, **not** in the ``mcvar`` package, so that a
student's ``pip install mcvar`` does not carry them (``tests/test_grade.py``
checks the package's files). ``SOLUTIONS`` maps each exercise name of
:data:`mcvar.testing.exercises.EXERCISES` to a :class:`Solution`.

A teacher checks every grader against them with::

    cd tests && python -m solutions            # PASS, FAIL and NOT ATTEMPTED for every exercise
"""
from ._base import Solution
from .nb01_06 import SOLUTIONS as _S01
from .nb07_09 import SOLUTIONS as _S07
from .nb10 import SOLUTIONS as _S10
from .nb11 import SOLUTIONS as _S11
from .nb12 import SOLUTIONS as _S12

SOLUTIONS = {**_S01, **_S07, **_S10, **_S11, **_S12}

__all__ = ["Solution", "SOLUTIONS"]
