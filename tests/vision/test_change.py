"""The change test's texture vote: a shadow keeps the table's texture at a shadow's scale; a sole's edge that
runs along a step of the table's own texture correlates with it too, but at ten times its scale."""

from __future__ import annotations

import numpy as np

from cellctl.vision.change import ChangeTest


def test_a_bright_sole_edge_along_a_step_of_the_tables_texture_is_changed_up_to_the_edge() -> None:
    rng = np.random.default_rng(3)
    shape = (120, 160)
    reference = np.full(shape, 50.0, np.float32)
    reference[60:, :] = 40.0  # the table's texture: a faint step along row 60, brighter on the sole's side
    reference += rng.normal(0.0, 1.0, shape).astype(np.float32)
    current = reference + rng.normal(0.0, 1.0, shape).astype(np.float32)
    current[:60, 40:120] = 190.0 + rng.normal(0.0, 1.0, (60, 80)).astype(np.float32)  # a white sole, edge at 60
    table = np.ones(shape, bool)
    table[:70, 30:130] = False
    test = ChangeTest.fit(current, reference, table)
    assert test is not None
    changed = test.changed(current, reference)
    assert changed[:59, 42:118].all()  # up to the row next to the edge: the step does not veto it
    assert not changed[61:, :].any() and not changed[:, :38].any()


def test_a_shadow_along_the_same_step_stays_table() -> None:
    rng = np.random.default_rng(4)
    shape = (120, 160)
    reference = np.tile(np.where(np.arange(160) % 8 < 4, 40.0, 55.0), (120, 1)).astype(np.float32)
    reference += rng.normal(0.0, 1.0, shape).astype(np.float32)
    current = reference + rng.normal(0.0, 1.0, shape).astype(np.float32)
    current[:60, 40:120] *= 0.6  # a cast shadow: the same stripes, darker
    table = np.ones(shape, bool)
    table[:70, 30:130] = False
    test = ChangeTest.fit(current, reference, table)
    assert test is not None
    assert test.changed(current, reference)[:60, 40:120].mean() < 0.1
