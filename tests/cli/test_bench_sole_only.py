"""`cellctl bench-sole --matrix --only`: the listed soles are the ones of the full matrix, not new ones."""

from __future__ import annotations

import pytest

from cellctl.cli.bench_sole import _only
from cellctl.errors import UserError
from cellctl.sim.matrix import matrix_soles


def test_only_keeps_the_matrix_soles_with_their_variations_and_colours() -> None:
    full = matrix_soles(84, 3000)
    chosen = _only(full, "3060,3002")
    assert [s.seed for s in chosen] == [3060, 3002]
    assert chosen == [full[60], full[2]]
    # a matrix of one sole from the same seed is another sole: why --only exists
    assert matrix_soles(1, 3002)[0] != full[2]


@pytest.mark.parametrize("text", ["3002,x", "3100"])
def test_only_refuses_what_is_not_a_seed_of_the_matrix(text: str) -> None:
    with pytest.raises(UserError):
        _only(matrix_soles(84, 3000), text)
