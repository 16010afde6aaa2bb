"""What every solution module shares: the record of one exercise's answers."""
from dataclasses import dataclass

from mcvar._validation import as_rng  # noqa: F401  (re-exported for the solution modules)


@dataclass(frozen=True)
class Solution:
    """The answers of one exercise: never shipped with the package.

    Attributes
    ----------
    reference : tuple
        A correct solution, one item per part of the exercise: must PASS.
    wrong : tuple
        A solution with the classic mistake ``mistake``: must FAIL.
    mistake : str
    """

    reference: tuple
    wrong: tuple
    mistake: str
