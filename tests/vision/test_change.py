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


def _textured_scene(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured table with noise, a shadow and a bright and a dark object: every branch of the test is taken."""
    rng = np.random.default_rng(seed)
    shape = (150, 210)
    stripes = np.where(np.arange(shape[1]) % 9 < 4, 35.0, 60.0)
    reference = (np.tile(stripes, (shape[0], 1)) + rng.normal(0.0, 2.0, shape)).astype(np.float32)
    current = (reference + rng.normal(0.0, 1.0, shape)).astype(np.float32)
    current[20:70, 30:100] = 200.0 + rng.normal(0.0, 3.0, (50, 70)).astype(np.float32)  # a white sole
    current[80:140, 120:200] = 45.0 + rng.normal(0.0, 0.5, (60, 80)).astype(np.float32)  # the table's mean
    current[90:150, 10:80] *= 0.6  # a shadow
    table = np.ones(shape, bool)
    table[10:150, 20:205] = False
    table[100:, :90] = True
    return current, reference, table


def test_the_change_test_on_a_box_marks_the_boxs_pixels_as_on_the_whole_image() -> None:
    for seed in range(3):
        current, reference, table = _textured_scene(seed)
        test = ChangeTest.fit(current, reference, table)
        assert test is not None
        whole = test.changed(current, reference)
        assert 0.1 < whole.mean() < 0.9
        # Sides just inside and just outside the objects' edges (where a filter cut at the box would see
        # another neighbourhood), inside, touching one side of the image, touching two, the whole image, a box
        # past the image, an empty box.
        for rows, cols in (
            (slice(22, 68), slice(32, 98)),
            (slice(18, 72), slice(28, 102)),
            (slice(83, 137), slice(123, 197)),
            (slice(77, 143), slice(117, 203)),
            (slice(30, 100), slice(40, 150)),
            (slice(0, 60), slice(50, 120)),
            (slice(90, 150), slice(150, 210)),
            (slice(0, 150), slice(0, 210)),
            (slice(-20, 400), slice(5, 300)),
            (slice(40, 40), slice(10, 20)),
        ):
            boxed = test.changed(current, reference, (rows, cols))
            inside = np.zeros(whole.shape, bool)
            inside[rows, cols] = True
            np.testing.assert_array_equal(boxed[inside], whole[inside])
            assert not boxed[~inside].any()
