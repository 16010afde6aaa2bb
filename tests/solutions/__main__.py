"""``python -m solutions`` (from ``tests/``): grade every exercise's reference,
planted wrong solution and untouched stub, and say whether each grader behaves."""
import sys

from mcvar.testing import grade
from mcvar.testing.exercises import EXERCISES, exercise

from . import SOLUTIONS


def main() -> int:
    bad = 0
    for name, ex in EXERCISES.items():
        sol = SOLUTIONS.get(name)
        if sol is None:
            print(f"{name:22s} NO SOLUTION on file")
            bad += 1
            continue
        ref = exercise(name, *sol.reference, verbose=False)
        wrong = exercise(name, *sol.wrong, verbose=False)
        stub = exercise(name, *ex.stubs(), verbose=False)
        ok = ref.status == "PASS" and wrong.status == "FAIL" and stub.status == grade.NOT_ATTEMPTED
        bad += not ok
        print(f"{name:22s} {'ok ' if ok else 'BAD'} reference {ref.status:4s} ({ref.seconds:4.1f} s) | "
              f"wrong {wrong.status}: {wrong.reason}")
    print(f"{len(EXERCISES) - bad} of {len(EXERCISES)} graders behave")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
