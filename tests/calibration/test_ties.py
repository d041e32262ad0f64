"""Near ties fall to the first candidate (calibration/ties.py): the planner's choices do
not depend on a machine's round-off."""
import math

import numpy as np

from calibration.ties import first_max, first_min, less, tied


def test_values_equal_but_for_round_off_are_tied_and_the_first_wins():
    rng = np.random.default_rng(5)
    for _ in range(200):
        v = rng.normal(size=12) * 10 ** rng.uniform(-3, 6)
        v[7] = v[3] = v.max() + abs(v.max())          # an exact tie, the first at 3
        for _ in range(5):
            off = v * (1 + 4e-16 * rng.standard_normal(v.shape))
            assert first_max(off) == 3 and first_min(-off) == 3
    assert first_max([1.0, 2.0, 2.0 + 1e-3]) == 2      # a real difference is not a tie
    assert first_max([-np.inf, np.nan, -5.0, -5.0]) == 2
    assert first_max([-np.inf, -np.inf]) == 0 and first_min([np.inf, 1.0, np.nan]) == 1
    assert tied(1e-20, 0.0) and tied(1e12, 1e12 * (1 + 1e-12)) and not tied(1.0, 1.0 + 1e-6)


def test_keys_compare_item_by_item_with_ties_as_equal():
    """A refit's key (not converged, residual sum of squares): converged first, then the
    smaller residual; two fits that end in one minimum are tied, and neither is less, so
    the first one kept stays whatever the last bits."""
    a = (False, 1.0)
    b = (False, math.nextafter(1.0, 0.0))                # one unit in the last place less
    assert not less(b, a) and not less(a, b)
    assert less((False, 1.0), (True, 0.5)) and not less((True, 0.5), (False, 1.0))
    assert less((False, 0.9), (False, 1.0)) and not less((False, 1.0), (False, 0.9))
